"""Input pairing (rollergear_ros.core.pairing): by log time, by arrival, vectorised equals message by message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.pairing import (CHANNELS, OIL_TEMPERATURE, OUT_SPEED, OUT_TORQUE, SPEED, TORQUE,
                                         SampleSynchronizer, pairing_tolerance_s, samples_to_arrays)
from rollergear_ros.core.lostmarks import LOST_VALUE, SequenceGaps, is_lost, lost_mask
from rollergear_ros.core.params import load_config

from helpers import preempted_catch_up

MS = 1_000_000


def stream(n: int, outputs: bool = True, temp_every: int = 7, seed: int = 0):
    """(code, t, value) messages of n samples at 1 kHz, channels of a sample at the same time."""
    rng = np.random.default_rng(seed)
    ev = []
    for k in range(n):
        t = 10**12 + k * MS
        chans = (TORQUE, SPEED, OUT_TORQUE, OUT_SPEED) if outputs else (TORQUE, SPEED)
        for c in chans:
            ev.append((CHANNELS.index(c), t, float(rng.normal())))
        if k % temp_every == 3:
            ev.append((CHANNELS.index(OIL_TEMPERATURE), t, 40.0 + k * 0.01))
    codes = np.array([e[0] for e in ev], dtype=np.int8)
    return codes, np.array([e[1] for e in ev], dtype=np.int64), np.array([e[2] for e in ev])


@pytest.mark.parametrize("outputs", [True, False])
def test_vectorised_pairing_equals_message_by_message(outputs):
    codes, t, v = stream(3000, outputs)
    slow = SampleSynchronizer(0.0004, 0.1)
    ref = []
    for c, tt, vv in zip(codes.tolist(), t.tolist(), v.tolist()):
        ref.extend(slow.push(CHANNELS[c], tt, vv))
    ref.extend(slow.flush())
    ref = samples_to_arrays(ref)
    fast = SampleSynchronizer(0.0004, 0.1)
    parts = []
    for a, b in ((0, 4001), (4001, 9000), (9000, len(codes))):  # batches cut mid-sample
        parts.append(fast.push_many(codes[a:b], t[a:b], v[a:b]))
    parts.append(samples_to_arrays(fast.flush()))
    got = [np.concatenate([p[i] for p in parts]) for i in range(6)]
    for r, g in zip(ref, got):
        np.testing.assert_array_equal(np.asarray(r), np.asarray(g))
    assert slow.counts == fast.counts and slow.received == fast.received


def test_timestamp_pairing_never_pairs_neighbouring_samples():
    sync = SampleSynchronizer(0.0004, 0.1)
    out = []
    for k in range(10):
        t = k * MS
        out += sync.push(TORQUE, t, float(k))
        if k != 4:  # speed of sample 4 lost
            out += sync.push(SPEED, t, float(k))
    out += sync.flush()
    assert [s.torque_nm for s in out] == [s.speed_rad_s for s in out]
    assert sync.counts["unpaired"] == 1 and len(out) == 9


def test_arrival_pairing_tolerates_reordering_and_resyncs_after_a_loss():
    sync = SampleSynchronizer(0.002, 0.1, arrival=True)
    out = []
    t = 0
    for k in range(400):
        order = [TORQUE, SPEED] if k % 5 else [SPEED, TORQUE]  # topics swap order now and then
        for c in order:
            if c == SPEED and k == 200:
                continue  # lost
            t += 10_000  # callback times advance 10 µs per message, samples 5 ms apart (200 Hz)
            out += sync.push(c, t + 5 * k * MS, float(k))
    paired = [(s.torque_nm, s.speed_rad_s) for s in out]
    good = [p for p in paired if p[0] == p[1]]
    assert len(good) >= 395, paired  # all but the few samples around the loss
    assert paired[-1][0] == paired[-1][1], "re-synchronised after the lost message"


@pytest.mark.parametrize("split", [[0], [200, 201, 202, 203, 204]])
def test_lossless_arrival_pairing_keeps_samples_a_busy_executor_spread_out(split):
    """Over a reliable, keep-all delivery nothing is lost, so a wide pair is never a loss: the
    first sample's messages spread 2.6 ms by slow first callbacks, or several consecutive samples
    each split by a preemption, are paired as they came (best-effort arrival pairing drops them:
    seen on a busy machine, one sample of a recording played reliably into the node lost)."""
    ref = SampleSynchronizer(0.002, 0.1, arrival=True)
    sync = SampleSynchronizer(0.002, 0.1, arrival=True, lossless=True)
    out, lossy = [], []
    for k in range(400):
        spread = 860_000 if k in split else 20_000  # 0, 0.86, 1.72, 2.58 ms for a spread sample
        for i, ch in enumerate((TORQUE, SPEED, OUT_TORQUE, OUT_SPEED)):
            t, v = 3 * MS + k * MS + i * spread, float(k) + i / 10
            out += sync.push(ch, t, v)
            lossy += ref.push(ch, t, v)
    out += sync.flush()
    lossy += ref.flush()
    assert [(s.torque_nm, s.out_speed_rad_s) for s in out] == [(k, k + 0.3) for k in range(400)]
    assert sync.counts["unpaired"] == 0
    assert ref.counts["unpaired"] > 0  # what the best-effort rule does with the same arrivals


def test_arrival_pairing_drops_the_backlog_of_a_topic_that_started_early():
    """A node started while a bag plays: the torque subscription matched 3 samples before speed's."""
    sync = SampleSynchronizer(0.002, 0.1, arrival=True)
    out = []
    for k in range(300):
        t = 5 * k * MS  # 200 Hz
        out += sync.push(TORQUE, t, float(k))
        if k >= 3:
            out += sync.push(SPEED, t + 10_000, float(k))
        if k == 150:
            t_gap = t
    # the same after a pause longer than the staleness limit, speed resuming 2 samples late
    for k in range(300, 400):
        t = t_gap + 2_000 * MS + 5 * k * MS
        out += sync.push(TORQUE, t, float(k))
        if k >= 302:
            out += sync.push(SPEED, t + 10_000, float(k))
    paired = [(s.torque_nm, s.speed_rad_s) for s in out]
    assert all(a == b for a, b in paired), [p for p in paired if p[0] != p[1]]
    assert len(paired) == 297 + 98
    assert sync.counts["unpaired"] == 5


