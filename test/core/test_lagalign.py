"""The lag aligner (rollergear_ros.core.lagalign): one answer however the samples are fed, whatever their
stamps do; what it cannot order and what the stamps' jitter does to the lags, counted."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.core.lagalign import LagAligner

PERIOD_NS = 5_000_000  # 200 Hz
LAGS = {"motor_speed": -0.0073, "output_torque": 0.0131, "output_speed": 0.0207}


def _stamps(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """A 200 Hz stream's stamps as hostile inputs give them."""
    t = np.arange(n, dtype=np.int64) * PERIOD_NS
    if kind == "repeated":  # a stamp given twice now and then (a clock with a coarse tick)
        k = rng.choice(np.arange(1, n), n // 10, replace=False)
        t[k] = t[k - 1]
    elif kind == "backwards":  # now and then a stamp a period or two behind the one before
        k = rng.choice(np.arange(2, n), n // 20, replace=False)
        t[k] = t[k - 1] - rng.integers(1, 2 * PERIOD_NS, len(k))
    elif kind == "jitter":  # jitter of more than a period either way
        t = t + rng.uniform(-1.2 * PERIOD_NS, 1.2 * PERIOD_NS, n).astype(np.int64)
    elif kind == "wild":  # jitter far beyond the reorder window (some come too late to be ordered)
        t = t + rng.normal(0.0, 1.5 * PERIOD_NS, n).astype(np.int64)
    elif kind == "stall":  # jittered arrivals and a 1 s stall, then the backlog in a burst
        t = t + np.abs(rng.normal(0.0, 0.4 * PERIOD_NS, n)).astype(np.int64)
        t[n // 2: n // 2 + 200] = t[n // 2 + 200]
        t = np.maximum.accumulate(t)
    elif kind == "far_back":  # a stamp far behind the rest (a clock reset)
        t[n // 3] -= 10**9
    return t


def _feed(aligner: LagAligner, paired: tuple[np.ndarray, ...], sizes: list[int]) -> tuple[np.ndarray, ...]:
    out, k = [], 0
    for size in sizes:
        out.append(aligner.push(tuple(a[k:k + size] for a in paired)))
        k += size
    out.append(aligner.flush())
    return tuple(np.concatenate([part[j] for part in out]) for j in range(6))


@pytest.mark.parametrize("kind", ["regular", "repeated", "backwards", "jitter", "wild", "stall", "far_back"])
@pytest.mark.parametrize("seed", range(4))
def test_one_sample_at_a_time_and_batches_give_one_answer_whatever_the_stamps_do(kind, seed):
    """The node feeds its aligner one sample at a time, replay in batches of any size: stamps that
    repeat, go backwards, jitter by more than a period, stall, or jump far back give the same samples
    out, in the same (time) order, with the same values to the last bit, and the same counts."""
    rng = np.random.default_rng(seed)
    n = 1500
    t = _stamps(kind, n, rng)
    phase = np.cumsum(rng.normal(0.0, 0.05, n))
    paired = (t, 1.0 + np.sin(phase), 5.0 * np.cos(phase), -0.9 * np.sin(phase), 0.05 * np.cos(phase),
              np.full(n, 40.0))
    answers = []
    for sizes in ([1] * n, [n], list(rng.integers(1, 50, n)), [7, 300, 1, 1, 2, 1189]):
        aligner = LagAligner(LAGS, 0.1, PERIOD_NS * 1e-9)
        out = _feed(aligner, paired, [int(s) for s in sizes])
        answers.append((out, aligner.late, dict(aligner.held), aligner.jittered, aligner.intervals))
    first, late, held, jittered, intervals = answers[0]
    assert np.all(np.diff(first[0]) >= 0)  # in time order
    assert len(first[0]) + late == n  # every sample out, or counted too late to order
    for out, *counts in answers[1:]:
        for a, b in zip(first, out):
            np.testing.assert_array_equal(a, b)
        assert counts == [late, held, jittered, intervals]
    if kind in ("regular", "repeated", "backwards", "jitter"):
        assert late == 0  # within the reorder window: ordered, none lost
    if kind == "far_back":
        assert late == 1
    if kind == "wild":
        assert 0 < late < 0.1 * n


def test_the_stamps_jitter_is_said_when_it_exceeds_what_the_lags_assume():
    """Stamps off the period by more than half the shortest lag in more than 1 % of the intervals are
    said; a steady clock and its pauses are not."""
    rng = np.random.default_rng(1)
    n = 2000

    def text(t):
        aligner = LagAligner(LAGS, 0.1, PERIOD_NS * 1e-9)
        paired = (t, *(np.zeros(n) for _ in range(5)))
        _feed(aligner, paired, [n])
        return aligner.jitter_text()

    steady = np.arange(n, dtype=np.int64) * PERIOD_NS
    steady[1000:] += 2 * 10**9  # a pause is no jitter
    assert text(steady) == ""
    jittered = np.arange(n, dtype=np.int64) * PERIOD_NS + rng.normal(0, 6.5e6, n).astype(np.int64)
    said = text(jittered)
    assert "the stamps jitter" in said and "3.65 ms, half the shortest lag" in said, said
