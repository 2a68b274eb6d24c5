"""The package drawn by its imports: no circle, counting lazy and type-only imports and modules
loaded by name at run time."""

from __future__ import annotations

import ast
from pathlib import Path

from rollergear_ros import WINGS

PACKAGE = Path(__file__).resolve().parent.parent / "rollergear_ros"


def module_name(path: Path, package: Path) -> str:
    """``core/params.py`` -> ``core.params``; a package's ``__init__.py`` is the package."""
    parts = path.relative_to(package).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module (dotted, below the package) -> the package's modules it imports anywhere in its text
    (``from .x import``, ``from ..wing import x``, ``from rollergear_ros.wing.x import``,
    ``importlib.import_module("rollergear_ros.wing.x")``)."""
    files = {module_name(p, package): p for p in package.rglob("*.py")}
    modules = set(files)
    graph: dict[str, set[str]] = {m: set() for m in modules}

    def resolve(dotted: str, names: list[str]) -> set[str]:
        """The modules ``from dotted import names`` reaches (a name that is a module, else ``dotted``)."""
        found = {f"{dotted}.{n}".strip(".") for n in names} & modules
        if len(found) < len(names) and dotted in modules:
            found.add(dotted)
        return found

    for name, path in files.items():
        here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, (ast.Import, ast.ImportFrom)) else []
            if isinstance(node, ast.ImportFrom) and node.level >= 1:
                base = here[: len(here) - (node.level - 1)]
                graph[name] |= resolve(".".join(base + ((node.module or "").split(".") if node.module else [])), names)
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("rollergear_ros"):
                graph[name] |= resolve(".".join(node.module.split(".")[1:]), names)
            elif isinstance(node, ast.Import):
                graph[name] |= {a.name.split(".", 1)[1] for a in node.names
                                if a.name.startswith("rollergear_ros.")} & modules
            elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module" and node.args:
                arg = node.args[0]
                if isinstance(arg, ast.Constant) and str(arg.value).startswith("rollergear_ros."):
                    graph[name] |= {str(arg.value).split(".", 1)[1]} & modules
        graph[name].discard(name)
    return graph


def climbs(graph: dict[str, set[str]], wings: tuple[str, ...]) -> list[str]:
    """The imports that run back up: from a module to one in a wing above its own (a module outside
    the wings, such as ``__main__``, stands at the top)."""
    def rank(module: str) -> int:
        wing = module.split(".")[0]
        return wings.index(wing) if wing in wings else len(wings)

    return sorted(f"{m} -> {t}" for m, targets in graph.items() for t in targets if rank(t) > rank(m))


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_package_has_no_import_circle():
    graph = import_graph()
    # the graph sees imports: within a wing, across wings, lazy ones
    assert graph["core.model"] >= {"core.equations"} and "core.model" not in graph["core.params"]
    assert graph["ros.node"] >= {"core.estimator", "ros.recorder", "recordings.messages", "base.output_channels"}
    assert "calibration.report" in graph["cli.calibrate"]
    assert circles(graph) == []


def test_every_module_is_in_a_wing_and_no_import_runs_back_up():
    graph = import_graph()
    outside = sorted(m for m in graph if "." not in m and m not in WINGS and m not in ("", "__main__"))
    assert outside == [], f"modules outside the wings: {outside}"
    assert all(w in graph for w in WINGS)  # each wing is a package
    assert climbs(graph, WINGS) == []


def test_a_climb_is_found_where_there_is_one(tmp_path):
    for wing in ("low", "high"):
        (tmp_path / wing).mkdir()
        (tmp_path / wing / "__init__.py").write_text("")
    (tmp_path / "low" / "a.py").write_text("def f():\n    from ..high import b\n")
    (tmp_path / "high" / "b.py").write_text("from ..low.a import f\n")
    (tmp_path / "high" / "c.py").write_text("from . import b\n")
    graph = import_graph(tmp_path)
    assert graph["high.c"] == {"high.b"}
    assert climbs(graph, ("low", "high")) == ["low.a -> high.b"]
    assert circles(graph) == [["high.b", "low.a"]]


def test_a_circle_is_found_where_there_is_one(tmp_path):
    (tmp_path / "a.py").write_text("from .b import x\n")
    (tmp_path / "b.py").write_text("def f():\n    from . import c\n")
    (tmp_path / "c.py").write_text("import importlib\nimportlib.import_module('rollergear_ros.a')\n")
    (tmp_path / "d.py").write_text("from .a import x\n")
    assert circles(import_graph(tmp_path)) == [["a", "b", "c"]]


def cross_wing_imports(package: Path = PACKAGE) -> set[tuple[str, str, str]]:
    """``(wing, module, name)`` of every ``from <wing>.<module> import <name>`` in a module of another wing."""
    found = set()
    for path in package.rglob("*.py"):
        here = module_name(path, package).split(".")
        here = here if path.name == "__init__.py" else here[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                dotted = here[: len(here) - (node.level - 1)] + (node.module.split(".") if node.module else [])
            elif (node.module or "").startswith("rollergear_ros."):
                dotted = node.module.split(".")[1:]
            else:
                continue
            if len(dotted) == 2 and here[:1] != dotted[:1]:
                found |= {(dotted[0], dotted[1], a.name) for a in node.names}
    return found


def test_each_wing_has_a_face_that_holds_what_other_wings_import_and_imports_nothing_until_asked():
    """A wing's ``__all__`` is its API: every name another wing imports is on it (a function named as
    its module, such as ``calibrate.calibrate``, is reached through the module), each resolves to the
    object its module defines, and importing the wing imports none of its modules."""
    import importlib
    import inspect
    import subprocess
    import sys

    missing = sorted(f"{w}.{m}.{n}" for w, m, n in cross_wing_imports()
                     if n != m and n not in importlib.import_module(f"rollergear_ros.{w}").__all__)
    assert missing == [], f"imported across wings but not on the wing's face: {missing}"
    for wing in WINGS:
        package = importlib.import_module(f"rollergear_ros.{wing}")
        faces = getattr(package, "_FACE", {})
        assert sorted(package.__all__) == sorted(faces) or wing == "cli", wing
        for name, module in faces.items():
            obj = getattr(package, name)
            assert obj is getattr(importlib.import_module(f"rollergear_ros.{wing}.{module}"), name)
            if inspect.isclass(obj) or inspect.isfunction(obj):  # defined there, not passed on from elsewhere
                assert obj.__module__ == f"rollergear_ros.{wing}.{module}", f"{wing}.{name} is {obj.__module__}'s"
    # importing every wing loads none of their modules but the face's own helper (rclpy, scipy stay out)
    code = ("import sys, rollergear_ros as r\n"
            "for w in r.WINGS: __import__('rollergear_ros.' + w)\n"
            "print(sorted(m for m in sys.modules if m.startswith('rollergear_ros.') and m.count('.') > 1))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "['rollergear_ros.base.face']", loaded


def test_each_verb_is_a_module_of_its_own_that_imports_no_other_verb_and_no_rclpy_until_it_runs():
    """``cli/main.py`` is the table of verbs; each verb module takes shared options from ``cli/args.py``
    only, never from another verb (nor the table), and building the whole parser loads no rclpy."""
    import subprocess
    import sys

    from rollergear_ros.cli.main import VERBS

    graph = import_graph()
    verbs = {m for m in graph if m.startswith("cli.") and m not in ("cli", "cli.main", "cli.args")}
    assert {f"cli.{module.__name__.rsplit('.', 1)[1]}" for module in VERBS.values()} == verbs
    assert all(module.__name__.rsplit(".", 1)[1].rstrip("_") == name for name, module in VERBS.items()
               if name != "map") and VERBS["map"].__name__.endswith(".map")
    crossing = sorted(f"{v} -> {t}" for v in verbs for t in graph[v] if t in verbs or t == "cli.main")
    assert crossing == [], crossing
    assert graph["cli.main"] >= verbs
    code = ("import sys\nfrom rollergear_ros.cli.main import build_parser\nbuild_parser()\n"
            "print(sorted(m for m in ('rclpy', 'scipy', 'dask', 'matplotlib') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "[]", loaded
