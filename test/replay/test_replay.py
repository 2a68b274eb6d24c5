"""Replay of recorded bags: outputs, two readers, rerun read-back, bad input, interrupts."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rollergear_ros.recordings.bagwriter import BagWriter
from rollergear_ros.recordings.messages import TopicMap, encode_float64
from rollergear_ros.recordings.baginfo import inspect_bag
from rollergear_ros.base.errors import BagError, UsageError
from rollergear_ros.base.interface import MessageType
from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.model import LossModel, rotation_sign
from rollergear_ros.core.params import config_to_yaml, load_config
from rollergear_ros.replay.run import replay
from rollergear_ros.outputs import review
from rollergear_ros.outputs.review import read_rrd_series
from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, read_truth, simulate, write_rig_bag

from bagtools import float_series, read_mcap_ros2, read_rosbags
from helpers import BAGS, ROOT, partial_files, run_cli

BUNDLED = sorted(BAGS.glob("*.mcap"))
T = TopicMap()


def test_bundled_bags_exist_and_are_small():
    names = {p.name for p in BUNDLED}
    assert {"rig_map.mcap", "rig_map_drag.mcap", "drive_cycle_joint_states.mcap", "warmup.mcap"} <= names
    for p in BUNDLED:
        assert p.stat().st_size <= 5 * 1024 * 1024


def _inputs_from_rosbags(msgs: dict, joint: str = "motor") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Torque/speed per sample of the motor (or the output) from the bag, read independently
    (Float64 or JointState)."""
    torque, speed = (T.motor_torque, T.motor_speed) if joint == "motor" else (T.output_torque, T.output_speed)
    if torque in msgs:
        t, tq = float_series(msgs, torque)
        _, w = float_series(msgs, speed)
        return t, tq, w
    t, ms = msgs[T.joint_states]
    k = list(ms[0].name).index(joint)
    return t, np.array([m.effort[k] for m in ms]), np.array([m.velocity[k] for m in ms])


def _check_streamable_with_provenance(out, bag, config) -> None:
    """An output MCAP a streaming reader can take front to back (messages in log-time order across
    topics, chunks one after another in time) that says what made it: the provenance record and
    rosbag2's own metadata record, with the outputs' offered QoS."""
    import yaml
    from mcap.reader import make_reader

    from rollergear_ros.core.params import load_config

    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        times = np.array([m.log_time for _, _, m in reader.iter_messages(log_time_order=False)])
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert np.all(np.diff(times) >= 0), "output messages not in log-time order"
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) > 1 and all(b.message_start_time >= a.message_end_time for a, b in zip(chunks, chunks[1:]))
    prov = meta["rollergear_provenance"]
    assert Path(prov["source"]) == Path(bag).resolve() and int(prov["source_bytes"]) == Path(bag).stat().st_size
    assert prov["version"] and prov["accepted_effects"] == (", ".join(config.effects.enabled()) or "none")
    params = out.with_name("provenance.yaml")
    params.write_text(prov["parameters"])
    assert load_config(params) == config  # the parameters, whole
    info = yaml.safe_load(meta["rosbag2"]["serialized_metadata"])["rosbag2_bagfile_information"]
    assert info["message_count"] == len(times)
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
           for t in info["topics_with_message_count"]}
    assert yaml.safe_load(qos[T.loss_torque])[0]["reliability"] == 1  # reliable, as the node offers it


