"""The live tracer's analysis (no ROS): what the node's worker runs on the node's own samples.

The samples are a simulated gearbox's (the whole model plus a declared effect switched on at a
known time), estimated by the node's estimator and kept as the node keeps them
(:class:`TraceBuffer`: every estimate's inputs); the alarm is the estimator's own
change detector's.  The tracer is not told what was simulated.
"""

from __future__ import annotations


import numpy as np
import pytest

from rollergear_ros.calibration.simulate import DeclaredEffect
from rollergear_ros.calibration.tracing import SAMPLE_FIELDS, TraceBuffer, TraceRequest, change_point, trace
from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.params import validate

from helpers import with_effect
from traces import ONSET_S, node_samples, rms_residual, up_to


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
        buffer.add_values((1.0 * i, 2.0 * i, 3.0, 4.0, float("nan"), 5.0))
    arrays = buffer.snapshot()  # the last `capacity` samples, also before a trim
    assert list(arrays) == list(SAMPLE_FIELDS)
    assert arrays["t_ns"].dtype == np.int64 and (arrays["t_ns"] - 1_700_000_000_000_000_000).tolist() == [2, 3, 4]
    assert arrays["torque_nm"].tolist() == [2.0, 3.0, 4.0] and arrays["speed_rad_s"].tolist() == [4.0, 6.0, 8.0]
    assert np.isnan(arrays["temperature_c"]).all()
    buffer.trim()
    assert len(buffer) == 3 and len(buffer.values) == 18 and buffer.last_ns() == 1_700_000_000_000_000_004
    for name, values in buffer.snapshot().items():
        np.testing.assert_array_equal(values, arrays[name])
    buffer.add((9, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0))  # and appends go on after a trim
    assert buffer.snapshot()["t_ns"].tolist()[-1] == 9 and TraceBuffer(5).snapshot()["t_ns"].dtype == np.int64


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


def _trace_and_calibrate_window(bag, config):
    """``bag`` as the node's buffer holds it (every estimate's inputs), traced after an alarm at its
    start with the speed noise the node learned from the stream's start; and ``calibrate --start/--end``
    of the recording over the trace's window: the trace's result and calibrate's."""
    from rollergear_ros.calibration.calibrate import CalibrationSettings, calibrate
    from rollergear_ros.calibration.samples import load_samples
    from rollergear_ros.cli.args import window_time
    from rollergear_ros.recordings.messages import TopicMap
    from rollergear_ros.recordings.baginfo import inspect_bag
    from rollergear_ros.replay.inputs import paired_plan
    from rollergear_ros.replay.run import _learn_speed_noise, replay

    _, batches = replay(bag, config, show_progress=False, collect=True)
    samples = {f: np.concatenate([getattr(b, f) for b in batches]) for f in SAMPLE_FIELDS}
    info = inspect_bag(bag)
    plan, pairing, period = paired_plan(info, TopicMap())
    node_estimator = Estimator(config, pairing, period)
    _learn_speed_noise(node_estimator, info, plan, 100_000)  # what the node learned from the stream's start
    t = samples["t_ns"]
    alarm = int(t[200])
    result = trace(TraceRequest(samples, config.to_flat(), "alarm", alarm, 60.0, 20.0, None,
                                tuple(node_estimator.speed_noise.learned)))
    # the window as the trace names it on the recording's clock, read as calibrate's command line reads it
    _, start, _, end = result.calibrate_window.split()
    window = calibrate(load_samples([bag], config), config,
                       CalibrationSettings(start_s=window_time(start), end_s=window_time(end)))
    return result, window


def _same_effects(result, window) -> None:
    named = {e["name"]: e["params"] for e in result.effects}
    found = {e.name: e.params for e in window.effects}
    assert set(named) == set(found) and named, (named, found)
    for name, params in named.items():
        for key, value in params.items():
            assert value == pytest.approx(found[name][key], rel=1e-6), (name, key)


def test_a_trace_names_what_calibrate_names_on_the_same_samples_of_a_recording():
    """The README's flow: the bundled drag recording as the node's buffer holds it, traced after an
    alarm at its start with the node's learned speed noise -- and ``calibrate --start/--end`` of the
    recording over the trace's window: the same effects, the same values (the same samples, the same
    speed noise, the same selection)."""
    from helpers import BAGS, ROOT

    from rollergear_ros.core.params import load_config

    config = load_config(ROOT / "config" / "gearbox.yaml")
    result, window = _trace_and_calibrate_window(BAGS / "rig_map_drag.mcap", config)
    assert result.verdict == "traced", result.message
    _same_effects(result, window)


def test_a_trace_over_stretches_without_output_torque_is_calibrate_of_the_same_window(tmp_path):
    """The drag recording with its output torque lost for 3 s of every 15 (a torque flange's link
    dropping out), and friction with memory among the candidates: the trace steps the memory over
    every sample, as ``calibrate --start/--end`` does over the recording, and its window runs across
    the stretches (the inputs never paused) -- the same effects with the same values as calibrate's."""
    from mcap.reader import make_reader

    from bagtools import filtered_copy
    from helpers import BAGS, ROOT

    from rollergear_ros.core.params import load_config
    from rollergear_ros.recordings.messages import TopicMap

    src, output = BAGS / "rig_map_drag.mcap", TopicMap().output_torque
    with open(src, "rb") as fh:
        start_ns = make_reader(fh).get_summary().statistics.message_start_time
    bag, dropped = filtered_copy(src, tmp_path / "dropouts.mcap",
                                 lambda topic, t: topic != output or (t - start_ns) % 15_000_000_000 < 12_000_000_000)
    assert dropped > 1000
    config = load_config(ROOT / "config" / "gearbox.yaml")
    result, window = _trace_and_calibrate_window(bag, config)
    assert not any("starts after it" in note for note in result.notes), result.notes  # no gap: the inputs ran on
    assert result.window_ns[1] - result.window_ns[0] >= 55e9, result.window_ns
    assert result.verdict == "traced", result.message
    _same_effects(result, window)
