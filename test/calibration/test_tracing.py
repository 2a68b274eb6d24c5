"""The live tracer's analysis (no ROS): what the node's worker runs on the node's own samples.

The samples are a simulated gearbox's (the whole model plus a declared effect switched on at a
known time), estimated by the node's estimator and kept as the node keeps them
(:class:`TraceBuffer`: the samples with a measured output); the alarm is the estimator's own
change detector's.  The tracer is not told what was simulated.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate
from rollergear_ros.calibration.tracing import (SAMPLE_FIELDS, TraceBuffer, TraceRequest, TraceWorker, change_point,
                                                trace, worker_cpus)
from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.params import validate

from helpers import with_effect

ONSET_S = 50.0


def node_samples(config, effects=(), seed=0, onset_s=ONSET_S, rate_hz=200.0):
    """A simulated drive cycle estimated as the node estimates it: (the buffer's arrays, the alarms)."""
    rig = simulate(config, SimulationOptions("drive_cycle", rate_hz, seed, list(effects),
                                             step_change_at_s=onset_s if effects else None))
    est = Estimator(config).process_batch(rig.t_ns, rig.torque_meas_nm, rig.speed_rad_s, rig.out_torque_meas_nm,
                                          rig.out_speed_meas_rad_s, rig.temperature_c, breakdown=False)
    buffer = TraceBuffer(10 ** 6)
    for i in np.flatnonzero(np.isfinite(est.measured_loss_nm)):  # the node's _publish: measured output only
        buffer.add((int(est.t_ns[i]), float(est.torque_nm[i]), float(est.speed_rad_s[i]),
                    float(est.out_torque_nm[i]), float(est.out_speed_rad_s[i]), float(est.temperature_c[i])))
    return buffer.snapshot(), est.alarms_t_ns, int(rig.t_ns[0])


def rms_residual(config, samples, window_ns):
    """The RMS residual of ``config``'s estimator, started fresh, over the samples in ``window_ns``."""
    keep = (samples["t_ns"] >= window_ns[0]) & (samples["t_ns"] <= window_ns[1])
    est = Estimator(config).process_batch(*(samples[f][keep] for f in SAMPLE_FIELDS), breakdown=False)
    return float(np.sqrt(np.nanmean(est.residual_nm ** 2)))


def up_to(samples, end_ns):
    """What the buffer held at ``end_ns`` (the node traces before the recording is over)."""
    keep = samples["t_ns"] <= end_ns
    return {k: v[keep] for k, v in samples.items()}


@pytest.mark.parametrize(("effect", "seed"), [(DeclaredEffect("drag_constant", {"c": 0.06}), 1),
                                              (DeclaredEffect("drag_speed", {"c": 3e-4, "p": 1.4}), 2),
                                              (DeclaredEffect("drag_speed", {"c": 2e-4, "p": 1.2}), 3)])
def test_an_effect_appearing_mid_run_is_named_with_its_value_inside_its_interval(config, effect, seed):
    samples, alarms, start = node_samples(config, [effect], seed)
    assert alarms and alarms[0] > start + ONSET_S * 1e9  # the detector fired after the onset
    # what the buffer holds 60 s after the onset (a later trace slides the window after the change on)
    held = up_to(samples, start + int((ONSET_S + 60.0) * 1e9))
    result = trace(TraceRequest(held, config.to_flat(), "alarm", alarms[0], window_s=60.0))
    assert result.verdict == "traced", result.message
    assert abs(result.since_ns - (start + ONSET_S * 1e9)) <= 0.5e9  # the change point: within two blocks
    assert [e["name"] for e in result.effects] == [effect.name]
    for name, value in effect.params.items():
        low, high = result.effects[0]["ci95"][name]
        assert low <= value <= high, (name, value, result.effects[0])
    # the errors are those of the parameter sets compared, over the window after the change: the
    # candidate's as low as the declared effect's own (the noise floor), the running parameters' above
    declared = with_effect(config, effect.name, effect.params)
    floor = rms_residual(declared, samples, result.window_ns)
    assert result.error_candidate_nm <= 1.05 * floor
    assert result.error_now_nm >= 1.5 * floor
    assert result.error_now_nm == pytest.approx(rms_residual(config, samples, result.window_ns), rel=1e-12)
    candidate = validate(_flat(result.candidate_yaml))
    assert candidate.effects.enabled() == (effect.name,)


def _flat(text: str) -> dict:
    from rollergear_ros.core.params import flat_from_yaml_document
    import yaml

    return flat_from_yaml_document(yaml.safe_load(text))


def test_too_few_samples_after_the_change_is_inconclusive_and_says_what_it_needs(config):
    samples, alarms, start = node_samples(config, [DeclaredEffect("drag_constant", {"c": 0.06})], 1)
    result = trace(TraceRequest(up_to(samples, alarms[0] + int(5e9)), config.to_flat(), "alarm", alarms[0],
                                min_after_s=20.0))
    assert result.verdict == "inconclusive" and "needs 20 s" in result.message and not result.effects


@pytest.mark.parametrize("seed", range(10, 22))
def test_no_effect_is_named_on_a_gearbox_without_a_change(config, seed):
    """Twelve seeds of an unchanged gearbox: neither a trace at an alarm in the middle (as after a
    false alarm) nor a periodic trace names an effect."""
    samples, alarms, start = node_samples(config, (), seed)
    assert not alarms  # the detector stays quiet
    middle = start + int(60e9)
    for request in (TraceRequest(samples, config.to_flat(), "alarm", middle),
                    TraceRequest(samples, config.to_flat(), "period")):
        result = trace(request)
        assert result.verdict != "traced" and not result.effects and result.candidate_yaml is None, result.message


def test_an_effect_already_in_the_parameters_is_not_traced_again(config):
    effect = DeclaredEffect("drag_constant", {"c": 0.06})
    samples, _, start = node_samples(config, [effect], 1, onset_s=0.0)
    with_it = config.with_values({"effects.drag_constant.enabled": True, "effects.drag_constant.c_nm": 0.06})
    result = trace(TraceRequest(samples, with_it.to_flat(), "period"))
    assert result.verdict == "nothing_new", result.message


def test_the_change_point_is_the_least_squares_split_before_the_alarm():
    rng = np.random.default_rng(0)
    t = np.arange(20_000, dtype=np.int64) * 5_000_000  # 200 Hz, 100 s
    r = rng.normal(0, 0.01, len(t)) + np.where(t >= 40e9, 0.03, 0.0)
    assert abs(change_point(t, r, alarm_ns=int(45e9)) - 40e9) <= 0.25e9
    # never after the alarm: a later step is not this alarm's change
    r2 = rng.normal(0, 0.01, len(t)) + np.where(t >= 80e9, 0.05, 0.0)
    assert change_point(t, r2, alarm_ns=int(30e9)) <= 30e9


def test_the_buffer_keeps_the_latest_samples_in_time_order():
    buffer = TraceBuffer(3)
    for i in range(5):
        buffer.add_time(1_700_000_000_000_000_000 + i)  # as the node appends: two calls a sample
        buffer.add_values((1.0 * i, 2.0 * i, 3.0, 4.0, float("nan")))
    arrays = buffer.snapshot()  # the last `capacity` samples, also before a trim
    assert list(arrays) == list(SAMPLE_FIELDS)
    assert arrays["t_ns"].dtype == np.int64 and (arrays["t_ns"] - 1_700_000_000_000_000_000).tolist() == [2, 3, 4]
    assert arrays["torque_nm"].tolist() == [2.0, 3.0, 4.0] and arrays["speed_rad_s"].tolist() == [4.0, 6.0, 8.0]
    assert np.isnan(arrays["temperature_c"]).all()
    buffer.trim()
    assert len(buffer) == 3 and len(buffer.values) == 15 and buffer.last_ns() == 1_700_000_000_000_000_004
    for name, values in buffer.snapshot().items():
        np.testing.assert_array_equal(values, arrays[name])
    buffer.add((9, 9.0, 9.0, 9.0, 9.0, 9.0))  # and appends go on after a trim
    assert buffer.snapshot()["t_ns"].tolist()[-1] == 9 and TraceBuffer(5).snapshot()["t_ns"].dtype == np.int64


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
    assert done.verdict == here.verdict == "traced"
    assert done.effects == here.effects and done.message == here.message
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
from rollergear_ros.calibration.tracing import TraceWorker, set_priority
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
from rollergear_ros.calibration.tracing import TraceWorker
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


@pytest.mark.parametrize("onset_s", [12.0, 30.0])
def test_a_drag_that_appears_long_before_the_drive_reverses_is_named_once_the_reversal_is_in_the_window(
        config, onset_s):
    """The node's schedule (its tracer re-traces an inconclusive change every ``min_after_s`` of
    samples while its buffer holds the change point): a constant drag from 12 s (30 s) of a drive cycle
    that first reverses after 90 s cannot be told from a torque offset until then; the window after
    the change grows to 60 s, then slides on, and the drag is named with its value in its interval."""
    effect = DeclaredEffect("drag_constant", {"c": 0.06})
    samples, alarms, start = node_samples(config, [effect], 7, onset_s=onset_s)
    assert alarms
    due, results = alarms[0] + int(20e9), []
    while due <= samples["t_ns"][-1]:
        result = trace(TraceRequest(up_to(samples, due), config.to_flat(), "alarm", alarms[0]))
        results.append(result)
        assert result.window_ns[1] - result.window_ns[0] <= 60e9 and result.window_ns[1] <= due
        if result.verdict != "inconclusive":
            break
        due = result.window_ns[1] + int(20e9)
    assert [r.verdict for r in results[:-1]] == ["inconclusive"] * (len(results) - 1)
    assert all("reverse rotation" in r.message for r in results[:-1]) and len(results) >= 3
    last = results[-1]
    assert last.verdict == "traced", last.message
    assert abs(last.since_ns - (start + onset_s * 1e9)) <= 0.5e9
    assert last.window_ns[0] > last.since_ns  # slid on past the change point
    low, high = last.effects[0]["ci95"]["c"]
    assert [e["name"] for e in last.effects] == ["drag_constant"] and low <= 0.06 <= high


def test_a_trace_never_builds_its_window_across_a_gap_in_the_inputs(config):
    """Two recordings played one after the other (the rig paused 30 s between them): a gearbox with a
    drag, then one without.  Traced after the second has run for a while, the window holds the second
    alone -- the drag of the first is not named -- and the result says why it starts there."""
    first, _, _ = node_samples(config, [DeclaredEffect("drag_constant", {"c": 0.08})], 1, onset_s=0.0)
    second, _, _ = node_samples(config, (), 2)
    shift = int(first["t_ns"][-1]) + int(30e9) - int(second["t_ns"][0])
    second = up_to(second | {"t_ns": second["t_ns"] + shift}, int(second["t_ns"][0]) + shift + int(40e9))
    both = {k: np.concatenate([first[k], second[k]]) for k in first}
    start_of_second = int(second["t_ns"][0])
    for request in (TraceRequest(both, config.to_flat(), "period", window_s=120.0),
                    TraceRequest(both, config.to_flat(), "alarm", int(first["t_ns"][-1]) - int(5e9), window_s=120.0,
                                 min_after_s=20.0)):
        result = trace(request)
        assert result.window_ns[0] >= start_of_second and result.since_ns >= start_of_second, result.to_json()
        assert not result.effects and result.verdict != "traced", result.message
        assert any("paused for 30 s" in n and "starts after it" in n for n in result.notes), result.notes
    # the first recording alone, as the buffer held it before the second began: its drag is traced
    alone = trace(TraceRequest(first, config.to_flat(), "period", window_s=120.0))
    assert [e["name"] for e in alone.effects] == ["drag_constant"], alone.message


def test_the_last_gap_is_where_inputs_paused_or_went_back_in_time():
    from rollergear_ros.calibration.tracing import after_last_gap

    t = np.arange(0, 10_000_000_000, 5_000_000)  # 200 Hz for 10 s
    assert after_last_gap(t) == 0
    paused = np.concatenate([t, t[-1] + int(3e9) + t])
    assert after_last_gap(paused) == len(t)
    back = np.concatenate([t, t[:100]])  # the next recording's clock starts earlier
    assert after_last_gap(back) == len(t)
    slow = np.arange(0, 600_000_000_000, 1_000_000_000)  # 1 Hz: a 3 s step is 3 periods, no gap
    assert after_last_gap(np.append(slow, slow[-1] + 3_000_000_000)) == 0


def test_a_trace_names_what_calibrate_names_on_the_same_samples_of_a_recording():
    """The README's flow: the bundled drag recording as the node's buffer holds it, traced after an
    alarm at its start with the node's learned speed noise -- and ``calibrate --start/--end`` of the
    recording over the trace's window: the same effects, the same values (the same samples, the same
    speed noise, the same selection)."""
    from helpers import BAGS, ROOT

    from rollergear_ros.calibration.calibrate import CalibrationSettings, calibrate
    from rollergear_ros.calibration.samples import load_samples
    from rollergear_ros.core.params import load_config
    from rollergear_ros.recordings.messages import TopicMap
    from rollergear_ros.recordings.baginfo import inspect_bag
    from rollergear_ros.replay.inputs import paired_plan
    from rollergear_ros.replay.run import _learn_speed_noise, replay

    bag = BAGS / "rig_map_drag.mcap"
    config = load_config(ROOT / "config" / "gearbox.yaml")
    _, batches = replay(bag, config, show_progress=False, collect=True)
    samples = {f: np.concatenate([getattr(b, f) for b in batches]) for f in SAMPLE_FIELDS}
    measured = np.isfinite(samples["out_torque_nm"])
    samples = {f: v[measured] for f, v in samples.items()}
    info = inspect_bag(bag)
    plan, pairing, period = paired_plan(info, TopicMap())
    node_estimator = Estimator(config, pairing, period)
    _learn_speed_noise(node_estimator, info, plan, 100_000)  # what the node learned from the stream's start
    t = samples["t_ns"]
    alarm = int(t[200])
    result = trace(TraceRequest(samples, config.to_flat(), "alarm", alarm, 60.0, 20.0, None,
                                tuple(node_estimator.speed_noise.learned)))
    assert result.verdict == "traced", result.message
    data = load_samples([bag], config)
    first = int(data.t_ns[0])  # --start/--end count from the first sample analysed; --end is exclusive
    window = calibrate(data, config, CalibrationSettings(start_s=(result.window_ns[0] - first) * 1e-9,
                                                         end_s=(result.window_ns[1] - first) * 1e-9 + 1e-6))
    named = {e["name"]: e["params"] for e in result.effects}
    found = {e.name: e.params for e in window.effects}
    assert set(named) == set(found) and named, (named, found)
    for name, params in named.items():
        for key, value in params.items():
            assert value == pytest.approx(found[name][key], rel=1e-6), (name, key)
