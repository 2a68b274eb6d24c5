"""A wing's face: the names other wings use, imported from their module when first asked for.

Each wing's ``__init__`` lists its API as ``{name: module}`` (as rosbags curates ``__all__``) and
takes :func:`lazy_face`'s ``__all__``, ``__getattr__`` and ``__dir__`` (PEP 562): ``from
rollergear_ros.recordings import BagWriter`` works without importing the wing's every module (the
``ros`` wing's import rclpy, the calibration's scipy).  ``test/test_imports.py`` checks that every
name another wing imports is on its wing's face.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_face(package: str, exports: dict[str, str]
              ) -> tuple[list[str], Callable[[str], object], Callable[[], list[str]]]:
    """``(__all__, __getattr__, __dir__)`` of ``package`` whose public ``name`` lives in its module
    ``exports[name]``."""
    names = sorted(exports)

    def __getattr__(name: str) -> object:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    def __dir__() -> list[str]:
        return names

    return names, __getattr__, __dir__
