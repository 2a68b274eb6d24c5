"""The rig's own nuisances: a channel's lag against the drive torque, and the drive's inertia.

Neither is a loss.  Both are fitted in every analysis as columns of the design (never reported as
effects), each linear in its coefficient to first order, per sample within each recording:

=====================  ==============================================  ======================
nuisance               column (its coefficient)                        data
=====================  ==============================================  ======================
``lag:output_torque``  ``dT_out/dt·ω_out/|ω_in|`` (the lag τ [s])      output torque measured
``lag:output_speed``   ``T_out·dω_out/dt/|ω_in|`` (τ [s])              output speed measured
``lag:motor_speed``    ``dT_in/dt·sgn ω`` (τ [s])                      a spin test
``inertia``            ``dω_in/dt·sgn ω`` (J [N·m·s²/rad])             always
=====================  ==============================================  ======================

A reading that lags the drive torque by τ reads ``x(t − τ) ≈ x(t) − τ·dx/dt``; in the measured loss
``(T_in·ω_in − T_out·ω_out)/|ω_in|`` that adds τ times the column (a spin test's loss is
``T_in·sgn ω``: a speed reading that lags is a drive torque that leads it).  A lag worth it is then
applied to the samples (:func:`shift`: the channel read at ``t + τ``, the measured loss recomputed)
and the analysis run again on the aligned samples; the total is reported with its interval, and a
channel map's ``lag_s`` applies it on import (:mod:`sources.channelmap`).  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..core.model import rotation_sign
from .grouping import pauses
from .samples import SampleData

__all__ = ["ChannelLag", "apply_lags", "lag_channel", "nuisance_columns", "shift"]

#: a lag is applied when it is this many standard errors from 0 ...
LAG_MIN_Z = 4.0
#: ... and at least this share of the median sample period
LAG_MIN_PERIODS = 0.5


def nuisance_columns(d: SampleData, sign: np.ndarray) -> dict[str, np.ndarray]:
    """The per-sample nuisance columns (see the module docstring) this data has; ``sign``: the
    direction each loss opposes (the estimator's smooth sign)."""
    t = d.t_ns.astype(np.float64) * 1e-9
    if d.steady_state:
        return {}
    dtin, dwin = _derivative(d, t, d.torque), _derivative(d, t, d.speed)
    cols = {"inertia": dwin * sign}
    if d.spin_test:
        cols["lag:motor_speed"] = dtin * sign
        return cols
    w_out = _output_speed(d)
    aw = np.maximum(np.abs(d.speed), 1e-12)
    t_out = np.nan_to_num(d.out_torque)
    cols["lag:output_torque"] = _derivative(d, t, t_out) * w_out / aw
    if _measured(d.out_speed) and not _derived(d.out_speed, d.speed):
        cols["lag:output_speed"] = t_out * _derivative(d, t, np.nan_to_num(d.out_speed)) / aw
    return cols


def lag_channel(name: str) -> str | None:
    """The channel a nuisance column's coefficient is the lag of (None: not a lag)."""
    return name.split(":", 1)[1] if name.startswith("lag:") else None


@dataclass(frozen=True)
class ChannelLag:
    """A channel's lag behind the drive torque, as fitted."""

    channel: str  #: motor_speed | output_torque | output_speed
    lag_s: float  #: positive: the channel's reading comes later than the drive torque's
    ci95_s: tuple[float, float]
    applied: bool  #: the analysis aligned the samples by it (else it was too small to matter, or beyond range)
    #: why it was not applied though clearly there ('': applied, or too small to matter)
    why_not: str = ""

    def to_json(self) -> dict:
        return {"channel": self.channel, "lag_s": self.lag_s, "ci95_s": list(self.ci95_s), "applied": self.applied,
                **({"why_not": self.why_not} if self.why_not else {})}

    def sentence(self) -> str:
        ms = 1e3 * self.lag_s
        lo, hi = (1e3 * v for v in self.ci95_s)
        if self.why_not:
            return f"{self.channel}: a lag of {ms:.4g} ms fitted (95 %: {lo:.4g} to {hi:.4g} ms), {self.why_not}"
        how = "the analysis aligned it" if self.applied else "too small to matter: not applied"
        return (f"{self.channel} lags the drive torque by {ms:.3g} ms (95 %: {lo:.3g} to {hi:.3g} ms; {how}; "
                f"lag_s: {self.lag_s:.4g} in the channel map's {self.channel} applies it on import)")


def worth_applying(lag_s: float, se_s: float, period_s: float) -> bool:
    """Whether a fitted lag is clearly there and at least half a sample long."""
    return se_s > 0 and abs(lag_s) >= LAG_MIN_Z * se_s and abs(lag_s) >= LAG_MIN_PERIODS * period_s


def shift(d: SampleData, channel: str, lag_s: float) -> SampleData:
    """The samples with ``channel`` read ``lag_s`` later (``x(t + τ)``, linear interpolation within
    each recording), its measured loss recomputed; a spin test's speed shift moves its samples'
    direction too (samples then within the direction's noise band stay as they are)."""
    t = d.t_ns.astype(np.float64) * 1e-9
    if channel == "output_torque":
        new = _resample(d, t, np.nan_to_num(d.out_torque), lag_s)
        loss = d.measured_loss + (np.nan_to_num(d.out_torque) - new) * _output_speed(d) / np.abs(d.speed)
        return replace(d, out_torque=new, measured_loss=loss)
    if channel == "output_speed":
        new = _resample(d, t, np.nan_to_num(d.out_speed), lag_s)
        loss = d.measured_loss + np.nan_to_num(d.out_torque) * (np.nan_to_num(d.out_speed) - new) / np.abs(d.speed)
        return replace(d, out_speed=new, measured_loss=loss)
    if channel == "motor_speed":
        new = _resample(d, t, d.speed, lag_s)
        flips = np.sign(new) != np.sign(d.speed)
        new = np.where(flips & (np.abs(new) < 3.0 * d.sign_width_rad_s), d.speed, new)
        moved = np.sign(new) != np.sign(d.speed)
        loss = np.where(moved, -d.measured_loss, d.measured_loss)
        sign = None if d.sign is None else np.where(moved, rotation_sign(new, d.torque, d.sign_width_rad_s), d.sign)
        return replace(d, speed=new, measured_loss=loss, sign=sign)
    raise ValueError(f"no lag for channel {channel!r}")


def apply_lags(d: SampleData, lags: dict[str, float], model=None) -> SampleData:
    """:func:`shift` by each channel's lag; ``model`` (a :class:`~core.model.LossModel`): the bare
    model re-evaluated where a speed moved."""
    out = d
    for channel, lag in lags.items():
        out = shift(out, channel, lag)
    if model is not None and "motor_speed" in lags:
        out = replace(out, model_loss=model.loss_magnitude(out.torque, out.speed),
                      fr_part=model.fr_part(out.torque, out.speed), parts=model.parts(out.torque, out.speed))
    return out


def _measured(x: np.ndarray | None) -> bool:
    return x is not None and bool(np.any(np.isfinite(x))) and float(np.nanmax(x) - np.nanmin(x)) > 0


def _derived(out_speed: np.ndarray, speed: np.ndarray) -> bool:
    """Whether the output speed is the drive's over a ratio (an import's, not a reading of its own)."""
    ok = np.isfinite(out_speed) & (out_speed != 0)
    if not ok.any():
        return True
    ratio = float(np.median(speed[ok] / out_speed[ok]))
    return bool(np.max(np.abs(out_speed[ok] * ratio - speed[ok])) <= 1e-9 * max(float(np.max(np.abs(speed))), 1e-300))


def _output_speed(d: SampleData) -> np.ndarray:
    """The output speed the measured loss used: measured, else the drive's over the ratio."""
    ratio = d.speed_ratio if d.speed_ratio and d.speed_ratio > 0 else 1.0
    if d.out_speed is None:
        return d.speed / ratio
    return np.where(np.isnan(d.out_speed), d.speed / ratio, d.out_speed)


def _derivative(d: SampleData, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """dx/dt within each run of each recording (np.gradient over time; never across a pause,
    :func:`~.grouping.pauses`: nothing is known of the motion there)."""
    out = np.zeros(len(t))
    for b in np.unique(d.bag_id):
        idx = np.flatnonzero(d.bag_id == b)
        cuts = pauses(t[idx])
        for lo, hi in zip(cuts[:-1], cuts[1:]):
            run = idx[lo:hi]
            if len(run) > 2:
                tt = t[run] + 1e-12 * np.arange(len(run))
                out[run] = np.gradient(x[run], tt)
    return out


def _resample(d: SampleData, t: np.ndarray, x: np.ndarray, lag_s: float) -> np.ndarray:
    """``x`` read at ``t + lag_s`` within each recording (held at its ends)."""
    out = x.copy()
    for b in np.unique(d.bag_id):
        idx = np.flatnonzero(d.bag_id == b)
        if len(idx) > 1:
            out[idx] = np.interp(t[idx] + lag_s, t[idx], x[idx])
    return out


def lag_range_s() -> float:
    """The largest lag a parameter file may hold (``estimator.<channel>_lag_s``, either sign)."""
    from ..core.paramspecs import spec_by_name

    return float(spec_by_name()["estimator.output_torque_lag_s"].high)


def lag_from_fit(name: str, coef: float, se: float, period_s: float, applied_before: float = 0.0) -> ChannelLag:
    """A channel's total lag (what an earlier pass applied plus this fit's) with its 95 % interval:
    applied where it is clearly there and half a sample long (:func:`worth_applying`), or an earlier
    pass applied one -- never beyond the range a parameter file may hold (a channel that far out of
    step is not late: another clock or another rate; the first order of ``x(t − τ)`` holds for lags
    of a few samples), said with the reason."""
    channel = lag_channel(name) or name
    total = applied_before + coef
    ci = (total - 1.96 * se, total + 1.96 * se)
    limit = lag_range_s()
    if abs(total) > limit:
        return ChannelLag(channel, total, ci, False,
                          f"beyond the ±{limit:g} s a parameter file may hold for estimator.{channel}_lag_s: not "
                          "applied -- a channel this far out of step is not read late but on another clock or at "
                          "another rate (align its stamps, or give its rate), and no lag is claimed")
    return ChannelLag(channel, total, ci, applied_before != 0.0 or worth_applying(coef, se, period_s))


def median_period_s(d: SampleData) -> float:
    """The median sample period [s] (within recordings)."""
    dt = np.diff(d.t_ns.astype(np.float64)) * 1e-9
    same = d.bag_id[1:] == d.bag_id[:-1]
    dt = dt[same & (dt > 0)]
    return float(np.median(dt)) if len(dt) else math.nan