def test_arrival_pairing_keeps_a_sample_split_by_an_executor_stall():
    """The executor stalls 150 ms between a sample's torque and speed callbacks, then catches up."""
    sync = SampleSynchronizer(0.002, 0.1, arrival=True)
    out = []
    for k in range(100):
        t = k * MS + (150 * MS if k >= 50 else 0)
        out += sync.push(TORQUE, t - (150 * MS if k == 50 else 0), float(k))
        out += sync.push(SPEED, t + 10_000, float(k))
    assert [(s.torque_nm, s.speed_rad_s) for s in out] == [(float(k), float(k)) for k in range(100)]
    assert sync.counts["unpaired"] == 0


@pytest.mark.parametrize("stall_after", [SPEED, OUT_TORQUE])
def test_arrival_pairing_keeps_the_outputs_of_a_sample_split_by_an_executor_stall(stall_after):
    """With measured outputs at 1 kHz, the executor stalls 150 ms (> staleness_s) inside one
    sample and then takes the queued messages in a burst.  The outputs were never silent: every
    sample keeps its own measured output, none is dropped."""
    sync = SampleSynchronizer(0.002, 0.1, arrival=True)
    order = (TORQUE, SPEED, OUT_TORQUE, OUT_SPEED)
    out, stall = [], 0
    for k in range(400):
        for i, ch in enumerate(order):
            out += sync.push(ch, k * MS + i * 20_000 + stall, float(k) + i / 10)
            if k == 200 and ch == stall_after:
                stall = 150 * MS  # then the backlog arrives as fast as the executor takes it
    assert [(s.torque_nm, s.speed_rad_s, s.out_torque_nm, s.out_speed_rad_s) for s in out] == [
        (k, k + 0.1, k + 0.2, k + 0.3) for k in range(400)]
    assert sync.counts["unpaired"] == 0 and sync.counts["output_missing"] == 0


