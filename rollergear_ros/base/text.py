"""Text from files shown on a terminal: escaped where it is not printable, bounded where it is long.

A recording's metadata or a parameter file's ``calibration.model_form`` is untrusted: escape codes in it
would clear the screen or recolour what follows, and a 900 KB segment would bury every line after it.
No rclpy import.
"""

from __future__ import annotations

__all__ = ["printable"]

#: text shown from a file is cut after this many characters, saying how many more there were
SHOWN_CHARS = 300


def printable(text: str, max_chars: int | None = SHOWN_CHARS) -> str:
    """``text`` with every non-printable character (escape codes, carriage returns) escaped as Python would,
    cut after ``max_chars`` characters (None: whole) with how many more there were."""
    more = ""
    if max_chars is not None and len(text) > max_chars:
        more = f"… ({len(text) - max_chars:,} characters more)"
        text = text[:max_chars]
    if not text.isprintable():
        text = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)
    return text + more
