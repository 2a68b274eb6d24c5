"""The sample clock rebuilt from the publishers' sequence numbers (core/seqclock.py)."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.core.seqclock import PAUSE_S, RATE_LEARN, SequenceClock

PERIOD_NS = 5_000_000  # 200 Hz
TOPICS = ("torque", "speed", "out_torque")


def _feed(clock: SequenceClock, deliveries) -> dict[str, list[int]]:
    """(topic, sequence number, reference time) in delivery order -> each topic's times."""
    times: dict[str, list[int]] = {}
    for topic, sequence, reference_ns in deliveries:
        times.setdefault(topic, []).append(clock.time_ns(topic, sequence, reference_ns))
    return times


def _rig(n: int, jitter_ns: np.ndarray, start_ns: int = 10**18) -> list[tuple[str, int, int]]:
    """A loop publishing the three topics once per period; their publisher timestamps ``jitter_ns`` off
    the period (per message), delivered topic by topic in the order of those timestamps."""
    out = [(topic, k + 1, start_ns + k * PERIOD_NS + int(jitter_ns[3 * k + i]))
           for k in range(n) for i, topic in enumerate(TOPICS)]
    return sorted(out, key=lambda m: m[2])


@pytest.mark.parametrize("held_s", [0.9, 1.5, 5.0])
def test_delivery_jitter_and_a_catch_up_burst_change_no_time(held_s):
    """Timestamps that jitter by 0.9 periods, and a publisher held up for up to 5 s (a reliable one
    whose subscriber stalled) that then sends what it owes in a burst: every message keeps the time of
    its number on one grid, equal across topics."""
    rng = np.random.default_rng(4)
    n = 2000
    deliveries = _rig(n, rng.uniform(-0.45, 0.45, 3 * n) * PERIOD_NS)
    t0 = 10**18
    resumed = t0 + 200 * PERIOD_NS + int(held_s * 1e9)
    # the samples due while it was held up (after sample 200) go out as soon as it is free, 1 µs apart
    owed = [m for m in deliveries if 200 < m[1] and m[2] < resumed]
    held = [(tp, k, resumed + 1000 * i) for i, (tp, k, _) in enumerate(owed)]
    stalled = [m for m in deliveries if m[1] <= 200] + held + [m for m in deliveries if m[2] >= resumed
                                                                and 200 < m[1] and m not in owed]
    assert len(stalled) == len(deliveries) and len(owed) > 3 * 150
    for fed in (deliveries, stalled):
        times = _feed(SequenceClock(PERIOD_NS * 1e-9), fed)
        first = times["torque"][0]
        for topic in TOPICS:
            np.testing.assert_array_equal(np.asarray(times[topic]) - first, np.arange(n) * PERIOD_NS)


def test_a_lost_message_leaves_its_slot_and_a_topic_numbered_apart_takes_the_slot_of_its_time():
    clock = SequenceClock(PERIOD_NS * 1e-9)
    t0 = 10**18
    assert clock.time_ns("torque", 1, t0) == t0
    assert clock.time_ns("torque", 4, t0 + 3 * PERIOD_NS + 700_000) == t0 + 3 * PERIOD_NS  # 2 and 3 lost
    assert clock.gap == 2
    # a topic whose number pairs it with no message kept (a publisher numbering far apart) joins at
    # the slot nearest its time
    assert clock.time_ns("speed", 5001, t0 + 3 * PERIOD_NS + 2_100_000) == t0 + 3 * PERIOD_NS
    assert clock.gap == 0  # a topic's first message follows no loss of its own
    assert clock.time_ns("speed", 5002, t0 + 4 * PERIOD_NS - 1_900_000) == t0 + 4 * PERIOD_NS
    assert clock.rate_problem is None and clock.step_problem is None and clock.pauses == 0


@pytest.mark.parametrize("pause_s", [PAUSE_S * 1.5, 30.0])
def test_a_pause_in_publishing_moves_the_clock_on_and_a_restart_never_back(pause_s):
    """A publisher that stops and goes on numbering: the clock takes the slot of its timestamp, not the
    next one; one that starts again from 1: the next slot at least (never an earlier time)."""
    clock = SequenceClock(PERIOD_NS * 1e-9)
    t0 = 10**18
    before = [clock.time_ns("torque", k + 1, t0 + k * PERIOD_NS) for k in range(10)]
    resumed = t0 + 9 * PERIOD_NS + int(pause_s * 1e9)
    after = clock.time_ns("torque", 11, resumed)
    assert abs(after - resumed) <= PERIOD_NS // 2 and (after - before[0]) % PERIOD_NS == 0
    assert clock.pauses == 1
    restarted = clock.time_ns("torque", 1, resumed + 10_000)  # numbering from 1 again, a moment later
    assert restarted == after + PERIOD_NS and clock.pauses == 2
    assert clock.time_ns("torque", 2, resumed + 10_000 + PERIOD_NS) == restarted + PERIOD_NS


def test_a_pause_shorter_than_the_limit_is_taken_for_a_stall():
    clock = SequenceClock(PERIOD_NS * 1e-9)
    t0 = 10**18
    for k in range(5):
        clock.time_ns("torque", k + 1, t0 + k * PERIOD_NS)
    assert clock.time_ns("torque", 6, t0 + 4 * PERIOD_NS + int(0.9 * PAUSE_S * 1e9)) == t0 + 5 * PERIOD_NS
    assert clock.pauses == 0