def _skewed(out) -> list[float]:
    return [s.torque_nm for s in out if s.torque_nm != s.speed_rad_s]


@pytest.mark.parametrize("lossless", [False, True])
def test_arrival_pairing_undoes_the_skew_of_a_start_up_backlog(lossless):
    """A node joins a 1 kHz stream: its torque subscription matched 3 samples before speed's and
    the backlog is taken in one burst (callbacks 10 µs apart: no timing left to pair by).  Once
    live, the pairing three samples off shows as a mean offset of a period, and is undone (also
    over a reliable delivery, where wide pairs are never taken for a loss)."""
    sync = SampleSynchronizer(0.002, 0.1, arrival=True, lossless=lossless)
    out = []
    t = 0
    burst = [(TORQUE, k) for k in range(3)] + [(c, k) for k in range(3, 300) for c in (TORQUE, SPEED)]
    for c, k in burst:
        t += 10_000
        out += sync.push(c, t, float(k))
    for k in range(300, 2300):
        t_k = t + (k - 299) * MS
        out += sync.push(TORQUE, t_k, float(k))
        out += sync.push(SPEED, t_k + 10_000, float(k))
    skewed = _skewed(out)
    assert max(skewed) < 300 + 50, "undone within 50 live samples"
    assert len(out) > 2200 and sync.counts["unpaired"] == 3


def test_arrival_pairing_undoes_the_skew_of_a_lost_message_at_1_khz():
    sync = SampleSynchronizer(0.002, 0.1, arrival=True)
    out = []
    for k in range(3000):
        out += sync.push(TORQUE, k * MS, float(k))
        if k != 1000:
            out += sync.push(SPEED, k * MS + 20_000, float(k))
    skewed = _skewed(out)
    assert skewed and min(skewed) >= 1000 and max(skewed) < 1050
    assert sync.counts["unpaired"] == 1 and len(out) == 2999


@pytest.mark.parametrize("phase", [0.3, 0.6, 0.9])
def test_arrival_pairing_settles_with_independently_phased_publishers(phase):
    """Speed published ``phase`` periods after torque by another node (both 1 kHz, ±50 µs jitter):
    pairing with the nearer message is kept; at most one resync, then no drops."""
    rng = np.random.default_rng(1)
    sync = SampleSynchronizer(0.002, 0.1, arrival=True)
    out = []
    for k in range(4000):
        jitter = rng.normal(0, 50_000, 2).astype(int)
        out += sync.push(TORQUE, k * MS + jitter[0], float(k))
        out += sync.push(SPEED, k * MS + int(phase * MS) + jitter[1], float(k))
    assert sync.counts["unpaired"] <= 1
    lag = {s.torque_nm - s.speed_rad_s for s in out[100:]}
    assert lag == ({0.0} if phase < 0.75 else {1.0}), lag


def test_arrival_pairing_skew_detector_ignores_an_executor_stall():
    """A 40 ms stall between one sample's torque and speed callbacks at 1 kHz is not a skew."""
    sync = SampleSynchronizer(0.002, 0.1, arrival=True)
    out = []
    for k in range(500):
        stall = 40 * MS if k >= 250 else 0
        out += sync.push(TORQUE, k * MS + (stall if k > 250 else 0), float(k))
        out += sync.push(SPEED, k * MS + stall + 10_000, float(k))
    assert not _skewed(out) and len(out) == 500 and sync.counts["unpaired"] == 0


def test_pairing_tolerance_is_explicit_or_a_fraction_of_the_period():
    assert pairing_tolerance_s(0.003, 0.01) == 0.003  # explicit wins
    assert pairing_tolerance_s(0.0, 0.01) == pytest.approx(0.004)  # 0.4 x the period: never k with k+-1
    assert pairing_tolerance_s(0.0, None) == pytest.approx(0.0004)  # unknown period: 1 kHz assumed
    assert Estimator(load_config(), sample_period_s=0.005).sync.tolerance_ns == 2_000_000
    assert Estimator(load_config(), "arrival", 0.01).sync.tolerance_ns == 4_000_000
    assert Estimator(load_config(), "arrival", 0.001).sync.tolerance_ns == 2_000_000  # at least 2 ms


