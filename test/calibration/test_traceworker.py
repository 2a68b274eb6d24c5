"""The trace worker (no ROS): a spawned process off the node's cores and input path, at idle priority
until a trace is late, gone with the node that started it."""

from __future__ import annotations

import os

import pytest

from rollergear_ros.calibration.simulate import DeclaredEffect
from rollergear_ros.calibration.traceworker import TraceWorker, worker_cpus
from rollergear_ros.calibration.tracing import TraceRequest, trace

from traces import ONSET_S, node_samples, up_to


def test_the_worker_process_traces_and_returns_the_result(config):
    """A real spawned worker gives what :func:`trace` gives in this process."""
    samples, alarms, start = node_samples(config, [DeclaredEffect("drag_constant", {"c": 0.06})], 1)
    request = TraceRequest(up_to(samples, start + int((ONSET_S + 60.0) * 1e9)), config.to_flat(), "alarm", alarms[0])
    worker = TraceWorker()
    try:
        worker.submit(request)
        assert worker.busy or worker.future.done()
        worker.future.result(timeout=600)  # waits for the condition; 600 s only tells a hang
        done = worker.result()
        worker.submit(request)  # and one under way when it is closed
        manager = worker._pool._executor_manager_thread
    finally:
        worker.close()
    here = trace(request)
    assert not manager.is_alive()  # closed: nothing left to race the interpreter's exit
    assert done.verdict == here.verdict == "traced" and done.message == here.message
    # the worker's BLAS runs on one thread (this process's on every core): its sums may differ in the
    # last bits, never in a decision -- the same effects, their values equal to 1e-9 (the package's claim)
    assert [e["name"] for e in done.effects] == [e["name"] for e in here.effects]
    for ours, theirs in zip(done.effects, here.effects):
        assert ours["params"] == pytest.approx(theirs["params"], rel=1e-9, abs=0)
        assert ours["rms_contribution_nm"] == pytest.approx(theirs["rms_contribution_nm"], rel=1e-9, abs=0)
        for name, bounds in ours["ci95"].items():
            assert bounds == pytest.approx(theirs["ci95"][name], rel=1e-9, abs=0)
    assert worker.result() is None  # taken once


def test_the_worker_runs_off_the_cores_the_node_is_pinned_to():
    """The rule: the CPUs the node was not given, or the node's own when it has them all."""
    assert worker_cpus({1}, 2) == {0} and worker_cpus({0, 1}, 4) == {2, 3}
    assert worker_cpus({0, 1}, 2) == {0, 1} and worker_cpus({0}, 1) == {0}


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs two CPUs this process may run on")
def test_a_real_worker_of_a_pinned_node_runs_on_the_other_cores_at_idle_priority():
    """A spawned process inherits the node's affinity; the worker leaves the node's core."""
    allowed = os.sched_getaffinity(0)
    node_cpu = min(allowed)
    os.sched_setaffinity(0, {node_cpu})
    worker = TraceWorker()
    try:
        worker.start()
        cpus = worker._pool.submit(os.sched_getaffinity, 0).result(timeout=600)
        policy = worker._pool.submit(os.sched_getscheduler, 0).result(timeout=600)
    finally:
        worker.close()
        os.sched_setaffinity(0, allowed)
    assert node_cpu not in cpus and cpus <= set(range(os.cpu_count()))
    assert policy == os.SCHED_IDLE


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="needs the idle scheduling class")
def test_a_trace_under_way_too_long_goes_on_at_the_lowest_nice_level_and_the_worker_returns_to_idle(config):
    """On a machine whose cores are all busy the idle class gets next to nothing (a trace sat for
    minutes importing scipy beside three busy processes): once a request has been under way for the
    bound, the worker is a normal process at nice 19 until its result is taken out."""
    samples, alarms, start = node_samples(config, [DeclaredEffect("drag_constant", {"c": 0.06})], 1)
    request = TraceRequest(up_to(samples, start + int((ONSET_S + 60.0) * 1e9)), config.to_flat(), "alarm", alarms[0])
    worker = TraceWorker()
    try:
        worker.start()
        worker._pid.result(timeout=600)  # started: a condition; 600 s only tells a hang
        pid = worker.pid
        assert worker.running_s() is None and not worker.hurry_if_late(0.0)  # nothing under way
        worker.submit(request)
        assert worker.running_s() >= 0.0 and not worker.hurry_if_late(1e9)  # not late yet
        assert os.sched_getscheduler(pid) == os.SCHED_IDLE
        assert worker.hurry_if_late(0.0) and worker.hurried and not worker.hurry_if_late(0.0)  # moved once
        hurried = os.sched_getscheduler(pid), os.getpriority(os.PRIO_PROCESS, pid)
        worker.future.result(timeout=600)
        done = worker.result()
        after = os.sched_getscheduler(pid)
    finally:
        worker.close()
    assert hurried == (os.SCHED_OTHER, 19)
    assert after == os.SCHED_IDLE and not worker.hurried and worker.running_s() is None
    assert done.verdict == "traced"


