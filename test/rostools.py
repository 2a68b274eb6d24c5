"""Real ROS 2 processes for tests: the node and the player as subprocesses, a private rclpy context."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from helpers import CONFIG, ROOT

from rollergear_ros.base.interface import MAX_QUEUE_DEPTH


class NodeProcess:
    """``loss_estimator`` in a subprocess, stopped with SIGINT (or another signal); one a failing
    test left running is killed after it (``conftest``), so it cannot answer the next test's player.
    Its output is read as it comes (a pipe nobody reads fills after 64 KB of log lines and then
    blocks the node in its logger: its inputs queue up and are lost)."""

    started: list[NodeProcess] = []

    def __init__(self, *params: str, params_file: Path | tuple[Path, ...] = CONFIG, args: tuple[str, ...] = ()) -> None:
        """``params_file``: one or several (``--params-file`` each, in order, as the README starts the node)."""
        cmd = [sys.executable, "-m", "rollergear_ros.ros.node", *args, "--ros-args"]
        for path in (params_file if isinstance(params_file, tuple) else (params_file,)):
            cmd += ["--params-file", str(path)]
        for p in params:
            cmd += ["-p", p]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                     env=dict(os.environ))
        self._out: list[str] = []
        self._err: list[str] = []
        self._readers = [threading.Thread(target=_drain, args=(stream, into), daemon=True)
                         for stream, into in ((self.proc.stdout, self._out), (self.proc.stderr, self._err))]
        for reader in self._readers:
            reader.start()
        NodeProcess.started.append(self)

    @property
    def stdout(self) -> str:
        return "".join(self._out)

    @property
    def stderr(self) -> str:
        return "".join(self._err)

    @classmethod
    def kill_leftovers(cls) -> None:
        for node in cls.started:
            if node.proc.poll() is None:
                node.proc.kill()
                node._wait_and_read()
        cls.started.clear()

    def _wait_and_read(self, timeout: float | None = None) -> None:
        self.proc.wait(timeout=timeout)
        for reader in self._readers:
            reader.join(timeout=30)

    def stop(self, sig: int = signal.SIGINT, timeout: float = 120.0) -> int:
        """Signal the node and wait until it has exited (closing its files takes seconds on a loaded
        slow machine: ``timeout`` only tells a hang from that)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            self._wait_and_read(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self._wait_and_read()
            raise AssertionError(f"node did not stop on {sig}:\n{self.stderr}") from None
        return self.proc.returncode


def _drain(stream, into: list[str]) -> None:
    """Read a process's output as it comes, into ``into``."""
    for line in stream:
        into.append(line)


class WatchProcess:
    """``rollergear watch`` in a subprocess; its output lines collected as it prints them."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "rollergear_ros", "watch", *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, cwd=ROOT, env=dict(os.environ))
        self.lines: list[str] = []
        self._errors: list[str] = []
        self._readers = [threading.Thread(target=self._read, args=(stream, into), daemon=True)
                         for stream, into in ((self.proc.stdout, self.lines), (self.proc.stderr, self._errors))]
        for reader in self._readers:
            reader.start()

    @staticmethod
    def _read(stream, into: list[str]) -> None:
        for line in stream:
            into.append(line.rstrip("\n"))

    @property
    def errors(self) -> str:
        return "\n".join(self._errors)

    def stop(self) -> int:
        """Ctrl-C, and its exit status once its output is read."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for reader in self._readers:
            reader.join(timeout=10)
        return self.proc.returncode


def play(bag: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "play", str(bag), *args], capture_output=True,
                          text=True, timeout=timeout, cwd=ROOT, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr
    return proc


@contextmanager
def ros_context():
    """A private rclpy Context with a probe node, spun in a thread by an EventsExecutor.

    The EventsExecutor takes a message for a few microseconds of Python where the
    SingleThreadedExecutor rebuilds its wait set each time (~3 k messages/s here, a few hundred on a
    slow, loaded machine): a probe must keep up with the node it watches.  ``spin_once`` with a
    timeout, because its ``spin()`` never returns on this rclpy version.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node

    ctx = Context()
    rclpy.init(context=ctx)
    node = Node(f"test_probe_{os.getpid()}", context=ctx)
    ex = EventsExecutor(context=ctx)
    ex.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set() and ctx.ok():
            ex.spin_once(timeout_sec=0.05)

    th = threading.Thread(target=spin, daemon=True)
    th.start()
    try:
        yield node
    finally:
        stop.set()
        th.join(timeout=5)
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


#: a reader's history holds at most this many samples (Fast DDS's default resource limit,
#: whatever larger depth is asked for): 5 s of backlog at 1 kHz
PROBE_DEPTH = MAX_QUEUE_DEPTH


#: nothing lost on either side: the inputs subscribed reliable (the player waits for the node), the
#: outputs offered as deep as Fast DDS keeps (a probe on a loaded machine that stalls for up to
#: PROBE_DEPTH messages has them resent)
LOSSLESS = ("node.input_qos:=reliable", f"node.output_depth:={PROBE_DEPTH}")


class FloatProbe:
    """Every ``std_msgs/Float64`` of one topic, as received: a reliable subscription with the
    deepest queue the middleware keeps, taking raw bytes (no per-message deserialisation)."""

    def __init__(self, probe_node, topic: str, msg_type=None) -> None:
        """``msg_type``: another message type, whose raw messages :attr:`raw` keeps (not :meth:`values`)."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64

        self.topic = topic
        self.raw: list[bytes] = []
        self.subscription = probe_node.create_subscription(
            msg_type or Float64, topic, self.raw.append,
            QoSProfile(depth=PROBE_DEPTH, reliability=ReliabilityPolicy.RELIABLE), raw=True)

    def wait_matched(self, timeout: float = 60.0) -> None:
        """Until the topic's publisher has been matched (the node publishes nothing before its
        inputs arrive, so nothing is missed once this returns)."""
        assert wait_for(lambda: self.subscription.get_publisher_count() > 0, timeout), \
            f"no publisher of {self.topic} matched in {timeout} s"

    def __len__(self) -> int:
        return len(self.raw)

    def values(self):
        import numpy as np

        raw = list(self.raw)
        assert all(r[:2] == b"\x00\x01" and len(r) >= 12 for r in raw), "not little-endian CDR Float64"
        return np.frombuffer(b"".join(r[4:12] for r in raw), dtype="<f8")


def call_until_answered(client, request, timeout: float = 120.0, first_resend_s: float = 1.0):
    """The answer to an idempotent service ``request`` (set a parameter), sent again while none came.

    A service's answer can be lost without an error on the client's side: the server's reply writer
    may not yet have matched this client's reply reader when it answers (discovery is asymmetric;
    rmw_fastrtps waits 100 ms, then drops the reply and rclpy only warns -- ros2/ros2#1253), which
    a loaded machine makes likely for the first call after ``wait_for_service``.  So the request is
    sent again after 1, 2, 4 … s without an answer; the first answer to any of them is returned.
    ``timeout`` only tells a node that never answers from a slow one."""
    deadline = time.monotonic() + timeout
    futures = []
    wait = first_resend_s
    while True:
        futures.append(client.call_async(request))
        if wait_for(lambda: any(f.done() for f in futures), min(wait, max(deadline - time.monotonic(), 0.0))):
            return next(f for f in futures if f.done()).result()
        assert time.monotonic() < deadline, f"no answer to {type(request).__name__} in {timeout} s"
        wait *= 2


def wait_for(predicate, timeout: float, step: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()