@pytest.mark.parametrize("late", [TORQUE, SPEED])
@pytest.mark.parametrize("held_ms", [20, 60, 150, 1000])
def test_lossless_arrival_pairing_waits_for_a_topic_whose_delivery_was_held_up(late, held_ms):
    """Over a reliable, keep-all delivery one topic's messages are held up (a busy machine; a
    repair of the reliable protocol) for ``held_ms`` and then arrive in one burst while the other
    topic kept coming: nothing is lost, so nothing is dropped and every sample is paired with its
    own partner (the skew detector does not mistake the burst for a skew, the motor messages wait
    longer than ``staleness_s``)."""
    sync = SampleSynchronizer(0.0004, 0.1, arrival=True, lossless=True)
    other = SPEED if late == TORQUE else TORQUE
    events = []
    for k in range(3000):
        t = 10**9 + k * MS
        events.append((t, other, k))
        released = 10**9 + (500 + held_ms) * MS if 500 <= k < 500 + held_ms else t
        events.append((released + 1_000, late, k))
    events.sort(key=lambda e: e[0])
    out = []
    for t, channel, k in events:
        out += sync.push(channel, t, float(k))
    out += sync.flush()
    assert sync.counts["unpaired"] == 0 and len(out) == 3000
    assert _skewed(out) == []


def test_lossless_arrival_pairing_never_drops_after_the_start_however_the_arrivals_jitter():
    """Reliable, keep all: after the start, arrival times scattered by a busy machine -- random
    delays of each message, and a stretch where one topic's callbacks run 1.5 periods late -- never
    cost a sample and never mispair one (per topic in order, as a reliable delivery keeps them)."""
    rng = np.random.default_rng(7)
    n = 20000
    sync = SampleSynchronizer(0.0004, 0.1, arrival=True, lossless=True)
    events = []
    for channel in (TORQUE, SPEED):
        delay = rng.exponential(0.3 * MS, n) * (np.arange(n) > 1000)
        if channel == SPEED:
            delay[5000:5100] += 1.5 * MS
        arrival = np.maximum.accumulate(np.arange(n) * MS + delay.astype(np.int64) + (channel == SPEED))
        events += [(int(t), channel, k) for k, t in enumerate(arrival)]
    events.sort(key=lambda e: (e[0], e[1]))
    out = []
    for t, channel, k in events:
        out += sync.push(channel, t, float(k))
    out += sync.flush()
    assert sync.counts["unpaired"] == 0 and len(out) == n
    assert _skewed(out) == []


@pytest.mark.parametrize("events", ["held_up_delivery_events.npz", "held_up_twice_events.npz"])
def test_lossless_arrival_pairing_of_a_busy_machines_recorded_arrivals_drops_nothing(events):
    """The arrival times (and order) of the 40 320 input messages a node received in a stress run
    (``data/*.npz``, each from its own recording: rig_map or rig_map_drag played at 5x, reliable,
    keep all, a busy 2-core machine).  ``held_up_delivery``: the node stalled for 0.34 s, the motor
    torque's delivery was held up for 0.68 s and came in a burst, then everything caught up faster
    than 1 kHz (the skew detector once took the catch-up for a skew and dropped 7 samples).
    ``held_up_twice``: the node stalled 0.34 s with nothing queued, the motor torque's delivery was
    held up 0.85 s and the speed's 50 ms (the stall was once taken for a new stream, which re-armed
    the skew detector: 2 samples dropped, 137 paired one speed ahead).  Nothing was lost, so every
    one of the 10 080 samples pairs with its own partners."""
    data = np.load(Path(__file__).resolve().parents[1] / "data" / events)
    t_ns = np.cumsum(data["dt_ns"])
    sync = SampleSynchronizer(0.002, 0.1, arrival=True, lossless=True, sample_period_s=0.001)
    seen = dict.fromkeys(range(4), 0)
    out = []
    for t, code in zip(t_ns.tolist(), data["channel"].tolist()):
        out += sync.push(CHANNELS[code], t, float(seen[code]))  # value: the message's index on its topic
        seen[code] += 1
    out += sync.flush()
    assert sync.counts["unpaired"] == 0 and len(out) == 10080
    assert all(s.torque_nm == s.speed_rad_s == s.out_torque_nm == s.out_speed_rad_s for s in out)


