"""docs/development.md's table of modules is what the modules' docstrings say (``scripts/layout-table``)."""

from __future__ import annotations

import subprocess
import sys

from helpers import ROOT

SCRIPT = ROOT / "scripts" / "layout-table"


def _table() -> str:
    return subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, check=True).stdout


def test_the_module_table_in_the_development_guide_is_generated_from_the_docstrings():
    proc = subprocess.run([sys.executable, str(SCRIPT), "--check"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_every_module_of_the_package_has_a_row():
    table = _table()
    for path in (ROOT / "rollergear_ros").glob("*/*.py"):
        name = f"`{path.parent.name}/`" if path.name == "__init__.py" else f"`{path.parent.name}/{path.stem}`"
        assert f"| {name} |" in table, name


def test_a_module_added_without_a_docstring_is_refused_and_a_stale_table_is_found(tmp_path):
    """The check fails on a table that lacks a module, and a module without a docstring stops the generator."""
    import shutil

    copy = tmp_path / "repo"
    for part in ("rollergear_ros", "docs", "scripts"):
        shutil.copytree(ROOT / part, copy / part, ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    script = copy / "scripts" / "layout-table"
    (copy / "rollergear_ros" / "core" / "newpart.py").write_text('"""A new part of the core."""\n')
    stale = subprocess.run([sys.executable, str(script), "--check"], capture_output=True, text=True)
    assert stale.returncode == 1 and "scripts/layout-table --write" in stale.stderr
    subprocess.run([sys.executable, str(script), "--write"], check=True)
    assert "| `core/newpart` | A new part of the core. |" in (copy / "docs" / "development.md").read_text()
    (copy / "rollergear_ros" / "core" / "bare.py").write_text("X = 1\n")
    bare = subprocess.run([sys.executable, str(script)], capture_output=True, text=True)
    assert bare.returncode != 0 and "core/bare.py has no docstring" in bare.stderr