#: a node's tracer where the system does not let a process leave the idle class: hurries a request
#: under way and says what became of it (the worker's process ids, the new one's scheduling, the result)
_UNPRIVILEGED_HURRY = """
import json, os, pickle, sys
from rollergear_ros.calibration.traceworker import TraceWorker, set_priority
with open(sys.argv[1], "rb") as fh:
    request = pickle.load(fh)
worker = TraceWorker()
worker.start()
worker._pid.result(timeout=600)
first = worker.pid
refused = not set_priority(first, hurried=True)
worker.submit(request)
hurried_now = worker.hurry_if_late(0.0)
worker._pid.result(timeout=600)
second = worker.pid
during = [os.sched_getscheduler(second) == os.SCHED_OTHER, os.getpriority(os.PRIO_PROCESS, second)]
worker.future.result(timeout=600)
done = worker.result()
after_idle = os.sched_getscheduler(second) == os.SCHED_IDLE
worker.close()
print(json.dumps({"refused": refused, "hurried_now": hurried_now, "replaced": second != first, "during": during,
                  "after_idle": after_idle, "verdict": done.verdict, "message": done.message}))
"""


def _without_cap_sys_nice() -> list[str] | None:
    """A command prefix under which this system refuses to let a process leave the idle class: root
    without CAP_SYS_NICE (setpriv), or nothing for a user whose RLIMIT_NICE is 0; None: neither."""
    import resource
    import shutil

    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        return [setpriv, "--bounding-set=-sys_nice", "--inh-caps=-sys_nice"] if setpriv else None
    return [] if resource.getrlimit(resource.RLIMIT_NICE)[0] == 0 else None


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE") or _without_cap_sys_nice() is None,
                    reason="needs the idle class and a way to run without CAP_SYS_NICE")
def test_where_the_idle_class_cannot_be_left_the_late_trace_starts_over_in_a_worker_at_nice_19(config, tmp_path):
    """Most users may not leave the idle class (RLIMIT_NICE 0): the worker that was late is replaced
    by one started at nice 19, the request runs again there and gives the result the trace gives."""
    import json
    import pickle
    import subprocess
    import sys

    samples, alarms, start = node_samples(config, [DeclaredEffect("drag_constant", {"c": 0.06})], 1)
    request = TraceRequest(up_to(samples, start + int((ONSET_S + 60.0) * 1e9)), config.to_flat(), "alarm", alarms[0])
    with (tmp_path / "request.pickle").open("wb") as fh:
        pickle.dump(request, fh)
    proc = subprocess.run([*_without_cap_sys_nice(), sys.executable, "-c", _UNPRIVILEGED_HURRY,
                           str(tmp_path / "request.pickle")], capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["refused"], "the premise: this process may not leave the idle class"
    assert got["hurried_now"] and got["replaced"] and got["during"] == [True, 19] and got["after_idle"]
    here = trace(request)
    assert got["verdict"] == here.verdict == "traced" and got["message"] == here.message


#: a "node" that starts the tracer's worker, says the worker's and the resource tracker's process ids
#: (argv[1] "started": once the worker has started and taken a long task; "spawned": at once, before the
#: worker has run a line of its own) and waits to be killed
_BUSY_NODE = """
import sys, time
from multiprocessing import resource_tracker
from rollergear_ros.calibration.traceworker import TraceWorker
worker = TraceWorker()
worker.start()
if sys.argv[1] == "started":
    worker._pid.result(timeout=600)
    busy = worker._pool.submit(time.sleep, 600)
print(*[p.pid for p in worker._pool._processes.values()], resource_tracker._resource_tracker._pid, flush=True)
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a process that has not ended (a zombie has ended)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _kill_node_and_wait_for_its_children(when: str) -> None:
    """Start :data:`_BUSY_NODE`, kill it (SIGKILL: no shutdown) and wait for the worker and the
    resource tracker to end; "spawned": the worker is held stopped from just after its spawn until
    the node is dead, so it starts its first line an orphan."""
    import signal
    import subprocess
    import sys
    import time

    node = subprocess.Popen([sys.executable, "-c", _BUSY_NODE, when], stdout=subprocess.PIPE, text=True)
    try:
        worker_pid, tracker_pid = map(int, node.stdout.readline().split())
        assert _alive(worker_pid) and _alive(tracker_pid)
        if when == "spawned":
            os.kill(worker_pid, signal.SIGSTOP)
        node.send_signal(signal.SIGKILL)
        node.wait(timeout=60)
        if when == "spawned":
            os.kill(worker_pid, signal.SIGCONT)
        # a condition: both gone (within a second here; an orphan starting up imports numpy and scipy
        # first, at whatever share of a core a busy machine leaves it)
        deadline = time.monotonic() + 600
        while (_alive(worker_pid) or _alive(tracker_pid)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(worker_pid), "the worker outlived the node"
        assert not _alive(tracker_pid), "the resource tracker outlived the node"
    finally:
        if node.poll() is None:
            node.kill()


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc")
def test_a_node_killed_mid_trace_takes_its_worker_and_the_resource_tracker_along():
    """A node killed (SIGKILL: no shutdown) while its worker traces: neither the worker (whose trace
    runs for minutes at the idle priority on a busy machine) nor the resource tracker stays behind."""
    _kill_node_and_wait_for_its_children("started")


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc")
def test_a_node_killed_while_its_worker_starts_takes_the_worker_along():
    """The worker is told which process is its node (not its parent at the time it looks, which is
    already another process when the node died during the worker's start-up)."""
    _kill_node_and_wait_for_its_children("spawned")