def test_lossless_arrival_pairing_undoes_the_skewed_start_of_a_new_stream_after_a_gap():
    """Reliable, keep all: a stream of 2000 samples, 2 s of silence, then a new publisher whose speed
    topic matched 3 samples after its torque (those 3 torque messages have no partner).  The messages
    after the gap come at the sample rate, so it is a new stream, not a stall: the skew detector acts
    on it again (its window counts from the new start) and undoes the pairing three samples off."""
    sync = SampleSynchronizer(0.002, 0.1, arrival=True, lossless=True, sample_period_s=0.001)
    out = []
    for k in range(2000):
        out += sync.push(TORQUE, k * MS, float(k))
        out += sync.push(SPEED, k * MS + 10_000, float(k))
    start = 4000 * MS
    for k in range(3000):
        out += sync.push(TORQUE, start + k * MS, float(10_000 + k))
        if k >= 3:
            out += sync.push(SPEED, start + k * MS + 10_000, float(10_000 + k))
    out += sync.flush()
    skewed = _skewed(out)
    assert skewed and min(skewed) >= 10_000 and max(skewed) < 10_000 + 50, "undone within 50 samples"
    assert sync.counts["unpaired"] == 3 and len(out) == 2000 + 2997


def test_sequence_gaps_count_the_messages_lost_between_those_received():
    gaps = SequenceGaps()
    assert [gaps.lost_before(s) for s in (1, 2, 5, 6, 10)] == [0, 0, 2, 0, 3]
    # a restarted publisher numbers from 1 again: a new writer, nothing lost; unnumbered: unknown
    assert [gaps.lost_before(s) for s in (1, 3, None, 4)] == [0, 1, 0, 0]


def test_a_lost_messages_placeholder_is_known_by_its_bits_only():
    assert is_lost(LOST_VALUE) and not is_lost(float("nan")) and not is_lost(1.0)
    values = np.array([1.0, np.nan, LOST_VALUE, -np.inf])
    assert lost_mask(values).tolist() == [False, False, True, False]
    # it survives the recording: a Float64 payload decoded back is the same placeholder
    from rollergear_ros.recordings.messages import decode_float64, float64_payloads

    assert lost_mask(decode_float64([bytes(r) for r in float64_payloads(values)])).tolist() == [False, False, True,
                                                                                                  False]


@pytest.mark.parametrize("lossless", [False, True])
def test_placeholders_keep_arrival_pairing_aligned_across_a_burst_loss(lossless):
    """A node a whole queue behind loses the oldest messages of each topic, a different number on
    each (torque 200..500, speed 200..400), and then takes what is left round-robin, a few microseconds
    apart: with a placeholder in place of every lost message, every sample pairs with its own
    inputs and the samples with a lost input are skipped as ``lost``; without them first-in
    first-out pairs torque k with speed k - 100 for the rest of the catch-up."""
    def run(placeholders: bool):
        est = Estimator(load_config(), "arrival_sequenced" if lossless else "arrival", 1e-3)
        out = []
        t = 1_000_000_000
        for k in range(200):
            out += est.push(TORQUE, t, 10 + k * 1e-3)
            out += est.push(SPEED, t + 5_000, 50 + k * 1e-3)
            t += 1_000_000
        t += 1_300_000_000  # the stall; then the catch-up, round-robin
        left = {TORQUE: list(range(501, 1501)), SPEED: list(range(401, 1401))}
        lost = {TORQUE: 301, SPEED: 201}
        while left[TORQUE] or left[SPEED]:
            for ch, base in ((TORQUE, 10), (SPEED, 50)):
                if not left[ch]:
                    continue
                if lost[ch] and placeholders:
                    for i in range(lost[ch]):
                        out += est.push(ch, t - lost[ch] + i, LOST_VALUE)
                lost[ch] = 0
                out += est.push(ch, t, base + left[ch].pop(0) * 1e-3)
                t += 8_000
        for k in range(1401, 1501):
            out += est.push(SPEED, t, 50 + k * 1e-3)
            t += 8_000
        for k in range(1501, 1700):  # live again
            out += est.push(TORQUE, t, 10 + k * 1e-3)
            out += est.push(SPEED, t + 5_000, 50 + k * 1e-3)
            t += 1_000_000
        k_t = np.round((np.array([e.torque_nm for e in out]) - 10) * 1000).astype(int)
        k_w = np.round((np.array([e.speed_rad_s for e in out]) - 50) * 1000).astype(int)
        return k_t, k_w, est.counts

    k_t, k_w, counts = run(placeholders=True)
    assert np.array_equal(k_t, k_w)
    assert counts["lost"] == 301 and counts["unpaired"] == 0
    assert len(k_t) == 1700 - 301
    k_t, k_w, _ = run(placeholders=False)
    assert np.sum(k_t != k_w) > 50  # what the placeholders prevent