def test_publishers_at_another_rate_than_the_clock_are_said_once_learned():
    """A recording played three times as fast: the times stay the numbers on the clock's grid, and
    once :data:`RATE_LEARN` intervals are in, the clock says the publishers' rate and its own."""
    clock = SequenceClock(PERIOD_NS * 1e-9)
    t0 = 10**18
    times = [clock.time_ns("torque", k + 1, t0 + k * PERIOD_NS // 3) for k in range(RATE_LEARN)]
    assert clock.rate_problem is None
    times.append(clock.time_ns("torque", RATE_LEARN + 1, t0 + RATE_LEARN * PERIOD_NS // 3))
    np.testing.assert_array_equal(np.diff(times), PERIOD_NS)
    assert clock.rate_problem is not None and "600 Hz" in clock.rate_problem and "200 Hz" in clock.rate_problem


def test_a_clock_without_a_rate_is_refused():
    with pytest.raises(ValueError, match="period > 0"):
        SequenceClock(0.0)


def test_topics_of_a_recording_played_faster_join_the_slot_of_their_time_not_the_latest():
    """Played ten times as fast, the torque's second message may come before the speed's first: the
    speed still joins at slot 0, beside the torque published with it."""
    clock = SequenceClock(PERIOD_NS * 1e-9)
    t0 = 10**18
    fast = PERIOD_NS // 10
    assert clock.time_ns("torque", 1, t0) == t0
    assert clock.time_ns("torque", 2, t0 + fast) == t0 + PERIOD_NS
    assert clock.time_ns("torque", 3, t0 + 2 * fast) == t0 + 2 * PERIOD_NS
    assert clock.time_ns("speed", 1, t0 + 30_000) == t0
    assert clock.time_ns("speed", 2, t0 + fast + 30_000) == t0 + PERIOD_NS


def test_the_merge_hands_on_in_time_order_whatever_topic_comes_first():
    """One topic's backlog taken before the others' (a stalled node catching up): every message comes
    out in time order, each once no topic can still come before it; the rest when the stream ends."""
    from rollergear_ros.core.seqclock import ClockMerge

    merge = ClockMerge()
    assert merge.push("torque", 0, 0, ("torque", 0)) == [("torque", 0)]  # alone so far: nothing to wait for
    assert merge.push("speed", 0, 0, ("speed", 0)) == [("speed", 0)]
    out = []
    for k in range(1, 10):  # the torque's backlog first: held for the speed
        out += merge.push("torque", k * PERIOD_NS, k, ("torque", k))
    assert out == [] and len(merge) == 9
    for k in range(1, 8):
        out += merge.push("speed", k * PERIOD_NS, k, ("speed", k))
    assert out == [(name, k) for k in range(1, 8) for name in ("torque", "speed")]
    assert merge.drain() == [("torque", 8), ("torque", 9)] and len(merge) == 0


def test_a_topic_that_stopped_publishing_holds_nothing_back():
    from rollergear_ros.core.seqclock import SILENT_S, ClockMerge

    merge = ClockMerge()
    assert merge.push("out_torque", 0, 0, "out 0") == ["out 0"]
    assert merge.push("torque", 0, 0, "torque 0") == ["torque 0"]
    assert merge.push("torque", PERIOD_NS, int(0.5 * SILENT_S * 1e9), "torque 1") == []  # still waited for
    late = int(1.5 * SILENT_S * 1e9)
    assert merge.push("torque", 2 * PERIOD_NS, late, "torque 2") == ["torque 1", "torque 2"]


def test_a_topic_numbered_alike_joins_beside_its_partner_though_its_publisher_was_preempted():
    """A recording played ten times as fast whose player was preempted for 3 ms between the torque's
    first message and the speed's: by its timestamp the speed would join three slots late; its number
    puts it beside the torque published with it.  A publisher numbering apart (started later) joins
    by its timestamp."""
    clock = SequenceClock(PERIOD_NS * 1e-9)
    t0 = 10**18
    fast = PERIOD_NS // 10
    for k in range(5):
        clock.time_ns("torque", k + 1, t0 + k * fast)
    assert clock.time_ns("speed", 1, t0 + 3 * fast + 100_000) == t0
    assert clock.time_ns("speed", 2, t0 + 4 * fast + 100_000) == t0 + PERIOD_NS
    # preempted for 4 ms where the clock's period is 1 ms: its number still puts it beside its partner
    clock = SequenceClock(1e-3)
    assert clock.time_ns("torque", 1, t0) == t0
    assert clock.time_ns("speed", 1, t0 + 4_000_000) == t0
    for k in range(1, RATE_LEARN + 2):
        assert clock.time_ns("torque", k + 1, t0 + k * 1_000_000) == clock.time_ns("speed", k + 1, t0 + k * 1_000_000)
    assert clock.step_problem is None


def test_a_publisher_that_numbers_out_of_step_is_said():
    """Publishers that do not number alike (one started three samples after the other, both from 1):
    paired by number, their messages lie three periods apart; once its first messages are in, the clock
    says which topic and by how much."""
    clock = SequenceClock(PERIOD_NS * 1e-9)
    t0 = 10**18
    for k in range(RATE_LEARN + 3):
        clock.time_ns("torque", k + 1, t0 + k * PERIOD_NS)
        if k >= 3:
            clock.time_ns("out_torque", k - 2, t0 + k * PERIOD_NS + 50_000)
    assert clock.step_problem is not None
    assert "out_torque's publisher numbers its messages out of step with torque's" in clock.step_problem
    assert "+15 ms" in clock.step_problem, clock.step_problem
