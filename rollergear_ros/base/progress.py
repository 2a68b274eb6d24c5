"""Progress bars that move by time: a thread redraws them several times a second.

A command's work does not always report often (a replay batch of 100 000 messages, one step of
``calibrate``'s selection, a player pacing a recording at its own rate), and a tqdm bar redraws
only when it is updated, so it stood still for seconds.  :class:`TimedProgress` reads a counter
(any callable) and the current stage from a thread every :data:`REDRAW_S`, so the count, the rate,
the elapsed time and the stage move on their own; the work itself only bumps a number.  Bars are
drawn on a terminal only (stderr a TTY), never into logs or pipes.  No rclpy import.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable

__all__ = ["REDRAW_S", "TimedProgress", "progress_wanted"]

#: seconds between redraws
REDRAW_S = 0.2
#: bar size on a terminal that reports none (tqdm would draw an empty bar)
FALLBACK_SIZE = {"ncols": 100, "nrows": 24}


def _terminal_columns() -> int:
    """Columns of the terminal stderr is on (0: it reports none, e.g. a pseudo-terminal never sized)."""
    try:
        return os.get_terminal_size(sys.stderr.fileno()).columns
    except (OSError, ValueError, AttributeError):
        return 0


def progress_wanted(enabled: bool | None = None) -> bool:
    """``enabled``, or where not given: whether stderr is a terminal."""
    return sys.stderr.isatty() if enabled is None else bool(enabled)


class TimedProgress:
    """A bar on stderr that a thread redraws every :data:`REDRAW_S` from ``read()`` (the count done).

    ``total``: the count at the end (None: unknown, the bar shows count and rate); ``stage``: set
    :attr:`stage` to show what is being done.  Use as a context manager; with ``enabled`` false it
    does nothing (and costs nothing).
    """

    def __init__(self, desc: str, total: float | None = None, unit: str = "it", read: Callable[[], float] | None = None,
                 enabled: bool | None = None, unit_scale: bool = True) -> None:
        self.desc = desc
        self.total = total
        self.unit = unit
        self.unit_scale = unit_scale
        self.enabled = progress_wanted(enabled)
        self.stage = ""
        self._count = 0
        self._read = read if read is not None else (lambda: self._count)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bar = None

    def set_total(self, total: float | None) -> None:
        """The count at the end, once known."""
        self.total = total
        if self._bar is not None:
            self._bar.total = total

    def update(self, n: float = 1) -> None:
        """Count ``n`` more done (when no ``read`` was given)."""
        self._count += n

    def start(self) -> TimedProgress:
        """Draw the bar and start redrawing it (nothing when not enabled)."""
        if self.enabled and self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, unit=self.unit, unit_scale=self.unit_scale, desc=self.desc,
                             file=sys.stderr, **({} if _terminal_columns() else FALLBACK_SIZE))
            self._thread = threading.Thread(target=self._redraw_loop, name=f"progress {self.desc}", daemon=True)
            self._thread.start()
        return self

    __enter__ = start

    def _redraw(self, refresh: bool = True) -> None:
        bar = self._bar
        if self.stage:
            bar.set_postfix_str(self.stage, refresh=False)
        bar.n = self._read()
        if refresh:
            bar.refresh()

    def _redraw_loop(self) -> None:
        while not self._stop.wait(REDRAW_S):
            self._redraw()

    def close(self, final: bool = True) -> None:
        """Stop redrawing; ``final``: draw the last count first (not after an error)."""
        if self._bar is None:
            return
        self._stop.set()
        self._thread.join()
        if final:
            self._redraw(refresh=False)  # close() draws the last state
        self._bar.close()
        self._bar = None

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(final=exc_type is None)
