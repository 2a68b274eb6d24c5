"""The live node's inputs taken in a thread of their own, with their message info (rclpy).

rclpy's ``EventsExecutor`` is the fast executor, but it gives a callback no message info (one
that asks for it fails with ``SystemError`` on this rclpy), and without the publishers' sequence
numbers a node that pairs by arrival cannot see what the middleware dropped: a best-effort,
keep-last history overwritten while the node was behind loses its oldest messages without a
trace (Fast DDS reports no "sample lost" for it), and first-in first-out pairing then joins one
topic's message from before the loss with another's from after it.  :class:`InputTaker` waits on
the input subscriptions in a thread of its own and takes every message with its info (publication
sequence number, timestamps); the node's timers and services stay on the executor.  The thread
takes round-robin -- one message of each ready subscription in turn -- so that a backlog is taken
in the order it was sent, as the events executor would, and holds ``lock`` while it delivers, so
that a parameter change on the executor never meets a half-pushed sample.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.type_support import check_is_valid_msg_type

#: the longest the thread waits before it looks whether the context was shut down (a signal)
WAIT_NS = 200_000_000


@dataclass
class _Input:
    handle: Any  # the rclpy C subscription
    msg_type: type
    raw: bool
    callback: Callable[[Any, dict], None]  # (message or its serialized bytes, message info)


class InputTaker:
    """Subscriptions whose messages a thread of their own takes, each with its message info."""

    def __init__(self, node, lock: threading.Lock) -> None:
        self._node = node
        self._lock = lock
        self._inputs: list[_Input] = []
        self._wake = GuardCondition(None, None, context=node.context)
        self._stopping = False
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None  #: what ended the thread, if a callback raised

    def subscribe(self, msg_type: type, topic: str, qos, callback: Callable[[Any, dict], None],
                  raw: bool = False):
        """Subscribe ``callback(message, info)`` to ``topic`` (relative names resolve in the node's
        namespace; remapping applies, as for ``Node.create_subscription``).  Returns the rclpy
        subscription handle (``get_publisher_count()``, ``get_topic_name()``)."""
        check_is_valid_msg_type(msg_type)  # also loads the type's support library
        with self._node.handle:
            handle = _rclpy.Subscription(self._node.handle, msg_type, topic, qos.get_c_qos_profile())
        self._inputs.append(_Input(handle, msg_type, raw, callback))
        return handle

    def take_round_robin(self) -> int:
        """Take every message queued now, one of each subscription in turn, and hand each to its
        callback.  Returns how many were taken."""
        taken = 0
        pending = self._inputs
        while pending:
            still = []
            for sub in pending:
                got = sub.handle.take_message(sub.msg_type, sub.raw)
                if got is None:
                    continue
                still.append(sub)
                taken += 1
                sub.callback(got[0], got[1])
            pending = still
        return taken

    def start(self, ready: Callable[[], bool] | None = None, first: Callable[[], None] | None = None) -> None:
        """Start taking (once); with ``ready``, only once it returns True (the messages wait in
        the middleware's queues meanwhile); ``first`` is called in the thread before it takes
        anything else (without ``lock``)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, args=(ready, first), name="inputs", daemon=True)
            self._thread.start()

    def _run(self, ready: Callable[[], bool] | None, first: Callable[[], None] | None) -> None:
        context = self._node.context
        try:
            while ready is not None and not ready() and not self._stopping and context.ok():
                time.sleep(0.002)
            if first is not None and not self._stopping and context.ok():
                first()
            with context.handle:
                wait_set = _rclpy.WaitSet(len(self._inputs), 1, 0, 0, 0, 0, context.handle)
            while not self._stopping and context.ok():
                wait_set.clear_entities()
                for sub in self._inputs:
                    wait_set.add_subscription(sub.handle)
                wait_set.add_guard_condition(self._wake.handle)
                wait_set.wait(WAIT_NS)
                if self._stopping:
                    return
                with self._lock:
                    self.take_round_robin()
        except BaseException as exc:  # noqa: BLE001 - handed to the main thread, which reports it
            if not self._stopping and context.ok():
                self.error = exc

    def stop(self) -> None:
        """Stop the thread (it finishes the round it is in) and wait for it."""
        self._stopping = True
        if self._thread is not None and self._thread.is_alive():
            self._wake.trigger()
            if self._thread is not threading.current_thread():
                self._thread.join(timeout=10)

    def destroy(self) -> None:
        """Stop, then release the subscriptions (before the node is destroyed)."""
        self.stop()
        for sub in self._inputs:
            sub.handle.destroy_when_not_in_use()
        self._inputs = []
        self._wake.destroy()