def _sample_indices(estimates) -> tuple[np.ndarray, np.ndarray]:
    """Sample k's inputs are torque 10 + k/1000 and speed 50 + k/1000: each estimate's two k."""
    return (np.round((np.array([e.torque_nm for e in estimates]) - 10) * 1000),
            np.round((np.array([e.speed_rad_s for e in estimates]) - 50) * 1000))


def test_a_node_preempted_while_it_catches_up_keeps_every_pair_by_the_publishers_clock():
    """The skew detector measures with the publishers' timestamps: a node preempted now and then while
    it takes a backlog (its arrival times spread by milliseconds) pairs every sample with its own
    inputs, seed after seed.  Measured with the arrival times instead, the same takes looked like a
    skew, and the detector dropped a head of a correctly paired stream: hundreds of later samples
    paired with their neighbours'."""
    mispaired_by_arrival = []
    for seed in range(10):
        events = preempted_catch_up(seed)
        est = Estimator(load_config(), "arrival_sequenced", 1e-3)
        k_t, k_w = _sample_indices([e for ch, t, v, sent in events for e in est.push(ch, t, v, sent)])
        assert len(k_t) == 1701 - 301 and np.array_equal(k_t, k_w), f"seed {seed}: {np.sum(k_t != k_w)} mispaired"
        assert est.counts["lost"] == 301 and est.counts["unpaired"] == 0
        est = Estimator(load_config(), "arrival_sequenced", 1e-3)
        k_t, k_w = _sample_indices([e for ch, t, v, _ in events for e in est.push(ch, t, v)])
        mispaired_by_arrival.append(int(np.sum(k_t != k_w)))
    assert max(mispaired_by_arrival) > 100, "the takes never looked like a skew: nothing tested"


@pytest.mark.parametrize("late", [OUT_TORQUE, OUT_SPEED])
@pytest.mark.parametrize("held_ms", [60, 150, 1000])
def test_lossless_arrival_pairing_waits_for_a_measured_output_whose_delivery_was_held_up(late, held_ms):
    """Over a reliable, keep-all delivery an output topic is held up (a repair of the reliable
    protocol takes a heartbeat period, ~0.1 s) while the motor topics kept coming: nothing is lost,
    so the output is waited for, not taken as silent -- given up on, its late messages would pair
    with later motor samples for the rest of the stream (residuals of ~90 N·m in a stress run)."""
    sync = SampleSynchronizer(0.0004, 0.1, arrival=True, lossless=True, sample_period_s=1e-3)
    events = []
    for k in range(3000):
        t = 10**9 + k * MS
        for i, channel in enumerate((TORQUE, SPEED, OUT_TORQUE, OUT_SPEED)):
            released = 10**9 + (500 + held_ms) * MS if channel == late and 500 <= k < 500 + held_ms else t
            events.append((released + 1_000 * i, channel, k))
    events.sort(key=lambda e: e[0])
    out = []
    for t, channel, k in events:
        out += sync.push(channel, t, float(k))
    out += sync.flush()
    assert len(out) == 3000 and sync.counts["unpaired"] == sync.counts["output_missing"] == 0
    assert all(s.torque_nm == s.speed_rad_s == s.out_torque_nm == s.out_speed_rad_s for s in out)