@pytest.mark.slow
@pytest.mark.parametrize("bag", BUNDLED, ids=lambda p: p.stem)
def test_replay_bundled_bag_matches_model_on_its_inputs(bag, tmp_path, config):
    out, rrd = tmp_path / "out.mcap", tmp_path / "out.rrd"
    # a speed noise given (not learned): the sign's width is one number from the first sample on
    config = config.with_values({"estimator.speed_noise_rad_s": 0.02})
    params = tmp_path / "params.yaml"
    params.write_text(config_to_yaml(config))
    proc = run_cli("replay", str(bag), "--out", str(out), "--rrd", str(rrd), "--params", str(params))
    assert "energy lost" in proc.stdout and "skipped: none" in proc.stdout

    inputs = read_rosbags(bag)
    t_in, tq, w = _inputs_from_rosbags(inputs)
    lm = LossModel(config.gearbox, config.estimator.min_torque_for_efficiency_nm,
                   config.estimator.min_speed_for_efficiency_rad_s)
    expect = lm.evaluate(tq, w, breakdown=False)
    # the estimator's sign runs smoothly through standstill (tanh within a few speed-noise widths)
    signed = expect.loss_magnitude_nm * rotation_sign(w, tq, config.estimator.speed_noise_rad_s)

    for reader in (read_rosbags, read_mcap_ros2):
        got = reader(out)
        for topic in (T.loss_torque, T.loss_power, T.efficiency, T.residual_torque):
            assert topic in got, f"{topic} missing ({reader.__name__})"
        t_loss, loss = float_series(got, T.loss_torque)
        assert len(loss) == len(tq), "one estimate per input sample"
        np.testing.assert_array_equal(t_loss, t_in)
        np.testing.assert_allclose(loss, signed, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(float_series(got, T.loss_power)[1], expect.loss_power_w, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(float_series(got, T.efficiency)[1], expect.efficiency, rtol=1e-12, equal_nan=True)
        # the inputs are carried into the output bag unchanged
        for topic in inputs:
            assert len(got[topic][0]) == len(inputs[topic][0])

    _check_streamable_with_provenance(out, bag, config)
    series = read_rrd_series(rrd)
    t_r, v_r = series[review.LOSS_TORQUE]
    np.testing.assert_array_equal(t_r, t_in)
    np.testing.assert_allclose(v_r, signed, rtol=1e-12)
    # efficiency in % as everywhere else
    np.testing.assert_allclose(series[review.EFFICIENCY][1], 100 * expect.efficiency, rtol=1e-12, equal_nan=True)
    # the breakdown: the terms that are not always 0 (tb, fg without a ball pressure force), adding up
    drawn = {e.rsplit("/", 1)[1][:-3] for e in series if e.startswith(review.BREAKDOWN + "/")}
    assert drawn == set(lm.nonzero_terms())
    assert ({"tb", "fg"} & drawn) == ({"tb", "fg"} if config.gearbox.Fg_n else set())
    bd = sum(series[f"{review.BREAKDOWN}/{k}_nm"][1] for k in drawn)
    np.testing.assert_allclose(bd, expect.loss_torque_nm, rtol=1e-9)
    assert review.RESIDUAL in series and review.DRIVE_SPEED in series
    # the measured output with the inputs, on the axes of its unit
    t_out, out_torque, out_speed = _inputs_from_rosbags(inputs, "output")
    for entity, values in ((review.OUTPUT_TORQUE, out_torque), (review.OUTPUT_SPEED, out_speed)):
        t_o, v_o = series[entity]
        np.testing.assert_array_equal(t_o, t_out)
        np.testing.assert_array_equal(v_o, values)


@pytest.mark.parametrize("batch_size", [100_000, 300])
@pytest.mark.parametrize("bag", sorted(BAGS.glob("*.mcap")), ids=lambda p: p.stem)
def test_time_slices_of_a_recording_add_up_to_its_replay(bag, batch_size, config):
    """A long recording replayed in four time slices apart (fleet tasks): counts, sums and the
    estimates themselves equal one replay of the whole -- the slices' lead-in and lead-out pair
    the samples at their edges as the whole replay does, also where a read batch ends at an edge.

    The bundled parameters accept no effect, so there is no adaptation to start afresh; change
    alarms are each slice's own (a slice's detector starts from the parameter file).
    """
    whole, estimates = replay(bag, config, show_progress=False, collect=True)
    info = inspect_bag(bag)
    edges = [info.start_ns + (info.end_ns - info.start_ns) * i // 4 for i in range(1, 4)]
    slices = [replay(bag, config, show_progress=False, collect=True, window_ns=w, batch_size=batch_size)
              for w in zip([None, *edges], [*edges, None])]
    for field in ("samples", "estimated", "input_messages", "residual_samples", "efficiency_samples"):
        assert sum(getattr(s, field) for s, _ in slices) == getattr(whole, field), field
    assert {k: sum(s.skipped[k] for s, _ in slices) for k in whole.skipped} == whole.skipped
    for field in ("energy_in_j", "energy_lost_j", "energy_in_measured_j", "energy_lost_measured_j"):
        assert sum(getattr(s, field) for s, _ in slices) == pytest.approx(getattr(whole, field), rel=1e-12), field
    assert (slices[0][0].start_ns, slices[-1][0].end_ns) == (whole.start_ns, whole.end_ns)
    for name in ("t_ns", "torque_nm", "speed_rad_s", "loss_torque_nm", "residual_nm"):
        joined = np.concatenate([getattr(b, name) for _, bs in slices for b in bs])
        np.testing.assert_array_equal(joined, np.concatenate([getattr(b, name) for b in estimates]), err_msg=name)
    assert all(s.samples > 0 for s, _ in slices)


def test_time_slices_pair_the_samples_that_straddle_their_edges(tmp_path, config):
    """Speed and the outputs logged 3 ms after the motor torque (100 Hz; the tolerance is 4 ms),
    a chunk per message, and slice edges 1 ms after a torque message: each sample at an edge is
    estimated once, by the slice its torque lies in -- its partners are read by that slice's
    lead-out, the next slice's lead-in reads the torque (even when it sits in a chunk of its own).
    Samples skipped (a NaN torque) just before an edge count in the slice they lie in only."""
    n, period = 1200, 10_000_000
    t = 1_000_000_000 + np.arange(n, dtype=np.int64) * period
    rng = np.random.default_rng(5)
    path = tmp_path / "spread.mcap"
    edge_samples = range(60, n, 240)
    nan_samples = {k - d for k in edge_samples for d in (3, 5)}
    with BagWriter(path, chunk_size=1) as bw:  # a chunk per message: a torque may end one
        for k in range(n):
            torque = math.nan if k in nan_samples else rng.uniform(5, 50)
            bw.write_raw(T.motor_torque, MessageType.FLOAT64, int(t[k]), encode_float64([torque])[0])
            for topic, value in ((T.motor_speed, rng.uniform(50, 300)), (T.output_torque, rng.uniform(10, 100)),
                                 (T.output_speed, rng.uniform(10, 100))):
                bw.write_raw(topic, MessageType.FLOAT64, int(t[k]) + 3_000_000, encode_float64([value])[0])
    whole, estimates = replay(path, config, show_progress=False, collect=True)
    assert whole.estimated == n - len(nan_samples) and whole.skipped["unpaired"] == 0
    assert whole.skipped["non_finite"] == len(nan_samples)
    edges = [int(t[k]) + 1_000_000 for k in edge_samples]
    slices = [replay(path, config, show_progress=False, collect=True, window_ns=w, batch_size=50)
              for w in zip([None, *edges], [*edges, None])]
    assert [s.skipped["unpaired"] for s, _ in slices] == [0] * len(slices)
    assert [s.skipped["non_finite"] for s, _ in slices] == [2] * (len(slices) - 1) + [0]
    assert sum(s.estimated for s, _ in slices) == whole.estimated
    joined = np.concatenate([b.loss_torque_nm for _, bs in slices for b in bs])
    np.testing.assert_array_equal(joined, np.concatenate([b.loss_torque_nm for b in estimates]))


def test_a_time_slice_is_replayed_without_outputs(tmp_path, config):
    with pytest.raises(UsageError, match="without outputs"):
        replay(BAGS / "rig_map.mcap", config, out_mcap=tmp_path / "x.mcap", window_ns=(None, 10))


@pytest.mark.parametrize("batch_size", [100_000, 997])
def test_summary_picture_holds_the_replay_in_bounded_bins(tmp_path, config, batch_size):
    """The summary trace of a replay: every estimate counted once in its time bin, the bins' sums,
    minima and maxima those of the estimates (whatever the batches, across the bins' doubling),
    at most 2 x TIME_BINS bins; the PNG is written and the CLI writes it beside --out."""
    from rollergear_ros.replay.plot import SummaryTrace

    bag = BAGS / "rig_map_drag.mcap"
    _, batches = replay(bag, config, show_progress=False, collect=True)
    trace = SummaryTrace(sum(len(b.t_ns) for b in batches), bins=50)
    for b in batches:
        for part in range(0, len(b.t_ns), batch_size):
            trace.add(b.select(np.arange(len(b.t_ns)) // batch_size == part // batch_size))
    t_ns = np.concatenate([b.t_ns for b in batches])
    loss = np.abs(np.concatenate([b.loss_torque_nm for b in batches]))
    residual = np.concatenate([b.residual_nm for b in batches])
    assert trace.width_ns > 10_000_000 and trace.count["loss_nm"].sum() == len(loss)
    bins = (t_ns - t_ns[0]) // trace.width_ns
    assert bins.max() < 100
    for key, v in (("loss_nm", loss), ("residual_nm", residual)):
        ok = np.isfinite(v)
        t_s, mean, low, high = trace.series(key)
        expect = [v[ok][bins[ok] == i] for i in np.unique(bins[ok])]
        np.testing.assert_allclose(mean, [e.mean() for e in expect], rtol=1e-9)
        np.testing.assert_array_equal(low, [e.min() for e in expect])
        np.testing.assert_array_equal(high, [e.max() for e in expect])
    speed, torque = trace.operating_points()
    assert 0 < len(speed) <= 20_000 and len(speed) == len(torque)

    summary, _ = replay(bag, config, show_progress=False, summary_png=tmp_path / "s.png")
    assert summary.summary_png == str(tmp_path / "s.png")
    png = tmp_path / "s.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 50_000
    proc = run_cli("replay", str(bag), "--out", str(tmp_path / "est.mcap"), "--no-progress")
    assert f"summary picture: {tmp_path / 'est.png'}" in proc.stdout and (tmp_path / "est.png").exists()


def test_summary_picture_draws_the_estimate_over_the_measured_loss_alarms_and_speeds_in_rpm(config):
    """The estimate is drawn over the measured loss (it was hidden under it), each change alarm is a
    line on every time axis at its sample time, and the map's speeds are in rpm like ``map``'s."""
    import matplotlib.pyplot as plt

    from rollergear_ros.base.interface import RPM_PER_RAD_S
    from rollergear_ros.replay.plot import SummaryTrace, summary_figure

    _, batches = replay(BAGS / "rig_map_drag.mcap", config, show_progress=False, collect=True)
    alarms = sorted({t for b in batches for t in b.alarms_t_ns})
    assert alarms  # the undeclared drag trips the detector
    trace = SummaryTrace(sum(len(b.t_ns) for b in batches))
    for b in batches:
        trace.add(b)
    fig = summary_figure(trace, config, "test")
    try:
        time_axes = fig.axes[:3]  # loss, efficiency, residual (output torque measured); then the map
        assert time_axes[-1].get_xlabel().startswith("time since the start")
        lines = {ln.get_gid(): ln for ln in fig.axes[0].get_lines()}
        assert lines["loss_nm"].get_zorder() > lines["measured_nm"].get_zorder()
        t0 = min(int(b.t_ns[0]) for b in batches if len(b.t_ns))
        for ax in time_axes:
            marked = [ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_gid() == "alarm"]
            np.testing.assert_allclose(marked, [(t - t0) * 1e-9 for t in alarms], rtol=0, atol=1e-9)
        ax_map = next(ax for ax in fig.axes if ax.get_xlabel() == "drive speed [rpm]")
        speed, torque = trace.operating_points()
        np.testing.assert_allclose(ax_map.collections[-1].get_offsets()[:, 0], speed * RPM_PER_RAD_S)
    finally:
        plt.close(fig)


def test_rrd_has_review_blueprint(tmp_path):
    from rerun.chunk import RrdReader

    rrd = tmp_path / "x.rrd"
    replay(BAGS / "rig_map.mcap", load_config(), rrd=rrd, show_progress=False)
    reader = RrdReader(str(rrd))
    assert reader.recordings() and reader.blueprints(), "recording and its blueprint are in the file"


def test_change_alarms_are_events_on_the_rerun_timeline(tmp_path, config):
    """The drag the code was not told of trips the change detector: the alarm is a WARN event at
    the alarm's sample time, and every entity lives in the tree of its unit."""
    rrd = tmp_path / "x.rrd"
    summary, batches = replay(BAGS / "rig_map_drag.mcap", config, rrd=rrd, show_progress=False, collect=True)
    alarms = sorted({t for b in batches for t in b.alarms_t_ns})
    assert summary.alarms == len(alarms) >= 1
    events = review.read_rrd_events(rrd)
    assert [(t, level) for t, level, text in events if "change alarm" in text] == [(t, "WARN") for t in alarms]
    units = {"/inputs/torque": "N·m", "/inputs/speed": "rad/s", "/loss/torque": "N·m", "/loss/power": "W",
             "/efficiency": "%", "/residual": "N·m"}
    for entity in read_rrd_series(rrd):
        tree = next((u for u in units if entity.startswith(u + "/")), None)
        if tree is not None and entity in review.SERIES:
            assert f"[{units[tree]}]" in review.SERIES[entity], entity


def test_residual_equals_measured_minus_model(tmp_path, config):
    """Residual topic = measured loss (from the bag's four channels) − model."""
    out = tmp_path / "o.mcap"
    replay(BAGS / "rig_map_drag.mcap", config, out_mcap=out, show_progress=False)
    msgs = read_rosbags(out)
    _, tq = float_series(msgs, T.motor_torque)
    _, w = float_series(msgs, T.motor_speed)
    _, tq_o = float_series(msgs, T.output_torque)
    _, w_o = float_series(msgs, T.output_speed)
    meas = (tq * w - tq_o * w_o) / np.abs(w)
    model = LossModel(config.gearbox).loss_magnitude(tq, w)
    ok = np.abs(w) >= config.estimator.min_speed_for_efficiency_rad_s
    ok[0] = False  # the first sample arrives before the output channel is known
    _, res = float_series(msgs, T.residual_torque)
    np.testing.assert_allclose(res, (meas - model)[ok], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("effect", ["drag_constant", "drag_speed:c=4e-4,p=1.3", "load_dependent:c=3e-3,q=1.2",
                                    "viscosity_temperature:B=800", "torque_offset:b=0.08", "torque_gain:g=0.01"])
def test_simulated_measured_loss_is_model_plus_declared_effect(effect, tmp_path, config):
    eff = DeclaredEffect.parse(effect)
    opts = SimulationOptions(profile="warmup", rate_hz=50, seed=7, effects=[eff], torque_noise_nm=0.005,
                             speed_noise_rad_s=0.0)
    rig = simulate(config, opts)
    path = tmp_path / "sim.mcap"
    write_rig_bag(rig, opts, path)
    assert read_truth(path)["effects"][0]["name"] == eff.name
    msgs = read_rosbags(path)
    _, tq = float_series(msgs, T.motor_torque)
    _, w = float_series(msgs, T.motor_speed)
    _, tq_o = float_series(msgs, T.output_torque)
    _, w_o = float_series(msgs, T.output_speed)
    theta = np.interp(np.arange(len(tq)), np.arange(0, len(tq), 5)[:len(msgs[T.oil_temperature][1])],
                      [m.temperature for m in msgs[T.oil_temperature][1]])
    ok = np.abs(w) > 5
    meas = (tq[ok] * w[ok] - tq_o[ok] * w_o[ok]) / np.abs(w[ok])
    tt, ww, th = rig.torque_true_nm[ok], w[ok], theta[ok]
    lm = LossModel(config.gearbox)
    p = eff.params
    sg = np.sign(ww)
    declared = {
        "drag_constant": lambda: p["c"] + 0 * ww,
        "drag_speed": lambda: p["c"] * np.abs(ww) ** p["p"],
        "load_dependent": lambda: p["c"] * np.abs(tt) ** p["q"],
        "viscosity_temperature": lambda: lm.fr_part(tt, ww) * (
            np.exp(p["B"] / (th + p["C"]) - p["B"] / (p["theta_ref"] + p["C"])) ** 0.66 - 1),
        "torque_offset": lambda: p["b"] * sg,
        "torque_gain": lambda: p["g"] * tt * sg,
    }[eff.name]()
    expected = lm.loss_magnitude(tt, ww) + declared
    err = meas - expected
    # what is left is sensor noise: zero mean, sigma ~ torque noise (x sqrt 2)
    assert abs(err.mean()) < 0.002
    assert err.std() < 0.02
    assert np.sqrt(np.mean(declared ** 2)) > 5 * err.std(), "the effect stands out of the noise"


def test_streaming_path_equals_batch_path(config):
    """The node's per-message path gives the replay's numbers (incl. online adaptation)."""
    cal = config.with_values({"effects.drag_speed.enabled": True, "effects.drag_speed.c": 1e-4,
                              "effects.drag_speed.p": 1.4, "effects.drag_constant.enabled": True,
                              "effects.drag_constant.c_nm": 0.01})
    _, batches = replay(BAGS / "rig_map_drag.mcap", cal, show_progress=False, collect=True)
    loss = np.concatenate([x.loss_torque_nm for x in batches])
    res = np.concatenate([x.residual_nm for x in batches])
    est = Estimator(cal)
    msgs = read_rosbags(BAGS / "rig_map_drag.mcap")
    events = []
    chan = {T.motor_torque: "motor_torque", T.motor_speed: "motor_speed", T.output_torque: "output_torque",
            T.output_speed: "output_speed"}
    for topic, (ts, ms) in msgs.items():
        for t, m in zip(ts.tolist(), ms):
            if topic in chan:
                events.append((t, list(chan).index(topic), chan[topic], m.data))
            else:
                events.append((t, -1, "oil_temperature", m.temperature))
    events.sort(key=lambda e: (e[0], e[1]))
    out = []
    for t, _, ch, v in events:
        out.extend(est.push(ch, t, v))
    out.extend(filter(None, (est.process(s) for s in est.sync.flush())))
    assert len(out) == len(loss)
    np.testing.assert_allclose([e.loss_torque_nm for e in out], loss, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose([e.residual_nm for e in out], res, rtol=1e-7, atol=1e-9, equal_nan=True)


# ------------------------------------------------------------------------------- bad input
def _write_bag(path: Path, series: dict[str, tuple[str, np.ndarray]], n: int = 200, rate: float = 100.0):
    t = (1_000_000_000 + np.arange(n) * (1e9 / rate)).astype(np.int64)
    with BagWriter(path) as bw:
        for i in range(n):
            for topic, (type_name, values) in series.items():
                if type_name == MessageType.FLOAT64:
                    bw.write_raw(topic, MessageType.FLOAT64, int(t[i]), encode_float64(values[i:i + 1])[0])
                else:
                    bw.write_message(topic, type_name, int(t[i]), values[i])


def test_missing_topics_error_lists_what_the_bag_has(tmp_path):
    p = tmp_path / "m.mcap"
    _write_bag(p, {"/other/torque": (MessageType.FLOAT64, np.ones(10))}, n=10)
    proc = run_cli("replay", str(p), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "/other/torque [std_msgs/msg/Float64]" in proc.stderr and T.motor_torque in proc.stderr


def _mcap_with_payloads(path: Path, messages: list[tuple[str, int, bytes]], float64_text: bytes = b"float64 data\n",
                        joint_states: bool = False) -> None:
    """An MCAP written by the ``mcap`` library with the given (topic, log time, payload) in this order."""
    from mcap.writer import Writer

    from rollergear_ros.recordings.messages import MSG_DEFINITIONS

    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        f64 = w.register_schema(MessageType.FLOAT64, "ros2msg", float64_text)
        js = w.register_schema(MessageType.JOINT_STATE, "ros2msg", MSG_DEFINITIONS[MessageType.JOINT_STATE].encode())
        ids: dict[str, int] = {}
        for topic, t, payload in messages:
            if topic not in ids:
                ids[topic] = w.register_channel(topic, "cdr", js if joint_states else f64)
            w.add_message(ids[topic], t, payload, t)
        w.finish()


def _f64(v: float) -> bytes:
    return encode_float64(np.array([v]))[0]


def _pairs(n: int = 100) -> list[tuple[str, int, bytes]]:
    msgs = []
    for k in range(n):
        t = 10**9 + k * 10**7
        msgs += [(T.motor_torque, t, _f64(20.0 + k % 7)), (T.motor_speed, t, _f64(150.0))]
    return msgs


def test_a_malformed_message_is_skipped_and_counted_not_fatal(tmp_path, config):
    """A Float64 payload shorter than 12 bytes used to end replay with exit 2 and an empty output;
    one with an invalid CDR encapsulation was decoded as big-endian garbage.  Both are skipped,
    counted and named (topic, log time, reason)."""
    msgs = _pairs()
    msgs[20] = (T.motor_torque, msgs[20][1], msgs[20][2][:8])  # 8 bytes
    msgs[41] = (T.motor_speed, msgs[41][1], b"\x00\x05\x00\x00" + msgs[41][2][4:])  # encapsulation 0x0005
    p = tmp_path / "malformed.mcap"
    _mcap_with_payloads(p, msgs)
    proc = run_cli("replay", str(p), "--out", str(tmp_path / "o.mcap"))
    assert "2 malformed input messages skipped" in proc.stderr
    assert f"{T.motor_torque} at log time {msgs[20][1]} ns: payload of 8 bytes" in proc.stderr
    assert "CDR encapsulation 0005" in proc.stderr
    s, batches = replay(p, config, show_progress=False, collect=True)
    assert s.skipped["malformed"] == 2 and s.estimated == 98
    speeds = np.concatenate([b.speed_rad_s for b in batches])
    np.testing.assert_array_equal(speeds, 150.0)  # no garbage decoded
    assert len(read_rosbags(tmp_path / "o.mcap")[T.loss_torque][0]) == 98


def test_a_malformed_joint_state_is_skipped_and_counted(tmp_path, config):
    src = BAGS / "drive_cycle_joint_states.mcap"
    from mcap.reader import make_reader

    with src.open("rb") as fh:
        reader = make_reader(fh)
        messages = [(c.topic, m.log_time, m.data) for _s, c, m in reader.iter_messages(topics=[T.joint_states])]
    messages[10] = (messages[10][0], messages[10][1], messages[10][2][:30])
    p = tmp_path / "js.mcap"
    _mcap_with_payloads(p, messages, joint_states=True)
    full, _ = replay(src, config, show_progress=False)
    s, _ = replay(p, config, show_progress=False)
    assert s.skipped["malformed"] == 1 and s.estimated == full.estimated - 1


def test_a_float64_schema_that_is_not_float64_names_the_topic(tmp_path):
    p = tmp_path / "schema.mcap"
    _mcap_with_payloads(p, _pairs(10), float64_text=b"int32 data\n")
    proc = run_cli("replay", str(p), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"{T.motor_torque}: its schema std_msgs/msg/Float64 defines 'int32 data'" in proc.stderr


def test_duplicated_messages_are_estimated_once_and_backward_time_is_warned(tmp_path, config):
    """A message recorded twice used to be estimated twice; a log time going backwards was silent."""
    msgs = _pairs()
    msgs.insert(31, msgs[30])  # the speed of sample 15, twice
    msgs.insert(30, msgs[29])  # and the torque of sample 14
    msgs[80], msgs[82] = msgs[82], msgs[80]  # two torque messages swapped: time goes back on that topic
    p = tmp_path / "dup.mcap"
    _mcap_with_payloads(p, msgs)
    s, _ = replay(p, config, show_progress=False)
    assert s.skipped["duplicate"] == 2 and s.estimated == 100 and s.skipped["unpaired"] == 0
    assert any("2 duplicated input messages skipped" in w for w in s.warnings)
    assert any("1 input messages whose log time goes backwards" in w and T.motor_torque in w for w in s.warnings)


def test_unexpected_type_names_the_topic(tmp_path):
    p = tmp_path / "t.mcap"
    msg = {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}, "temperature": 1.0, "variance": 0.0}
    _write_bag(
        p,
        {T.motor_torque: ("sensor_msgs/msg/Temperature", [msg] * 5), T.motor_speed: (MessageType.FLOAT64, np.ones(5))},
        n=5,
    )
    with pytest.raises(BagError, match=f"{T.motor_torque} has type sensor_msgs/msg/Temperature"):
        replay(p, load_config(), show_progress=False)


def test_foreign_and_non_mcap_files(tmp_path):
    from mcap.writer import Writer

    p = tmp_path / "json.mcap"
    with p.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel(T.motor_torque, "json", sid)
        w.add_message(cid, 1, b"{}", 1)
        w.finish()
    with pytest.raises(BagError, match="not a ROS 2 bag"):
        replay(p, load_config(), show_progress=False)
    q = tmp_path / "x.db3"
    q.write_bytes(b"SQLite format 3\0" + b"\0" * 100)
    with pytest.raises(BagError, match="not an MCAP"):
        replay(q, load_config(), show_progress=False)
    with pytest.raises(BagError, match="does not exist"):
        replay(tmp_path / "nope.mcap", load_config(), show_progress=False)


def test_nan_and_inf_samples_are_skipped_and_counted(tmp_path, config):
    n = 300
    tq = np.full(n, 20.0)
    w = np.full(n, 100.0)
    tq[[10, 20]] = np.nan
    w[30] = np.inf
    tq[40] = -np.inf
    tq[50] = 1e9  # implausible
    p = tmp_path / "nan.mcap"
    _write_bag(p, {T.motor_torque: (MessageType.FLOAT64, tq), T.motor_speed: (MessageType.FLOAT64, w)}, n=n)
    out, rrd = tmp_path / "o.mcap", tmp_path / "o.rrd"
    s, _ = replay(p, config, out_mcap=out, rrd=rrd, show_progress=False)
    assert s.skipped["non_finite"] == 4 and s.skipped["implausible"] == 1
    # and as an event on the rerun timeline
    (event,) = review.read_rrd_events(rrd)
    assert event[1] == "WARN" and event[2] == "skipped 1 implausible, 4 non finite"
    assert s.estimated == n - 5
    _, loss = float_series(read_rosbags(out), T.loss_torque)
    assert len(loss) == n - 5 and np.all(np.isfinite(loss))
    assert math.isfinite(s.mean_loss_nm) and math.isfinite(s.energy_lost_j)


def test_unpaired_and_missing_output_are_counted(tmp_path, config):
    n = 200
    t = (1_000_000_000 + np.arange(n) * 10_000_000).astype(np.int64)
    p = tmp_path / "gap.mcap"
    with BagWriter(p) as bw:
        for i in range(n):
            bw.write_raw(T.motor_torque, MessageType.FLOAT64, int(t[i]), encode_float64(np.array([10.0]))[0])
            if i % 10 != 5:  # every tenth speed message lost
                bw.write_raw(T.motor_speed, MessageType.FLOAT64, int(t[i]), encode_float64(np.array([50.0]))[0])
            if i < 100:  # output torque stops half way
                bw.write_raw(T.output_torque, MessageType.FLOAT64, int(t[i]), encode_float64(np.array([13.0]))[0])
    s, _ = replay(p, config, show_progress=False)
    assert s.skipped["unpaired"] == 20
    assert s.skipped["output_missing"] >= 89
    assert s.estimated == 180


def _separately_logged_bag(path: Path, offset_s: float, jitter_s: float, n: int = 1000, rate: float = 100.0):
    """Torque, speed and output torque logged by separate publishers: each topic's log time lags the
    torque's by ``k * offset_s`` plus up to ``jitter_s`` (as ``ros2 bag record`` sees them)."""
    rng = np.random.default_rng(7)
    k = np.arange(n)
    torque = 40.0 * np.sin(k / 50.0)
    speed = 100.0 + 50.0 * np.cos(k / 70.0)
    rows = []
    for lag, (topic, values) in enumerate(
        ((T.motor_torque, torque), (T.motor_speed, speed), (T.output_torque, torque * 11.6))
    ):
        t = 1_000_000_000 + (k / rate + lag * offset_s + rng.uniform(0, jitter_s, n)) * 1e9
        rows += [(int(ti), topic, v) for ti, v in zip(t, values)]
    rows.sort()
    with BagWriter(path) as bw:
        for t, topic, v in rows:
            bw.write_raw(topic, MessageType.FLOAT64, t, encode_float64(np.array([v]))[0])
    return torque, speed


def test_topics_logged_apart_are_paired_by_the_automatic_tolerance(tmp_path, config):
    """At 100 Hz, topics 1-2.5 ms apart (far beyond a fixed 0.4 ms) still pair sample by sample."""
    bag = tmp_path / "apart.mcap"
    torque, speed = _separately_logged_bag(bag, offset_s=0.001, jitter_s=0.0005)
    s, batches = replay(bag, config, show_progress=False, collect=True)
    assert s.sample_period_s == pytest.approx(0.01, rel=0.05)
    assert s.sync_tolerance_s == pytest.approx(0.004, rel=0.05)
    assert s.skipped["unpaired"] == 0 and s.estimated == len(torque) and not s.warnings
    got_t = np.concatenate([b.torque_nm for b in batches])
    got_w = np.concatenate([b.speed_rad_s for b in batches])
    np.testing.assert_array_equal(got_t, torque)
    np.testing.assert_array_equal(got_w, speed)  # each torque with its own speed
    # an explicit tolerance is used as given: at 0.4 ms the speed is out of step with the torque, and
    # resampled onto its stamps (every sample estimated, and said); paired only, most samples are lost, and said why
    tight, _ = replay(bag, config.with_values({"estimator.sync_tolerance_s": 0.0004}), show_progress=False)
    assert tight.estimated == len(torque) - 1 and "motor_speed (1x the torque's rate)" in tight.resampled_text
    paired_only, _ = replay(bag, config.with_values({"estimator.sync_tolerance_s": 0.0004,
                                                     "estimator.resample_max_age_s": 0.0}), show_progress=False)
    assert paired_only.skipped["unpaired"] > 500
    assert any("pairing tolerance" in w and "sync_tolerance_s" in w for w in paired_only.warnings)


def test_truncated_bag_processes_what_is_readable(tmp_path, config):
    src = BAGS / "rig_map.mcap"
    cut = tmp_path / "cut.mcap"
    data = src.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.5)])
    info = inspect_bag(cut)
    assert info.truncated and not info.indexed
    proc = run_cli("replay", str(cut), "--out", str(tmp_path / "o.mcap"), check=False)
    assert "warning" in proc.stderr and "could not be read" in proc.stderr
    assert proc.returncode == 3 and "% of the recording unreadable (more than 1 %)" in proc.stderr  # half of it
    got = read_rosbags(tmp_path / "o.mcap")
    n = len(got[T.loss_torque][0])
    full = inspect_bag(src).counts[T.motor_torque]
    assert 0.2 * full < n < 0.9 * full


@pytest.mark.parametrize("name", ["warmup.mcap", "drive_cycle_joint_states.mcap"])
def test_a_damaged_chunk_costs_that_chunk_only_and_is_reported(tmp_path, name):
    """One byte flipped in the second chunk: replay goes on after it (it used to stop there, exit 0,
    with most samples lost), and the warning says which bytes, which log times and how many
    messages were lost."""
    from mcap.reader import make_reader

    src = BAGS / name
    with src.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    ci = summary.chunk_indexes[1]
    lost = 0
    raw = bytearray(src.read_bytes())
    for offset in ci.message_index_offsets.values():  # the chunk's message index: 16 bytes per message
        lost += int.from_bytes(raw[offset + 11:offset + 15], "little") // 16
    raw[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0x01
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(raw))
    proc = run_cli("replay", str(bad), "--out", str(tmp_path / "o.mcap"), check=False)
    assert f"{lost:,} messages lost" in proc.stderr, proc.stderr
    share = max(lost / summary.statistics.message_count, ci.chunk_length / src.stat().st_size)
    assert proc.returncode == (3 if share > 0.01 else 0), (share, proc.stderr)
    assert f"bytes {ci.chunk_start_offset:,}" in proc.stderr
    full, _ = replay(src, load_config(None), show_progress=False)
    got = read_rosbags(tmp_path / "o.mcap")
    n = len(got[T.loss_torque][0])
    per_sample = summary.statistics.message_count / full.samples  # messages per estimated sample
    assert full.estimated - lost / per_sample - 2 <= n < full.estimated


def test_topic_remapping(tmp_path, config):
    p = tmp_path / "r.mcap"
    _write_bag(
        p,
        {"/rig/tq": (MessageType.FLOAT64, np.full(50, 10.0)), "/rig/w": (MessageType.FLOAT64, np.full(50, 100.0))},
        n=50,
    )
    proc = run_cli(
        "replay",
        str(p),
        "--topic-motor-torque",
        "/rig/tq",
        "--topic-motor-speed",
        "/rig/w",
        "--topic-loss-torque",
        "/est/loss",
        "--out",
        str(tmp_path / "o.mcap"),
    )
    assert "estimated: 50" in proc.stdout
    got = read_rosbags(tmp_path / "o.mcap")
    assert len(got["/est/loss"][0]) == 50


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_replay_leaves_valid_files(tmp_path, config, sig):
    # a long bag so the replay is still running when the signal comes
    opts = SimulationOptions(profile="warmup", rate_hz=1000, seed=1)
    rig = simulate(config, opts)
    big = tmp_path / "big.mcap"
    write_rig_bag(rig, opts, big)
    out, rrd = tmp_path / "o.mcap", tmp_path / "o.rrd"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rollergear_ros", "replay", str(big), "--out", str(out), "--rrd", str(rrd)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    deadline = time.time() + 60
    # the output is written beside its name and renamed when closed: wait for 2 MB of it
    while time.time() < deadline and sum(p.stat().st_size for p in partial_files(out)) < 2_000_000:
        time.sleep(0.05)
    assert not out.exists()  # not in place before it is whole
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "rollergear: interrupted: finishing the batch under way" in stderr  # said at once
    assert not partial_files(out) and not partial_files(rrd)  # renamed into place
    assert "INTERRUPTED" in stdout and "Traceback" not in stderr
    got = read_rosbags(out, [T.loss_torque])  # a valid, indexed file
    n = len(got[T.loss_torque][0])
    assert 0 < n < len(rig.t_ns)
    assert inspect_bag(out).indexed
    assert len(read_mcap_ros2(out, [T.loss_torque])[T.loss_torque][0]) == n
    series = read_rrd_series(rrd)
    assert 0 < len(series[review.LOSS_TORQUE][0]) <= n


@pytest.mark.parametrize("second", [False, True])
def test_a_signal_right_after_the_outputs_open_leaves_valid_files(tmp_path, second):
    """The moment the output MCAP appears, SIGINT (and, with ``second``, another one 20 ms later).
    The handler used to be installed after the writers opened, leaving a 43-byte MCAP and no
    ``.rrd``; a second signal could end the run between a batch's estimates and its inputs."""
    out, rrd = tmp_path / "o.mcap", tmp_path / "o.rrd"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rollergear_ros", "replay", str(BAGS / "warmup.mcap"), "--out", str(out),
         "--rrd", str(rrd), "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    while not partial_files(out) and proc.poll() is None:  # a condition: the writer has created its file
        time.sleep(0.001)
    proc.send_signal(signal.SIGINT)
    if second:
        time.sleep(0.02)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert inspect_bag(out).indexed  # summary and footer written
    got = read_rosbags(out)
    none = (np.empty(0, np.int64), [])
    est_t, in_t = got.get(T.loss_torque, none)[0], got.get(T.motor_torque, none)[0]
    # consistent: every estimate's input is in the file, and at most a handful of inputs (still
    # waiting for a partner at the stop) lack an estimate
    assert 0 <= len(in_t) - len(est_t) <= 5
    assert set(est_t.tolist()) <= set(in_t.tolist())
    n_est = len(est_t)
    series = read_rrd_series(rrd)  # a valid rerun recording (possibly without samples)
    assert len(series.get(review.LOSS_TORQUE, ([],))[0]) <= n_est


def test_a_second_signal_waits_for_the_end_of_a_critical_section():
    import os

    from rollergear_ros.replay.run import GracefulStop

    stop = GracefulStop()
    try:
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.requested
        with pytest.raises(KeyboardInterrupt):
            with stop.critical():
                os.kill(os.getpid(), signal.SIGINT)  # deferred: the section completes
                finished = True
        assert finished
        with pytest.raises(KeyboardInterrupt):  # outside a section it stops at once
            os.kill(os.getpid(), signal.SIGINT)
    finally:
        stop.restore()


def test_big_endian_float64_payloads_are_decoded(tmp_path, config):
    import struct

    p = tmp_path / "be.mcap"
    n = 50
    with BagWriter(p) as bw:
        for i in range(n):
            t = 10**9 + i * 10**7
            bw.write_raw(T.motor_torque, MessageType.FLOAT64, t, b"\x00\x00\x00\x00" + struct.pack(">d", 20.0))
            bw.write_raw(T.motor_speed, MessageType.FLOAT64, t, b"\x00\x00\x00\x00" + struct.pack(">d", 100.0))
    s, batches = replay(p, config, show_progress=False, collect=True)
    loss = np.concatenate([b.loss_torque_nm for b in batches])
    assert len(loss) == n
    np.testing.assert_allclose(loss, LossModel(config.gearbox).loss_magnitude(20.0, 100.0), rtol=1e-12)


@pytest.mark.parametrize(
    "metadata, pairing",
    [
        ({"pairing": "arrival", "sample_period_s": "0.001"}, "arrival"),
        ({"pairing": "arrival", "sample_period_s": "abc"}, "timestamp"),  # unreadable: the bag's own timing
        ({"pairing": "arrival", "sample_period_s": "-1"}, "timestamp"),
        ({"pairing": "timestamp", "sample_period_s": "0.001"}, "timestamp"),
        (None, "timestamp"),
    ],
)
def test_a_node_recording_is_paired_as_the_node_paired_it(tmp_path, config, metadata, pairing):
    """``rollergear_recording`` metadata (written by loss_estimator) selects arrival pairing with the
    node's sample period; anything unreadable falls back to pairing by the bag's timestamps."""
    from rollergear_ros.base.interface import Metadata

    n = 300
    t = (1_000_000_000 + np.arange(n) * 1_000_000).astype(np.int64)
    p = tmp_path / "node.mcap"
    with BagWriter(p) as bw:
        if metadata is not None:
            bw.add_metadata(Metadata.RECORDING, metadata)
        bw.write_float64_series(T.motor_torque, t, np.linspace(5.0, 50.0, n))
        bw.write_float64_series(T.motor_speed, t + 50_000, np.full(n, 100.0))
    s, batches = replay(p, config, show_progress=False, collect=True)
    assert s.pairing == pairing and ("pairing: by arrival" in s.text()) == (pairing == "arrival")
    assert s.sync_tolerance_s == pytest.approx(0.002 if pairing == "arrival" else 0.0004)
    assert s.estimated == n
    np.testing.assert_allclose(
        np.concatenate([b.loss_torque_nm for b in batches]),
        LossModel(config.gearbox).loss_magnitude(np.linspace(5.0, 50.0, n), np.full(n, 100.0)),
        rtol=1e-12,
    )


def test_a_node_recording_is_replayed_in_the_order_the_node_took_its_inputs(tmp_path, config):
    """Replay takes a node's recorded inputs in the order the node took them.

    A node pairing by publisher timestamps that takes one input's backlog before another's (the
    single-threaded executor after a stall) gives up the samples that input left behind; its
    recording holds the inputs in the order it took them.  Replay takes them in that order, not
    sorted by their timestamps, and so estimates what the node estimated -- as :meth:`Estimator.push`
    does message by message.  (Found by the stress test: replay had estimated a sample the node
    had given up.)"""
    from rollergear_ros.recordings.messages import encode_float64
    from rollergear_ros.core.estimator import Estimator
    from rollergear_ros.base.interface import Metadata, MessageType

    n, period_ns = 40, 50_000_000
    t0 = 1_000_000_000
    topic = {"motor_torque": T.motor_torque, "motor_speed": T.motor_speed, "output_torque": T.output_torque,
             "output_speed": T.output_speed}
    sample = {ch: [(t0 + k * period_ns + j * 200_000, v) for k in range(n)]
              for j, (ch, v) in enumerate(zip(topic, (20.0, 100.0, 117.0, 17.0)))}
    for ch in sample:  # unique values, as a rig's
        sample[ch] = [(t, v + 0.5 * k) for k, (t, v) in enumerate(sample[ch])]
    # taken by the node: the first three output speeds before anything else, then sample by sample
    taken = [("output_speed", *sample["output_speed"][k]) for k in range(3)]
    for k in range(n):
        taken += [(ch, *sample[ch][k]) for ch in topic if not (ch == "output_speed" and k < 3)]
    p = tmp_path / "node.mcap"
    with BagWriter(p, time_ordered=False) as bw:  # as the node records: in the order it took them
        bw.add_metadata(Metadata.RECORDING, {"pairing": "timestamp", "input_log_time": "source_timestamp",
                                             "sample_period_s": repr(period_ns * 1e-9)})
        for ch, t, v in taken:
            bw.write_raw(topic[ch], MessageType.FLOAT64, t, encode_float64(np.array([v]))[0])
    node = Estimator(config, "timestamp", period_ns * 1e-9)
    live = [e.torque_nm for ch, t, v in taken for e in node.push(ch, t, v)] + [e.torque_nm for e in node.finish()]
    assert node.counts["unpaired"] > 0 and len(live) < n  # the node gave up what the backlog left behind
    _, batches = replay(p, config, show_progress=False, collect=True)
    np.testing.assert_array_equal(np.concatenate([b.torque_nm for b in batches]), live)


def test_a_node_recording_carries_its_inputs_send_times_and_replay_pairs_with_them(tmp_path, config):
    """A node records each input at the time it took it (the log time: the order it paired by) and
    with the time its publisher sent it (the publish time), which its skew detector measures with.
    Replay reads both: a recording of a loaded node's catch-up replays to exactly what the node
    estimated, every sample from its own inputs.  The same recording without the send times (an
    older node's) pairs hundreds of samples with their neighbours': replay did use them."""
    from helpers import preempted_catch_up

    from rollergear_ros.base.interface import Metadata

    events = preempted_catch_up(seed=3)
    node = Estimator(config, "arrival_sequenced", 1e-3)
    live = [e for ch, t, v, sent in events for e in node.push(ch, t, v, sent)] + node.finish()
    topic = {"motor_torque": T.motor_torque, "motor_speed": T.motor_speed}
    replayed = {}
    for name, with_sent in (("node", True), ("older", False)):
        p = tmp_path / f"{name}.mcap"
        with BagWriter(p, time_ordered=False) as bw:
            bw.add_metadata(Metadata.RECORDING, {"pairing": "arrival_sequenced", "input_log_time": "arrival",
                                                 "sample_period_s": "0.001"})
            for ch, t, v, sent in events:
                bw.write_raw(topic[ch], MessageType.FLOAT64, t, encode_float64(np.array([v]))[0],
                             publish_time_ns=sent if with_sent else None)
        summary, batches = replay(p, config, show_progress=False, collect=True)
        assert summary.pairing == "arrival_sequenced"
        replayed[name] = (np.concatenate([b.torque_nm for b in batches]),
                          np.concatenate([b.speed_rad_s for b in batches]))
    torque, speed = replayed["node"]
    np.testing.assert_array_equal(torque, [e.torque_nm for e in live])
    np.testing.assert_array_equal(speed, [e.speed_rad_s for e in live])
    np.testing.assert_array_equal(np.round((torque - 10) * 1000), np.round((speed - 50) * 1000))
    torque, speed = replayed["older"]
    assert np.sum(np.round((torque - 10) * 1000) != np.round((speed - 50) * 1000)) > 100


def test_every_sample_implausible_is_a_warning_and_whole_empty_outputs(tmp_path):
    """``estimator.max_abs_torque_nm`` below every sample: "cannot reshape array" out of the stamped
    output; now every output is written whole without an estimate, and a warning says why."""
    params = tmp_path / "tiny.yaml"
    params.write_text("/**/loss_estimator:\n  ros__parameters:\n    estimator: {max_abs_torque_nm: 0.001}\n")
    proc = run_cli("replay", str(BAGS / "rig_map_drag.mcap"), "--params", str(params), "--no-png",
                   "--out", str(tmp_path / "o.mcap"), "--csv", str(tmp_path / "o.csv"),
                   "--rrd", str(tmp_path / "o.rrd"))
    assert "no sample was estimated: every one of the 10,080 was skipped (implausible 10,080)" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert (tmp_path / "o.csv").read_text().count("\n") == 1  # the header
    assert inspect_bag(tmp_path / "o.mcap").counts.get("/rollergear/loss/torque", 0) == 0


def test_adaptation_kept_inside_the_files_range_is_said_by_replay(tmp_path):
    """A gearbox that loses nothing measured against a file with a constant drag: online adaptation
    wants the drag below zero (a file with it is refused: a power source).  Replay keeps it at 0,
    says so in one line with the count, and no model efficiency is above 100 %."""
    from dataclasses import replace

    opts = SimulationOptions("drive_cycle", 100.0, 5)
    rig = simulate(load_config(), opts)
    moving = np.abs(rig.out_speed_meas_rad_s) > 1e-3
    out_torque = np.full(len(rig.t_ns), np.nan)  # every watt in comes out
    out_torque[moving] = rig.torque_meas_nm[moving] * rig.speed_rad_s[moving] / rig.out_speed_meas_rad_s[moving]
    write_rig_bag(replace(rig, out_torque_meas_nm=out_torque), opts, tmp_path / "lossless.mcap")
    params = tmp_path / "drag.yaml"
    params.write_text("/**/loss_estimator:\n  ros__parameters:\n    estimator: {adapt: true}\n"
                      "    effects:\n      drag_constant: {enabled: true, c_nm: 0.05}\n")
    proc = run_cli("replay", str(tmp_path / "lossless.mcap"), "--params", str(params), "--no-png",
                   "--csv", str(tmp_path / "o.csv"))
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("adaptation: "))
    assert "effects.drag_constant.c_nm kept within the range a parameter file may hold [0, " in line
    assert "(now 0)" in line
    header, *rows = (ln.split(",") for ln in (tmp_path / "o.csv").read_text().splitlines())
    efficiency = np.array([r[header.index('"efficiency [1]"')] or "nan" for r in rows], dtype=float)
    assert np.isfinite(efficiency).sum() > 10_000
    assert np.nanmax(efficiency) <= 1.0


def test_stamps_that_jitter_beyond_what_the_files_lags_assume_are_said_by_replay(tmp_path):
    """A file with channel lags of 7 to 21 ms replayed on a recording whose stamps jitter by 4 ms (a
    publisher preempted now and then) says so on its channel lags line; the same rig on a steady clock
    does not."""
    from dataclasses import replace

    opts = SimulationOptions("drive_cycle", 100.0, 5)
    rig = simulate(load_config(), opts)
    jitter = np.random.default_rng(3).normal(0.0, 4e6, len(rig.t_ns)).astype(np.int64)
    write_rig_bag(rig, opts, tmp_path / "steady.mcap")
    write_rig_bag(replace(rig, t_ns=np.sort(rig.t_ns + jitter)), opts, tmp_path / "jittered.mcap")
    config = load_config().with_values({"estimator.motor_speed_lag_s": -0.0073, "estimator.output_torque_lag_s": 0.0131,
                                        "estimator.output_speed_lag_s": 0.0207})
    steady, _ = replay(tmp_path / "steady.mcap", config, show_progress=False)
    jittered, _ = replay(tmp_path / "jittered.mcap", config, show_progress=False)
    assert "jitter" not in steady.lags_text and "motor_speed 7.3 ms early" in steady.lags_text
    assert "the stamps jitter: " in jittered.lags_text and "more than 3.65 ms, half the shortest lag" in \
        jittered.lags_text, jittered.lags_text
    assert f"channel lags (the parameter file's): {jittered.lags_text}" in jittered.text()


def test_an_output_torque_stamped_ten_seconds_late_is_said_and_counts_name_their_channel(tmp_path):
    """The output torque of a 100 Hz rig re-stamped 10 s late pairs, stamp for stamp, with drive samples
    of another moment: replay says the channel is shifted (by how much, after the torque) instead of
    a silent measured efficiency.  Its own recording, and one whose output torque logger only started
    late, say nothing.  A motor speed lost in part is counted as its own channel's."""
    from bagtools import _copy

    source = BAGS / "rig_map_drag.mcap"
    late = _copy(source, tmp_path / "late.mcap", lambda _s, channel, m: (
        (m.log_time + 10**10, m.data, m.publish_time + 10**10) if channel.topic == T_OUT_TORQUE
        else (m.log_time, m.data, m.publish_time)), log_time_order=False)
    started_late = _copy(source, tmp_path / "started_late.mcap", lambda _s, channel, m: None if (
        channel.topic == T_OUT_TORQUE and m.log_time < 10**10 + _first_log_time(source)) else (
        m.log_time, m.data, m.publish_time), log_time_order=False)
    speed_gaps = _copy(source, tmp_path / "speed_gaps.mcap", lambda _s, channel, m: None if (
        channel.topic == TopicMap().motor_speed and m.sequence % 5 == 0) else (
        m.log_time, m.data, m.publish_time), log_time_order=False)
    said: dict[str, list[str]] = {}
    for path in (source, late, started_late, speed_gaps):
        said[path.stem] = []
        replay(path, load_config(), show_progress=False, warn=said[path.stem].append)
    shifted = [w for w in said["late"] if "whole stream is shifted" in w]
    assert len(shifted) == 1 and "output torque 10 s after it, at both ends" in shifted[0], said["late"]
    for stem in ("rig_map_drag", "started_late", "speed_gaps"):
        assert not any("shifted" in w for w in said[stem]), said[stem]
    unpaired = [w for w in said["speed_gaps"] if "without a partner" in w]
    assert len(unpaired) == 1 and "motor torque 2,016 of 10,080" in unpaired[0] and "motor speed" not in \
        unpaired[0], unpaired


T_OUT_TORQUE = TopicMap().output_torque


def _first_log_time(path: Path) -> int:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return make_reader(f).get_summary().statistics.message_start_time



def test_a_spin_test_prints_its_loss_not_an_efficiency(tmp_path):
    """A spin test (the channel map's output torque the constant 0): replay says the drive power is all loss,
    in watts, and prints no measured efficiency (it printed 0.00 %, the model's beside it, per operating
    point) and no model efficiency."""
    from helpers import run_cli
    from rigs import params, spin_map, write_csv

    t = np.arange(0.0, 30.0, 0.005)
    w = 300.0 * np.sin(2 * np.pi * 0.1 * t)
    rng = np.random.default_rng(0)
    csv = write_csv(tmp_path / "spin.csv", {"t": t, "T": (0.02 + 1e-4 * np.abs(w)) * np.sign(w)
                                            + rng.normal(0.0, 1e-3, len(t)), "w": w + rng.normal(0.0, 0.05, len(t))})
    said = run_cli("replay", str(csv), "--channels", str(spin_map(tmp_path / "spin.yaml")), "--params",
                   str(params(tmp_path / "p.yaml")), "--no-png").stdout
    assert "measured: no power leaves the output (a spin test: 0 J delivered of " in said, said
    assert "the drive power is all loss" in said and " W on average" in said
    assert "measured efficiency" not in said and "model efficiency: none (no power leaves the output)" in said
    assert "per operating point" not in said and "%" not in said.split("skipped:")[1], said
