"""One exception family for what users get wrong: every ``rollergear`` command turns these -- and
only these -- into one line ``rollergear: error: …`` and exit status 2 (``loss_estimator``:
``loss_estimator: error: …``).  Anything else is a defect and surfaces as a traceback.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


class RollergearError(Exception):
    """Base of the errors a user can fix: the message says what is wrong and where."""


class ParameterError(RollergearError, ValueError):
    """A parameter value is out of range, of the wrong type, unknown, or inconsistent."""

    def __init__(self, name: str, value: Any, allowed: str) -> None:
        self.name = name
        self.value = value
        self.allowed = allowed
        super().__init__(f"parameter '{name}' = {_shown(value)} is invalid: {allowed}")

    @classmethod
    def broken_file(cls, path: str, problem: Exception) -> ParameterError:
        """A parameter file that cannot be read as YAML: one line, with file, line and column
        where known (``problem`` is a :class:`~.safeyaml.YamlProblem`)."""
        err = cls("<file>", path, "")
        err.args = (str(problem),)
        return err


def _shown(value: Any, limit: int = 80) -> str:
    """``repr(value)``, shortened: an error line never echoes a huge value."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit - 20]}… ({len(text):,} characters)"


class BagError(RollergearError):
    """A recording cannot be used: missing topics, wrong types, not a ROS 2 MCAP, unreadable, or
    too little of what a command needs (e.g. no measured output torque to calibrate with)."""


class InputFileError(RollergearError):
    """An input file other than a recording (a CSV of operating points, a table) cannot be used."""


class UsageError(RollergearError):
    """A command-line request that cannot be served (a bad option value, an unknown name)."""


#: a command whose input lost more than this share of its recording to damage (of its messages or
#: its bytes) says so in an error line and exits with :data:`DAMAGED_EXIT` -- its outputs hold what
#: was readable; one that could read nothing at all is a :class:`BagError` (exit 2, no output)
MAX_LOST_SHARE = 0.01
DAMAGED_EXIT = 3


def damaged_exit(source: str, share: float, what: str) -> int:
    """0, or -- the input lost more than :data:`MAX_LOST_SHARE` to damage -- an error line on stderr
    (``what``: what the command did with the rest) and :data:`DAMAGED_EXIT`."""
    import sys

    if share <= MAX_LOST_SHARE:
        return 0
    print(f"rollergear: error: {source}: {100 * share:.1f} % of the recording unreadable (more than "
          f"{100 * MAX_LOST_SHARE:g} %): {what}", file=sys.stderr)
    return DAMAGED_EXIT


def lost_share(spans: Sequence[Any], total_bytes: int, message_count: int) -> float:
    """The share of a recording its damaged spans (:class:`~recordings.fastmcap.DamagedSpan`) cost:
    the larger of its bytes' and its messages' share."""
    damaged_bytes, messages_lost = damage_totals(spans)
    by_bytes = damaged_bytes / total_bytes if total_bytes > 0 else 0.0
    by_messages = messages_lost / message_count if message_count > 0 else 0.0
    return min(1.0, max(by_bytes, by_messages))


def damage_totals(spans: Sequence[Any]) -> tuple[int, int]:
    """Bytes and messages (those a damaged chunk's index tells) the damaged spans lost."""
    return sum(s.end_byte - s.start_byte for s in spans), sum(s.messages_lost or 0 for s in spans)


__all__ = ["BagError", "DAMAGED_EXIT", "InputFileError", "MAX_LOST_SHARE", "ParameterError", "RollergearError",
           "UsageError", "damage_totals", "damaged_exit", "lost_share"]
