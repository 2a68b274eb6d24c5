"""One exception family for what users get wrong: every ``rollergear`` command turns these -- and
only these -- into one line ``rollergear: error: …`` and exit status 2 (``loss_estimator``:
``loss_estimator: error: …``).  Anything else is a defect and surfaces as a traceback.
"""

from __future__ import annotations

from typing import Any


class RollergearError(Exception):
    """Base of the errors a user can fix: the message says what is wrong and where."""


class ParameterError(RollergearError, ValueError):
    """A parameter value is out of range, of the wrong type, unknown, or inconsistent."""

    def __init__(self, name: str, value: Any, allowed: str) -> None:
        self.name = name
        self.value = value
        self.allowed = allowed
        super().__init__(f"parameter '{name}' = {value!r} is invalid: {allowed}")

    @classmethod
    def broken_file(cls, path: str, exc: Exception) -> ParameterError:
        """A parameter file that is not YAML: one line with the file, line and column."""
        err = cls("<file>", path, "")
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else path
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        context = getattr(exc, "context", None)
        err.args = (f"{where}: not valid YAML: {problem}" + (f" ({' '.join(str(context).split())})"
                                                             if context else ""),)
        return err


class BagError(RollergearError):
    """A recording cannot be used: missing topics, wrong types, not a ROS 2 MCAP, unreadable, or
    too little of what a command needs (e.g. no measured output torque to calibrate with)."""


class InputFileError(RollergearError):
    """An input file other than a recording (a CSV of operating points, a table) cannot be used."""


class UsageError(RollergearError):
    """A command-line request that cannot be served (a bad option value, an unknown name)."""


__all__ = ["BagError", "InputFileError", "ParameterError", "RollergearError", "UsageError"]
