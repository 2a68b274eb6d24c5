"""The trace worker: one process beside the node that runs :func:`~.tracing.trace`, off its input path.

Spawned (a process that runs rclpy must not fork), on the CPUs the node was not pinned to, in the
idle scheduling class (a waking thread of the node takes the core from it at once) -- or, when a
trace has waited longer than :data:`IDLE_PRIORITY_S` on a busy machine, at the lowest nice level.
It ignores Ctrl-C (the node stops it) and exits when the node that started it is gone.  No rclpy
import: the worker process never loads ROS.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from concurrent.futures import Future, ProcessPoolExecutor

from ..base.stopping import children_spared_interrupts
from .tracing import TraceRequest, TraceResult, trace

__all__ = ["IDLE_PRIORITY_S", "TraceWorker", "set_priority", "worker_cpus"]


def _ready() -> int:
    """The worker's first task: its process id (unpickling it imported this module and what it imports)."""
    return os.getpid()


def worker_cpus(node_cpus: set[int], cpu_count: int) -> set[int]:
    """The CPUs the worker runs on: those the node was not given, when there are any (a node pinned
    to a core, its input path on it alone), else the node's own."""
    return (set(range(cpu_count)) - node_cpus) or node_cpus


def _worker_start(node_pid: int, node_cpus: tuple[int, ...] = (), idle: bool = True) -> None:
    """The worker process keeps off the node's input path: on the CPUs the node was not pinned to
    (:func:`worker_cpus`; a spawned process inherits the node's affinity, and a worker on the node's
    only core delays its inputs by milliseconds whatever its priority), and scheduled when nothing else
    wants a core (``SCHED_IDLE``: a waking thread of the node takes the core from it at once), else at
    the lowest nice level.  On a machine whose cores are all busy the idle class gets next to nothing,
    so a trace under way for longer than :data:`IDLE_PRIORITY_S` goes on at the lowest nice level
    (:meth:`TraceWorker.hurry_if_late`; ``idle`` False: a worker started there).  Ctrl-C is the
    node's: the worker ignores it (the node stops it).  A node that dies without stopping it (killed,
    crashed) takes it along: the worker watches its parent (:func:`_exit_with_parent`), named by the
    node (``node_pid``): a node that died while the worker started up is no longer the parent the
    worker would find."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent(node_pid)
    if node_cpus and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, worker_cpus(set(node_cpus), os.cpu_count() or 1))
        except OSError:  # a CPU outside this process's cpuset: stay where the node is
            pass
    if not (idle and set_priority(0, hurried=False)):
        set_priority(0, hurried=True)


#: a trace under way for longer than this [s] leaves the idle class for the lowest nice level: on a
#: machine whose cores are all busy, a share of ~1.5 % of a core beside each busy nice-0 process (the
#: node itself competes with those at the full weight), so the trace is late by minutes, not forever
IDLE_PRIORITY_S = 30.0


def set_priority(pid: int, hurried: bool) -> bool:
    """Schedule process ``pid`` (0: this one) in the idle class (``SCHED_IDLE``: only on a core
    nothing else wants), or ``hurried``: as a normal process at the lowest nice level (19).  False
    when the system refused or has no idle class: a process may leave the idle class only with
    ``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` of at least 1 (``ulimit -e``; 0 for most users)."""
    try:
        if hurried:
            os.setpriority(os.PRIO_PROCESS, pid, 19)
            if getattr(os, "SCHED_IDLE", None) is not None and os.sched_getscheduler(pid) == os.SCHED_IDLE:
                os.sched_setscheduler(pid, os.SCHED_OTHER, os.sched_param(0))
        else:
            os.sched_setscheduler(pid, os.SCHED_IDLE, os.sched_param(0))
        return True
    except (AttributeError, OSError):
        return False


#: how often the worker looks whether the node that started it is still there [s]
PARENT_CHECK_S = 0.5


def _exit_with_parent(parent_pid: int) -> None:
    """Exit this process as soon as ``parent_pid`` is no longer its parent (the parent died and the
    process was handed to another): a thread that looks every :data:`PARENT_CHECK_S`.  A trace under
    way would otherwise run to its end, minutes at the idle priority on a busy machine, with the
    resource tracker the worker holds open beside it."""
    import threading

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_S)
        os._exit(0)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


class TraceWorker:
    """One worker process (spawned: a process that runs rclpy must not fork) tracing one request at
    a time; started by :meth:`start` (the node: at start-up, before its inputs) or the first request."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._pid: Future | None = None  #: the worker's process id, once it has started
        self.future: Future | None = None
        self._request: TraceRequest | None = None  #: the request under way
        self._submitted_at: float | None = None  #: time.monotonic() of the request under way
        self.hurried = False  #: the request under way runs at nice 19, not in the idle class

    @property
    def busy(self) -> bool:
        return self.future is not None and not self.future.done()

    @property
    def pid(self) -> int | None:
        """The worker's process id (None before it has started)."""
        started = self._pid is not None and self._pid.done() and self._pid.exception() is None
        return self._pid.result() if started else None

    def running_s(self) -> float | None:
        """Seconds since the request not yet taken out by :meth:`result` was submitted (None: none)."""
        return None if self.future is None or self._submitted_at is None else time.monotonic() - self._submitted_at

    def hurry_if_late(self, after_s: float = IDLE_PRIORITY_S) -> str | None:
        """Once a request has been under way for ``after_s``, move the worker from the idle class to
        the lowest nice level (:func:`set_priority`) until its result is taken out -- where the
        system does not let a process leave the idle class, replace the worker by one started at
        that level and submit the request to it again (the trace starts over).  What was done, when
        it was done now (for the node to say), else None."""
        running = self.running_s()
        if self.hurried or running is None or running < after_s or self.pid is None:
            return None
        self.hurried = True
        if set_priority(self.pid, hurried=True):
            return "it goes on at the lowest nice level"
        request, submitted_at = self._request, self._submitted_at
        self.close()
        self.start(idle=False)
        self.submit(request)
        self._submitted_at, self.hurried = submitted_at, True
        return "begun again in a worker at the lowest nice level (this system lets no process leave the idle class)"

    def start(self, idle: bool = True) -> None:
        """Start the process now and let it import what a trace needs: the first trace then costs
        the caller no process start (tens of milliseconds of the interpreter, imports included);
        ``idle`` False: at the lowest nice level from the start (:func:`_worker_start`)."""
        if self._pool is None:
            # one BLAS thread: the worker must leave the other core to the node
            for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
                os.environ.setdefault(var, "1")
            node_cpus = tuple(sorted(os.sched_getaffinity(0))) if hasattr(os, "sched_getaffinity") else ()
            with children_spared_interrupts():  # the worker is spawned with Ctrl-C ignored, from its first instruction
                self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                 initializer=_worker_start, initargs=(os.getpid(), node_cpus, idle))
                self._pid = self._pool.submit(_ready)

    def submit(self, request: TraceRequest) -> None:
        self.start()
        self.future = self._pool.submit(trace, request)
        self._request, self._submitted_at = request, time.monotonic()

    def result(self) -> TraceResult | Exception | None:
        """The finished trace (its exception if it failed), once; None while none is done.  A
        worker that was hurried goes back to the idle class."""
        if self.future is None or not self.future.done():
            return None
        future, self.future, self._request, self._submitted_at = self.future, None, None, None
        if self.hurried and self.pid is not None:
            set_priority(self.pid, hurried=False)
        self.hurried = False
        exc = future.exception()
        return exc if exc is not None else future.result()

    def close(self) -> None:
        """Stop the worker now (a trace under way is dropped: nothing of it was published)."""
        if self._pool is None:
            return
        processes = list(getattr(self._pool, "_processes", {}).values())
        manager = getattr(self._pool, "_executor_manager_thread", None)
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        # the pool's manager thread closes its wake-up pipe as it ends; one still ending when the
        # interpreter exits races the exit hook's wake-up ("Bad file descriptor" on the node's stderr)
        if manager is not None:
            manager.join(timeout=30)
        self._pool = self.future = self._pid = self._request = self._submitted_at = None
        self.hurried = False
