"""Signals that stop a long loop between batches, so that its files stay whole.  No rclpy import."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["GracefulStop", "children_spared_interrupts"]


@contextmanager
def children_spared_interrupts() -> Iterator[None]:
    """SIGINT ignored while worker processes are started inside the block: they inherit the
    disposition (Python keeps an ignored SIGINT ignored), so a Ctrl-C to the terminal's process group
    -- this process's to handle, which stops them -- never ends them with a traceback of their own.
    A Ctrl-C while they start is ignored too (a second or two).  Outside the main thread: nothing."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


class GracefulStop:
    """SIGINT/SIGTERM set a flag that long loops check between batches (files stay consistent).

    Installed before any output is opened, so a signal at any moment leaves complete files.  A
    second signal stops at once (``KeyboardInterrupt``) — but not inside :meth:`critical`, where
    one batch's estimates and inputs are written together: there it waits for the section's end.
    Only active in the main thread.
    """

    def __init__(self, announce: bool = True) -> None:
        import signal
        import threading

        self.announce = announce
        self.requested = False
        self._forced = False
        self._critical = 0
        self._old: dict[int, object] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)

    def _handler(self, signum, frame) -> None:  # noqa: ARG002
        if not self.requested:
            self.requested = True
            if self.announce:  # at once: the batch under way and the outputs' closing take a moment
                print("rollergear: interrupted: finishing the batch under way and closing the outputs with "
                      "what was processed (again to stop at once)", file=sys.stderr, flush=True)
        elif self._critical:
            self._forced = True
        else:
            raise KeyboardInterrupt

    @contextmanager
    def critical(self, raise_after: bool = True) -> Iterator[None]:
        """A section a second signal does not cut in two (it stops at the section's end)."""
        self._critical += 1
        try:
            yield
        finally:
            self._critical -= 1
        if raise_after and self._forced and not self._critical:
            raise KeyboardInterrupt

    def restore(self) -> None:
        import signal

        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()