def test_lossless_arrival_pairing_is_not_moved_by_a_publisher_late_in_most_samples_by_less_than_a_sample():
    """Reliable, keep all, 1 kHz: the outputs of 70 % of the samples are sent 0.7 periods after their
    torque and the rest 1.4 periods after it (a publisher preempted between a sample's messages on a
    busy machine; each topic still in order).  Their mean offset, each clipped to a period, is near a
    whole period (0.79), yet no pair is a sample off: most pairs lie within 0.75 periods of their
    torque, so nothing is dropped and every sample pairs with its own partners."""
    rng = np.random.default_rng(5)
    n = 600
    t = 1_000_000_000 + 1_000_000 * np.arange(n)
    late = np.where(rng.random(n) < 0.3, 1_400_000, 700_000)
    events = sorted([(int(t[k]), 0, k) for k in range(n)] + [(int(t[k]) + 20_000, 1, k) for k in range(n)]
                    + [(int(t[k] + late[k]), 2, k) for k in range(n)] + [(int(t[k] + late[k]) + 5_000, 3, k)
                                                                           for k in range(n)])
    sync = SampleSynchronizer(0.002, 0.1, arrival=True, lossless=True, sample_period_s=0.001)
    out = []
    for stamp, code, k in events:
        out += sync.push(CHANNELS[code], stamp, float(k), stamp)
    out += sync.flush()
    assert sync.counts["unpaired"] == 0 and len(out) == n
    assert all(s.torque_nm == s.speed_rad_s == s.out_torque_nm == s.out_speed_rad_s for s in out)


def test_a_jittering_output_torque_never_costs_the_loss_estimate():
    """The output torque stamped with jitter of ±0.6 sample period (one message in three beyond the
    pairing tolerance): every drive sample is still estimated -- those whose output lies beyond the
    tolerance without a residual, counted as ``output_missing`` -- message by message (the node) and in
    arrays (replay) alike."""
    from rollergear_ros.calibration.simulate import SimulationOptions, simulate

    rig = simulate(load_config(), SimulationOptions("drive_cycle", 100.0, 5))
    n = 4001
    period = int(rig.t_ns[1] - rig.t_ns[0])
    t = np.asarray(rig.t_ns[:n], dtype=np.int64)
    jittered = np.sort(t + (np.random.default_rng(2).uniform(-0.6, 0.6, n) * period).astype(np.int64))
    streams = [(0, t, rig.torque_meas_nm[:n]), (1, t, rig.speed_rad_s[:n]), (2, jittered, rig.out_torque_meas_nm[:n]),
               (3, t, rig.out_speed_meas_rad_s[:n])]
    codes = np.concatenate([np.full(n, c, dtype=np.int8) for c, _, _ in streams])
    times = np.concatenate([tt for _, tt, _ in streams])
    values = np.concatenate([v for _, _, v in streams])
    order = np.argsort(times, kind="stable")
    codes, times, values = codes[order], times[order], values[order]
    config = load_config().with_values({"estimator.adapt": False})

    batch_est = Estimator(config, sample_period_s=period * 1e-9)
    parts = [p for p in (batch_est.push_many(codes, times, values), batch_est.flush()) if p is not None]
    loss = np.concatenate([p.loss_torque_nm for p in parts])
    residual = np.concatenate([p.residual_nm for p in parts])
    node_est = Estimator(config, sample_period_s=period * 1e-9)
    live = [e for c, tt, v in zip(codes.tolist(), times.tolist(), values.tolist())
            for e in node_est.push(CHANNELS[c], tt, v)] + node_est.finish()
    assert batch_est.estimated == n - batch_est.counts["implausible"] - batch_est.counts["non_finite"] \
        and batch_est.counts["unpaired"] == 0, batch_est.counts
    without = int(np.count_nonzero(np.isnan(residual)))
    assert 0.2 * n < batch_est.counts["output_missing"] == without < 0.5 * n, batch_est.counts
    np.testing.assert_array_equal(np.array([e.loss_torque_nm for e in live]), loss)
    np.testing.assert_array_equal(np.array([e.residual_nm for e in live]), residual)
