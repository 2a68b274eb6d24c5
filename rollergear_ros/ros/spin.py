"""Spinning the node: the executor a ``node.executor`` names, and the signals that end the spin."""

from __future__ import annotations

import signal
import sys
import threading

from rclpy.executors import SingleThreadedExecutor

__all__ = ["make_executor", "stop_on_signals"]


def make_executor(kind: str, context=None):
    """``single_threaded`` (message info: pairs by publisher timestamps) or ``events`` (faster)."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def stop_on_signals() -> threading.Event:
    """Make SIGINT and SIGTERM set the returned event, and nothing else.

    The node's main loop ends when it is set, and the files are closed.  A handler that raises
    (Python's ``KeyboardInterrupt``, which rclpy's own handler chains to) lands wherever the main
    thread happens to be -- inside an input callback, between the recording of a message and its
    estimate, it leaves a recording that replays to one estimate more than the node published.
    A further signal while the node closes its files is reported and does not interrupt that."""
    stop = threading.Event()

    def handler(signum: int, _frame) -> None:
        if stop.is_set():
            print(f"loss_estimator: {signal.Signals(signum).name} again: still closing the recordings "
                  "(SIGKILL ends at once, leaving an MCAP without its index)", file=sys.stderr)
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
    return stop
