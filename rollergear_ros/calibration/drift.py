"""A drift: a loss that moves one way in time, told apart from steps (after :mod:`.segments` found where it
changes).

Changes in a row whose shifts all go one way, or one change whose two sides each trend the way it steps,
are a drift -- a warm-up without an oil temperature channel, running-in, wear -- not steps: no step's
time or interval is claimed for it.  It is reported with its rate over the recording (the residual of one
fit across, over time: a line, with its 95 % interval) and what it follows most closely: the time, the
energy the gearbox dissipated, or the oil temperature where it was recorded (the correlation of the
residual with each).  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .leastsquares import orthonormal_basis, wls
from .segments import Split, running_time, small_design
from .selection import Calibrator, Term

__all__ = ["Drift", "find_drift"]

#: a side of a single change trends the way it steps when its slope is this many standard errors from 0
TREND_Z = 3.0


@dataclass(frozen=True)
class Drift:
    """A loss that moves one way in time (:func:`find_drift`)."""

    rate_nm_per_s: float  #: the residual's slope over the recording [N·m/s]
    ci95: tuple[float, float]
    start_s: float  #: the span it was measured over (the recordings one after another) [s]
    end_s: float
    follows: str  #: "time", "energy dissipated" or "oil temperature"
    correlation: dict[str, float]  #: the residual's correlation with each

    @property
    def total_nm(self) -> float:
        return self.rate_nm_per_s * (self.end_s - self.start_s)

    def sentence(self, latest_from_s: float) -> str:
        way = "fell" if self.rate_nm_per_s < 0 else "rose"
        said = ", ".join(f"{k} {v:+.2f}" for k, v in self.correlation.items())
        return (f"the loss {way} steadily over the recordings: {100 * self.rate_nm_per_s:+.3g} N·m per 100 s (95 %: "
                f"{100 * self.ci95[0]:+.3g} to {100 * self.ci95[1]:+.3g}), {self.total_nm:+.3g} N·m from "
                f"{self.start_s:.0f} to {self.end_s:.0f} s, following {self.follows} most closely (correlation "
                f"{said}): a drift, not steps -- a warm-up without an oil temperature channel, running-in or wear "
                f"looks like this; the file is calibrated on the latest stretch (from {latest_from_s:.1f} s) and holds "
                "for the conditions there" + ("" if "oil temperature" in self.correlation else
                                              "; log the oil temperature to calibrate what the loss follows "
                                              "(viscosity_temperature)"))

    def to_json(self) -> dict:
        return {"rate_nm_per_s": self.rate_nm_per_s, "ci95": list(self.ci95), "start_s": self.start_s,
                "end_s": self.end_s, "total_nm": self.total_nm, "follows": self.follows,
                "correlation": self.correlation}


def find_drift(cal: Calibrator, terms: list[Term], splits: list[Split]) -> Drift | None:
    """Whether the changes ``splits`` are a drift (see the module docstring), and its rate; None: steps."""
    if not splits:
        return None
    b = cal.b
    t = running_time(b)
    x = orthonormal_basis(small_design(cal, terms), b.weight)
    r = b.y - x @ wls(x, b.y, b.weight).coef  # the residual of one fit across
    shifts = np.array([sp.shift_nm for sp in splits])
    one_way = len(splits) >= 2 and (np.all(shifts > 0) or np.all(shifts < 0))
    if not one_way and len(splits) == 1:
        k = splits[0].block
        way = math.copysign(1.0, splits[0].shift_nm)
        one_way = all(_slope_z(t[side], r[side], b.weight[side], b.dwell[side]) * way > TREND_Z
                      for side in (slice(0, k), slice(k, None)))
    if not one_way:
        return None
    slope, se = _slope(t, r, b.weight, b.dwell)
    corr = {"time": _corr(r, t, b.count)}
    duration = np.diff(np.r_[t, t[-1]])
    energy = np.cumsum(np.abs(b.measured * b.speed) * np.maximum(duration, 0.0))
    corr["energy dissipated"] = _corr(r, energy, b.count)
    theta = b.temperature
    if np.mean(np.isfinite(theta)) > 0.9 and np.nanmax(theta) - np.nanmin(theta) > 0:
        ok = np.isfinite(theta)
        corr["oil temperature"] = _corr(r[ok], theta[ok], b.count[ok])
    follows = max(corr, key=lambda k: abs(corr[k]) if math.isfinite(corr[k]) else -1.0)
    return Drift(slope, (slope - 1.96 * se, slope + 1.96 * se), float(t[0]), float(t[-1]), follows, corr)


def _slope(t: np.ndarray, r: np.ndarray, w: np.ndarray, dwell: np.ndarray) -> tuple[float, float]:
    """The weighted line's slope of ``r`` over ``t`` and its cluster-robust (by dwell) standard error."""
    if len(t) < 4 or np.ptp(t) <= 0:
        return 0.0, math.inf
    centred = t - np.average(t, weights=w)
    fit = wls(np.column_stack([np.ones(len(t)), centred]), r, w, dwell)
    return float(fit.coef[1]), float(math.sqrt(max(fit.cov[1, 1], 0.0)))


def _slope_z(t: np.ndarray, r: np.ndarray, w: np.ndarray, dwell: np.ndarray) -> float:
    slope, se = _slope(t, r, w, dwell)
    return slope / se if se > 0 and math.isfinite(se) else 0.0


def _corr(a: np.ndarray, b: np.ndarray, weight: np.ndarray) -> float:
    """The weighted Pearson correlation of ``a`` and ``b`` (NaN where either does not vary)."""
    if len(a) < 3:
        return math.nan
    da, db = a - np.average(a, weights=weight), b - np.average(b, weights=weight)
    den = math.sqrt(float(np.sum(weight * da * da)) * float(np.sum(weight * db * db)))
    return float(np.sum(weight * da * db) / den) if den > 0 else math.nan
