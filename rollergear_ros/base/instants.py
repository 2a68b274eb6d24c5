"""Instants on a recording's own clock, to the nanosecond: ISO 8601 text and back.

A sample's stamp is int64 ns since 1970 (UTC).  ``datetime`` keeps microseconds only, so the fraction of
a second is carried as an integer of its own: ``2026-12-07T10:00:01.234567891Z`` names one stamp exactly,
and a trace's window printed this way is the window ``calibrate --start/--end`` analyses.  No rclpy import.
"""

from __future__ import annotations

import datetime
import re

__all__ = ["Instant", "iso_ns", "parse_iso_ns"]

_ISO = re.compile(r"^\s*(\d{4}-\d{2}-\d{2})[T ](\d{2}:\d{2}(?::\d{2})?)(?:[.,](\d{1,9}))?"
                  r"\s*(Z|z|[+-]\d{2}(?::?\d{2})?)?\s*$")


class Instant(int):
    """An instant on a recording's clock (ns since 1970), told from a count of seconds by its type."""

    def __str__(self) -> str:
        return iso_ns(self)


def iso_ns(t_ns: int) -> str:
    """``t_ns`` (ns since 1970) as UTC ISO 8601 with nine decimals: ``2026-12-07T10:00:01.234567891Z``."""
    seconds, fraction = divmod(int(t_ns), 10**9)
    when = datetime.datetime.fromtimestamp(seconds, datetime.UTC)
    return f"{when:%Y-%m-%dT%H:%M:%S}.{fraction:09d}Z"


def parse_iso_ns(text: str) -> int | None:
    """An ISO 8601 date-time (``T`` or a space; seconds optional; up to nine decimals; ``Z``, an offset, or
    none for UTC) as ns since 1970; None where ``text`` is not one."""
    m = _ISO.match(text)
    if not m:
        return None
    day, clock, fraction, zone = m.groups()
    zone = "+00:00" if zone in (None, "Z", "z") else zone
    try:
        when = datetime.datetime.fromisoformat(f"{day}T{clock}{zone}")
    except ValueError:
        return None
    return int(when.timestamp()) * 10**9 + int((fraction or "0").ljust(9, "0"))
