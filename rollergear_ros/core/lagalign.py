"""A channel that reads late, aligned: ``estimator.<channel>_lag_s`` applied to paired samples.

A reading that lags the drive torque by τ (a DAQ on its own clock, a filter in the sensor) reads at
time ``t`` what the gearbox did at ``t − τ``.  :class:`LagAligner` sits between the pairing and the
estimate: each paired sample at ``t`` takes the lagging channel's value at ``t + τ``, linearly
interpolated between the two paired samples around it -- a sample waits until one at or after
``t + τ`` has come (τ > 0), or takes it from the samples before (τ < 0: the channel leads).  Where no
pair of samples brackets ``t + τ`` within ``max_gap_s`` (a pause in the recording, the end of a
stream; :func:`max_gap_s`: the staleness, or :data:`GAP_PERIODS` sample periods of a slower recording),
the nearest reading is held where it lies within ``|τ|`` of ``t + τ`` (the last of a run before a pause:
no later reading exists, and one from before the lag is closer than any other), counted per channel
(:attr:`LagAligner.held`); beyond that the value is NaN: that sample has no reading to align.
Samples are put in stamp order within a bounded window and given out once nothing still to come can
change what they read, so the node (one sample at a time) and replay (batches) give one answer whatever
the stamps do (:class:`LagAligner`); stamps that jitter more than the lags can stand are counted and said.
``calibrate`` writes the lag it found and aligned into the file, and the node, ``replay`` and
``calibrate``'s own claims apply it here -- one rule for all.  Zero lags (the default) change nothing.  No rclpy import.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["GAP_PERIODS", "LAG_CHANNELS", "REORDER_PERIODS", "LagAligner", "max_gap_s"]

#: channels a lag can be given for, and their column in a paired sample
#: ``(t_ns, torque, speed, out_torque, out_speed, temperature)``
LAG_CHANNELS = {"motor_speed": 2, "output_torque": 3, "output_speed": 4}
_CHANNEL_OF_COLUMN = {column: name for name, column in LAG_CHANNELS.items()}
#: two samples this many sample periods apart still bracket ``t + τ``: one sample missing is no gap
GAP_PERIODS = 2.5
#: stamps may come out of order by this many sample periods (at most the widest gap) and still be ordered
REORDER_PERIODS = 2.5
#: the stamps jitter beyond what the lags assume when more than this share of their intervals (and at
#: least :data:`JITTER_MIN` of them) are off the sample period by more than half the shortest lag
JITTER_SHARE = 0.01
JITTER_MIN = 10
JITTER_LEARN = 64  #: the stamps' period is the median of this many of their first intervals


def max_gap_s(staleness_s: float, sample_period_s: float | None) -> float:
    """The widest span two samples may bracket ``t + τ`` across: ``estimator.staleness_s``, or
    :data:`GAP_PERIODS` periods of a recording whose samples are further apart than that (a controller
    read every 256 ms: with the staleness alone, no two of its samples would bracket any time)."""
    return max(staleness_s, GAP_PERIODS * (sample_period_s or 0.0))


class LagAligner:
    """Paired samples in, the same samples out (in time order) with each lagging channel read at ``t + τ``.

    The answer does not depend on how the samples are fed -- one at a time (the node) or in batches
    (replay) -- whatever their stamps do: samples are ordered by stamp (ties in arrival order) within
    a reorder window (:data:`REORDER_PERIODS` sample periods, at most the widest gap); a sample whose
    stamp lies further back than that behind the newest already seen comes too late to be ordered and
    is not estimated (:attr:`late`, skip reason ``out_of_order``).  A sample is given out once no sample
    still to come can change what it reads: a later sample around ``t + τ`` is already in and behind
    the reorder window, or ``t + τ`` lies further back than any reading could still count from.
    ``sample_period_s`` (the reorder window, where known) is the recording's median period offline,
    ``1/node.expected_rate_hz`` live.  The stamps' intervals are measured against their own period (the
    median of the first ones): more than :data:`JITTER_SHARE` of them off it by more than half the
    shortest lag, and the lags read the channels at the wrong times (:attr:`jittered`, said)."""

    def __init__(self, lags_s: Mapping[str, float], max_gap_s: float, sample_period_s: float | None = None) -> None:
        self.lags_ns = {LAG_CHANNELS[c]: int(round(v * 1e9)) for c, v in lags_s.items() if v}
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.period_ns = int(round(sample_period_s * 1e9)) if sample_period_s and sample_period_s > 0 else 0
        #: how far behind the newest stamp a sample may come and still be put in its place
        self.window_ns = min(self.max_gap_ns, int(REORDER_PERIODS * self.period_ns)) if self.period_ns \
            else self.max_gap_ns
        #: beyond this from ``t + τ`` no reading counts (neither bracketing it nor held as the nearest)
        self._reach_ns = max([self.max_gap_ns, *(abs(v) for v in self.lags_ns.values())])
        self._back_ns = max([0, *(-v for v in self.lags_ns.values())])  #: how far back values are read
        self._times = np.empty(0, dtype=np.int64)  #: the samples kept (time order): history and those waiting
        self._rows = np.empty((0, 5))  #: their torque, speed, output torque, output speed, temperature
        self._pending = 0  #: index of the first sample not yet given out
        self._newest_ns: int | None = None  #: the newest stamp seen
        self._previous_ns: int | None = None  #: the stamp of the sample fed last (jitter)
        #: channel -> samples that took the nearest reading (no two around ``t + τ``: a pause, an end)
        self.held: dict[str, int] = {_CHANNEL_OF_COLUMN[column]: 0 for column in self.lags_ns}
        self.late = 0  #: samples whose stamp came further back than the reorder window: not estimated
        self.intervals = 0  #: stamp intervals measured (successive samples as fed, pauses excluded)
        #: ... off the stamps' own period by more than half the shortest lag (or backwards): stamps too
        #: unsteady for the lags to be applied on them (a jittering publisher, an executor's stall)
        self.jittered = 0
        self.reference_ns: int | None = None  #: the stamps' own period, learned from their first intervals
        self._first_steps = np.empty(0, dtype=np.int64)

    @property
    def active(self) -> bool:
        return bool(self.lags_ns)

    def describe(self) -> str:
        """``output_torque 29.8 ms late: read at t + lag``."""
        return "; ".join(f"{_CHANNEL_OF_COLUMN[c]} {abs(v) * 1e-6:.3g} ms {'late' if v > 0 else 'early'}"
                         for c, v in self.lags_ns.items()) + ": each sample takes its value at t + lag"

    def text(self) -> str:
        """:meth:`describe`, the samples that held the nearest reading (no two around ``t + τ``), and
        :meth:`jitter_text`."""
        parts = [self.describe()]
        for column, lag in self.lags_ns.items():
            name = _CHANNEL_OF_COLUMN[column]
            if self.held[name]:
                parts.append(f"no {name} reading {abs(lag) * 1e-6:.3g} ms {'later' if lag > 0 else 'earlier'} "
                             f"at {self.held[name]:,} samples (a pause or an end of the recording): the "
                             "nearest reading held")
        return "; ".join(p for p in (*parts, self.jitter_text()) if p)

    @property
    def jitters(self) -> bool:
        """Whether the stamps jitter beyond what the lags assume (:data:`JITTER_SHARE`)."""
        return self.jittered > JITTER_SHARE * self.intervals and self.jittered >= JITTER_MIN

    def jitter_text(self) -> str:
        """What the stamps did that the lags cannot be applied on ('' when nothing): the samples too late
        to order, the share of intervals off the period by more than half the shortest lag."""
        parts = []
        if self.late:
            parts.append(f"{self.late:,} samples stamped more than {self.window_ns * 1e-6:.3g} ms before one "
                         "already seen came too late to be ordered (skipped as out of order)")
        if self.jitters:
            half = 0.5 * min(abs(v) for v in self.lags_ns.values())
            period_ms = (self.reference_ns or 0) * 1e-6
            parts.append(f"the stamps jitter: {self.jittered:,} of {self.intervals:,} sample intervals are off their "
                         f"{period_ms:.3g} ms period by more than {half * 1e-6:.3g} ms, half the shortest lag: "
                         "the lags read the channels at the wrong times there (a jittering publisher, an executor "
                         "that stalled; stamp the inputs at the source)")
        return "; ".join(parts)

    def push(self, paired: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        """Paired arrays in (arrival order); out, the aligned samples whose lagging values are final now."""
        t = np.asarray(paired[0], dtype=np.int64)
        if len(t):
            rows = np.column_stack([np.asarray(a, dtype=float) for a in paired[1:]])
            self._measure_jitter(t)
            newest = np.maximum.accumulate(t)
            before = np.concatenate([[t[0] if self._newest_ns is None else self._newest_ns], newest[:-1]])
            if self._newest_ns is not None:
                before[1:] = np.maximum(before[1:], self._newest_ns)
                newest = np.maximum(newest, self._newest_ns)
            on_time = t >= before - self.window_ns
            self.late += int(len(t) - np.count_nonzero(on_time))
            self._newest_ns = int(newest[-1])
            t, rows = t[on_time], rows[on_time]
            if len(t):
                times = np.concatenate([self._times, t])
                order = np.argsort(times, kind="stable")  # ties: in arrival order
                self._times = times[order]
                self._rows = np.concatenate([self._rows, rows])[order]
        return self._emit(final=False)

    def flush(self) -> tuple[np.ndarray, ...]:
        """At the end of a stream: the samples still waiting, aligned where their values are known."""
        return self._emit(final=True)

    def _measure_jitter(self, t: np.ndarray) -> None:
        """Count the intervals between successive stamps (as fed; pauses excluded) that stray from the
        stream's own period: the median of its first :data:`JITTER_LEARN` intervals."""
        steps = np.diff(t) if self._previous_ns is None else np.diff(np.concatenate([[self._previous_ns], t]))
        self._previous_ns = int(t[-1])
        steps = steps[steps <= self.max_gap_ns]  # a pause is no jitter
        if self.reference_ns is None:
            self._first_steps = np.concatenate([self._first_steps, steps])
            if len(self._first_steps) < JITTER_LEARN:
                return
            self.reference_ns = int(np.median(self._first_steps[:JITTER_LEARN]))
            steps, self._first_steps = self._first_steps, np.empty(0, dtype=np.int64)
        half = min(abs(v) for v in self.lags_ns.values()) // 2 if self.lags_ns else 0
        self.intervals += len(steps)
        self.jittered += int(np.count_nonzero(np.abs(steps - self.reference_ns) > half))

    def _emit(self, final: bool) -> tuple[np.ndarray, ...]:
        times, rows = self._times, self._rows
        if self._pending >= len(times):
            return _empty()
        stop = len(times) if final else self._settled()
        stop = max(stop, self._pending)
        idx = np.arange(self._pending, stop)
        out = [times[idx], *(rows[idx, j].copy() for j in range(5))]
        for column, lag in self.lags_ns.items():
            out[column], held = self._at(rows[:, column - 1], times[idx] + lag, abs(lag))
            self.held[_CHANNEL_OF_COLUMN[column]] += held
        self._pending = stop
        if stop:  # keep what the samples still waiting may read back to (one sample before it)
            keep = max(int(np.searchsorted(times, int(times[stop - 1]) - self._back_ns, side="left")) - 1, 0)
            self._times, self._rows, self._pending = times[keep:], rows[keep:], stop - keep
        return tuple(out)

    def _settled(self) -> int:
        """How many of the waiting samples (a prefix, in time order) are final.  Every sample still to
        come is stamped at or after ``bound = newest - window``: a sample stamped at or before the bound
        is in its place, and what it reads at ``t + τ`` is final once a sample after ``t + τ`` is in and
        stamped at or before the bound (none to come can fall between), or once ``t + τ`` lies more than
        the reach before the bound (no reading to come counts for it)."""
        times = self._times
        bound = self._newest_ns - self.window_ns
        waiting = times[self._pending:]
        settled = waiting <= bound  # none to come is put before it
        for lag in self.lags_ns.values():
            at = waiting + lag
            after = np.searchsorted(times, at, side="right")
            known = after < len(times)
            first_after = times[np.minimum(after, len(times) - 1)]
            settled &= (known & (first_after <= bound)) | (at + self._reach_ns < bound)
        if settled.all():
            return len(times)
        return self._pending + int(np.argmin(settled))

    def _at(self, values: np.ndarray, at: np.ndarray, hold_ns: int) -> tuple[np.ndarray, int]:
        """``values`` at times ``at``: linear between the two samples around each (the sample itself at
        its own time); where no two within ``max_gap_s`` bracket it, the nearest sample's value if it lies
        within ``hold_ns`` of it (else NaN).  Also how many took the nearest."""
        times = self._times
        j = np.searchsorted(times, at, side="right")  # times[j-1] <= at < times[j]
        lo = np.clip(j - 1, 0, max(len(times) - 1, 0))
        hi = np.clip(j, 0, max(len(times) - 1, 0))
        exact = (j > 0) & (times[lo] == at)
        span = (times[hi] - times[lo]).astype(np.float64)
        inside = (j > 0) & (j < len(times)) & (span > 0) & (span <= self.max_gap_ns)
        w = (at - times[lo]).astype(np.float64) / np.where(span > 0, span, 1.0)
        between = values[lo] + w * (values[hi] - values[lo])
        to_lo, to_hi = np.abs(at - times[lo]), np.abs(times[hi] - at)
        nearest = np.where(to_lo <= to_hi, lo, hi)
        held = ~exact & ~inside & (np.minimum(to_lo, to_hi) <= hold_ns)
        out = np.where(exact, values[lo], np.where(inside, between, np.where(held, values[nearest], np.nan)))
        return out, int(np.count_nonzero(held))


def _empty() -> tuple[np.ndarray, ...]:
    z = np.empty(0)
    return np.empty(0, dtype=np.int64), z, z, z, z, z
