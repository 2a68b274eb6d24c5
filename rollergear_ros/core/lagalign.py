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
``calibrate`` writes the lag it found and aligned into the file, and the node, ``replay`` and
``calibrate``'s own claims apply it here -- one rule for all.  Zero lags (the default) change nothing.  No rclpy import.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["GAP_PERIODS", "LAG_CHANNELS", "LagAligner", "max_gap_s"]

#: channels a lag can be given for, and their column in a paired sample
#: ``(t_ns, torque, speed, out_torque, out_speed, temperature)``
LAG_CHANNELS = {"motor_speed": 2, "output_torque": 3, "output_speed": 4}
#: two samples this many sample periods apart still bracket ``t + τ``: one sample missing is no gap
GAP_PERIODS = 2.5


def max_gap_s(staleness_s: float, sample_period_s: float | None) -> float:
    """The widest span two samples may bracket ``t + τ`` across: ``estimator.staleness_s``, or
    :data:`GAP_PERIODS` periods of a recording whose samples are further apart than that (a controller
    read every 256 ms: with the staleness alone, no two of its samples would bracket any time)."""
    return max(staleness_s, GAP_PERIODS * (sample_period_s or 0.0))


class LagAligner:
    """Paired samples in, the same samples out with each lagging channel read at ``t + τ``."""

    def __init__(self, lags_s: Mapping[str, float], max_gap_s: float) -> None:
        self.lags_ns = {LAG_CHANNELS[c]: int(round(v * 1e9)) for c, v in lags_s.items() if v}
        self.max_gap_ns = int(max_gap_s * 1e9)
        self._lead_ns = max([0, *self.lags_ns.values()])  #: how far ahead a sample waits
        self._back_ns = max([0, *(-v for v in self.lags_ns.values())])  #: how far back values are read
        self._times = np.empty(0, dtype=np.int64)  #: the samples kept: history and those waiting
        self._rows = np.empty((0, 5))  #: their torque, speed, output torque, output speed, temperature
        self._pending = 0  #: index of the first sample not yet given out
        #: channel -> samples that took the nearest reading (no two around ``t + τ``: a pause, an end)
        self.held: dict[str, int] = {name: 0 for name, column in LAG_CHANNELS.items() if column in self.lags_ns}

    @property
    def active(self) -> bool:
        return bool(self.lags_ns)

    def describe(self) -> str:
        """``output_torque 29.8 ms late: read at t + lag``."""
        names = {column: name for name, column in LAG_CHANNELS.items()}
        return "; ".join(f"{names[c]} {abs(v) * 1e-6:.3g} ms {'late' if v > 0 else 'early'}"
                         for c, v in self.lags_ns.items()) + ": each sample takes its value at t + lag"

    def push(self, paired: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        """Paired arrays in (time order); out, the aligned samples whose lagging values are known now."""
        t = np.asarray(paired[0], dtype=np.int64)
        if len(t):
            rows = np.column_stack([np.asarray(a, dtype=float) for a in paired[1:]])
            self._times = np.concatenate([self._times, t])
            self._rows = np.concatenate([self._rows, rows])
        return self._emit(final=False)

    def flush(self) -> tuple[np.ndarray, ...]:
        """At the end of a stream: the samples still waiting, aligned where their values are known."""
        return self._emit(final=True)

    def _emit(self, final: bool) -> tuple[np.ndarray, ...]:
        times, rows = self._times, self._rows
        if self._pending >= len(times):
            return _empty()
        stop = len(times) if final else int(np.searchsorted(times, int(times[-1]) - self._lead_ns, side="right"))
        stop = max(stop, self._pending)
        idx = np.arange(self._pending, stop)
        out = [times[idx], *(rows[idx, j].copy() for j in range(5))]
        names = {column: name for name, column in LAG_CHANNELS.items()}
        for column, lag in self.lags_ns.items():
            out[column], held = self._at(rows[:, column - 1], times[idx] + lag, abs(lag))
            self.held[names[column]] += held
        self._pending = stop
        if stop:  # keep what the samples still waiting may read back to (one sample before it)
            keep = max(int(np.searchsorted(times, int(times[stop - 1]) - self._back_ns, side="left")) - 1, 0)
            self._times, self._rows, self._pending = times[keep:], rows[keep:], stop - keep
        return tuple(out)

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
