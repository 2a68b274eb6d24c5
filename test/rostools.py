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

from conftest import CONFIG, ROOT


class NodeProcess:
    """``loss_estimator`` in a subprocess, stopped with SIGINT (or another signal)."""

    def __init__(self, *params: str, params_file: Path = CONFIG, args: tuple[str, ...] = ()) -> None:
        cmd = [sys.executable, "-m", "rollergear_ros.node", *args, "--ros-args", "--params-file", str(params_file)]
        for p in params:
            cmd += ["-p", p]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                     env=dict(os.environ))
        self.stdout = self.stderr = ""

    def stop(self, sig: int = signal.SIGINT, timeout: float = 20.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            self.stdout, self.stderr = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.stdout, self.stderr = self.proc.communicate()
            raise AssertionError(f"node did not stop on {sig}:\n{self.stderr}")
        return self.proc.returncode


def play(bag: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "play", str(bag), *args], capture_output=True,
                          text=True, timeout=timeout, cwd=ROOT, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr
    return proc


@contextmanager
def ros_context():
    """A private rclpy Context with a node and an executor spinning in a thread."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    ctx = Context()
    rclpy.init(context=ctx)
    node = Node(f"test_probe_{os.getpid()}", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
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


def wait_for(predicate, timeout: float, step: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()
