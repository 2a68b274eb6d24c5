"""Small YAML files (parameter files, channel maps) read within bounds.

A parameter file is a few kilobytes of plain mappings.  What is not — a billion-laughs file whose
aliases expand to gigabytes, a 100 000-deep nesting that exhausts the recursion limit, ``/dev/zero``
or a FIFO that never ends, bytes that are not UTF-8 — is refused with one line saying where,
before PyYAML builds anything.  Anchors and aliases are refused outright: ROS 2's own parameter
parser (rcl) rejects them too, so a file the CLI accepted would not start the node.  No rclpy.
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

MAX_BYTES = 1 << 20  #: a parameter file or channel map larger than this is not one
MAX_DEPTH = 32  #: mappings and sequences nested deeper than this are refused


@dataclass
class YamlProblem(Exception):
    """Why a YAML file was refused; ``where`` is ``path:line:column`` when a place is known."""

    where: str
    message: str

    def __str__(self) -> str:
        return f"{self.where}: {self.message}"


def read_text(path: str | Path) -> str:
    """The file's text: a regular file of at most :data:`MAX_BYTES` bytes of UTF-8."""
    path = Path(path)
    if not path.exists():
        raise YamlProblem(str(path), "does not exist")
    if not path.is_file():
        raise YamlProblem(str(path), "is not a regular file" + (" (a directory)" if path.is_dir() else ""))
    with path.open("rb") as fh:
        data = fh.read(MAX_BYTES + 1)  # a size that stat() under-reports (/proc) is bounded too
    if len(data) > MAX_BYTES:
        raise YamlProblem(str(path), f"larger than {MAX_BYTES // 1024} KiB: not a parameter file or channel map")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise YamlProblem(f"{path}:{line}:{column}", f"not UTF-8 text (byte 0x{data[exc.start]:02x})") from None


def _where(path: str | Path, mark) -> str:
    return f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)


def check_structure(text: str, path: str | Path) -> None:
    """Refuse anchors, aliases, nesting beyond :data:`MAX_DEPTH` and a key given twice in one
    mapping (PyYAML would keep the later one without a word) by walking the parser's events
    (iterative: no recursion, nothing composed)."""
    # one entry per open collection: None for a sequence; for a mapping [keys seen, next is a key]
    open_: list[list | None] = []
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None):
            raise YamlProblem(_where(path, event.start_mark),
                              "anchors and aliases (&name, *name) are not supported (ROS 2 refuses them too)")
        if isinstance(event, yaml.CollectionEndEvent):
            open_.pop()
            continue
        if not isinstance(event, yaml.NodeEvent):
            continue
        parent = open_[-1] if open_ else None
        if parent is not None:  # a node inside a mapping: a key, then its value
            keys, is_key = parent
            if is_key and isinstance(event, yaml.ScalarEvent):
                if event.value in keys:
                    raise YamlProblem(_where(path, event.start_mark), f"the key {event.value!r} is given twice in "
                                      f"one mapping (first on line {keys[event.value]})")
                keys[event.value] = event.start_mark.line + 1
            parent[1] = not is_key
        if isinstance(event, yaml.CollectionStartEvent):
            if len(open_) >= MAX_DEPTH:
                raise YamlProblem(_where(path, event.start_mark), f"nested deeper than {MAX_DEPTH} levels")
            open_.append([{}, True] if isinstance(event, yaml.MappingStartEvent) else None)


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader reading ``1e-6`` and ``1e6`` as numbers, as ROS 2's parameter parser
    does (YAML 1.1 wants a dot in a float: ``1.0e-6``; rcl, and YAML 1.2, do not)."""


_Loader.add_implicit_resolver("tag:yaml.org,2002:float",
                              re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
                              list("-+0123456789."))


def _ros_float(loader: yaml.SafeLoader, node: yaml.ScalarNode):
    """A number as ROS 2's parameter parser reads it (``strtod``, refused on ``ERANGE``): one that overflows
    to infinity or underflows below the smallest normal double (``1e-320``, ``1e999``) is text there, so it
    is text here -- the node and every command give one file one verdict."""
    value = loader.construct_yaml_float(node)
    text = node.value.strip().lower().replace("_", "")
    if text.lstrip("+-") in (".inf", ".nan"):
        return value
    digits = text.lstrip("+-").split("e")[0].replace(".", "")
    if math.isinf(value) or (value != 0.0 and abs(value) < sys.float_info.min) or (value == 0.0 and digits.strip("0")):
        return node.value
    return value


_Loader.add_constructor("tag:yaml.org,2002:float", _ros_float)


def loads(text: str) -> Any:
    """A YAML document's text as :func:`load` reads it (numbers as ROS 2 reads them)."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader with one more number form


def load(path: str | Path) -> Any:
    """The YAML document in ``path``, within the bounds above; :class:`YamlProblem` otherwise
    (also for YAML syntax errors, with line and column)."""
    text = read_text(path)
    try:
        check_structure(text, path)
        return loads(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        context = getattr(exc, "context", None)
        raise YamlProblem(_where(path, mark), "not valid YAML: " + problem
                          + (f" ({' '.join(str(context).split())})" if context else "")) from None


__all__ = ["MAX_BYTES", "MAX_DEPTH", "YamlProblem", "check_structure", "load", "loads", "read_text"]
