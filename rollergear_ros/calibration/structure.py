"""What the calibrated file explains, and what the residual left still follows.

* :func:`adequacy` -- the shares of the predicted loss (the paper's model and each accepted effect;
  they add up to 100 %) and how much of the measured loss the file predicts on average.
* :func:`residual_structure` -- the share of the held-out residual's variance that each input carries
  (its mean per bin of speed, torque, oil temperature, time, acceleration and the angle turned since the
  last reversal; per direction and power flow) and what is
  periodic in the shaft angle: orders of the input and output revolutions for a rotating drive, the
  position for one that travels less than :data:`ROTATING_TURNS` turns (a screw, a joint).  "No
  structure" is said only where no input carries :data:`STRUCTURE_SHARE` of the variance *and* the
  residual is within :data:`NOISE_FACTOR` of the noise of a block mean.

No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Adequacy", "adequacy", "angle_spectrum", "residual_structure"]

RESIDUAL_BINS = 8  #: quantile bins of an input for the residual's structure
STRUCTURE_SHARE = 0.1  #: below this share of the variance, an input does not explain the residual left
NOISE_FACTOR = 1.5  #: a residual within this factor of a block mean's noise is noise
ROTATING_TURNS = 5.0  #: a drive that turns more than this is rotating (orders of a revolution)
MAX_ORDER = 32  #: orders of a revolution searched
ANGLE_SAMPLES = 50_000  #: the angle spectrum of at most this many samples (evenly thinned)


@dataclass(frozen=True)
class Adequacy:
    """Which share of the predicted loss the paper's model and each accepted effect carry (they add up
    to 100 %), and how much of the measured loss the file predicts on average, said in words."""

    model_share_pct: float  #: the paper's model (0 when switched off)
    effects_share_pct: dict[str, float]  #: accepted effect -> its share (sensor errors included)
    predicted_pct: float  #: the mean predicted loss as a share of the mean measured loss
    paper_model: bool  #: the paper's model was part of the fit (``estimator.paper_model``)
    statement: str

    @property
    def unexplained_pct(self) -> float:
        """The mean measured loss the file does not predict (negative: it predicts more)."""
        return 100.0 - self.predicted_pct

    def to_json(self) -> dict:
        return {"model_share_pct": self.model_share_pct, "effects_share_pct": self.effects_share_pct,
                "predicted_pct": self.predicted_pct, "unexplained_pct": self.unexplained_pct,
                "paper_model": self.paper_model, "statement": self.statement}


def adequacy(model_mean_nm: float, measured_mean_nm: float, effects_mean_nm: dict[str, float],
             paper_model: bool, viscous: bool = False, apart: list[str] | None = None) -> Adequacy:
    """The shares of the predicted loss, and a sentence a reader of the report can act on;
    ``viscous``: the model's share is at the oil's viscosity law (said); ``apart``: accepted effects
    that carry no loss of their own (a sensor's error, a difference between directions), said apart
    (``measured_mean_nm`` without them)."""
    predicted = model_mean_nm + sum(effects_mean_nm.values())
    scale = 100.0 / predicted if predicted > 0 else math.nan
    model = model_mean_nm * scale if paper_model else 0.0
    effects = {n: v * scale for n, v in effects_mean_nm.items()}
    predicted_pct = 100.0 * predicted / measured_mean_nm if measured_mean_nm > 0 else math.nan
    listed = ", ".join(f"{n} {v:.0f} %" for n, v in effects.items()) or "no accepted effect"
    at = " (at the oil's viscosity law)" if viscous else ""
    model_of_measured = 100.0 * model_mean_nm / measured_mean_nm if measured_mean_nm > 0 else math.nan
    if not paper_model:
        text = (f"the paper's ball-track model is switched off (estimator.paper_model: false); the accepted effects "
                f"carry the loss: {listed}")
    elif model_of_measured > 150.0:
        text = (f"the ball-track model{at} alone predicts {model_of_measured:.0f} % of the measured loss: it does not "
                f"describe this gearbox (the accepted effects must cancel most of it: {listed}); try "
                "estimator.paper_model: false")
    elif model < 50.0:
        text = f"the ball-track model{at} carries {model:.0f} % of this gearbox's predicted loss; the rest is {listed}"
    else:
        text = f"the ball-track model{at} carries {model:.0f} % of the predicted loss; {listed}"
    for name in apart or ():
        kind = "a sensor's error, no loss" if not _physical(name) else "the difference between the directions"
        text += f"; {name}: {kind}"
    if math.isfinite(predicted_pct) and abs(predicted_pct - 100.0) >= 1.0:
        text += (f"; on average it predicts {predicted_pct:.0f} % of the measured loss"
                 + (" (the rest is unexplained)" if predicted_pct < 100 else ""))
    return Adequacy(model, effects, predicted_pct, paper_model, text)


def residual_structure(blocks, residual: np.ndarray, angle: dict | None = None, spin_test: bool = False) -> dict:
    """How much of the unexplained (held-out) residual each input explains: the weighted share of its
    variance carried by its mean over :data:`RESIDUAL_BINS` quantile bins of speed, torque, oil
    temperature, time, acceleration and the angle since the last reversal (:func:`_motion_axes`), per
    direction and power flow; with ``angle`` (:func:`angle_spectrum` of the
    samples' residual), what is periodic in the shaft angle or follows the position."""
    w = blocks.count.astype(float)
    r = residual - np.average(residual, weights=w)
    total = float(np.sum(w * r * r))
    t = blocks.t_s[blocks.start] if blocks.t_s is not None and not blocks.steady_state else None
    inputs = {"speed": np.abs(blocks.speed), "temperature": blocks.temperature}
    if not spin_test:  # a spin test's drive torque is the loss measured: no input to explain it by
        inputs["torque"] = np.abs(blocks.torque)
    if t is not None:
        inputs["time"] = t + 1e6 * blocks.bag_id[blocks.start]  # recordings one after another
        inputs.update(_motion_axes(blocks))
    shares: dict[str, float] = {}
    for name, x in inputs.items():
        ok = np.isfinite(x)
        if ok.sum() < 2 * RESIDUAL_BINS or np.ptp(x[ok]) <= 0 or total <= 0:
            continue
        edges = np.unique(np.quantile(x[ok], np.linspace(0, 1, RESIDUAL_BINS + 1)))
        shares[name] = _explained(np.digitize(x[ok], edges[1:-1]), r[ok], w[ok], total)
    for name, key in (("direction", np.sign(blocks.speed)), ("power flow", np.sign(blocks.speed * blocks.torque))):
        if name == "power flow" and spin_test:  # nothing on the output: the drive torque is the friction
            continue
        if len(np.unique(key)) > 1 and total > 0:
            shares[name] = _explained(np.unique(key, return_inverse=True)[1], r, w, total)
    periodic = []
    if angle:
        shares.update(angle.get("shares", {}))
        periodic = angle.get("periodic", [])
    strongest = max(shares, key=shares.get) if shares else None
    noise = block_noise(blocks)
    rms = math.sqrt(total / float(np.sum(w))) if total > 0 else 0.0
    quiet = math.isfinite(noise) and rms <= NOISE_FACTOR * noise
    if total <= 0 or strongest is None:
        statement = "nothing left to explain"
    elif shares[strongest] < STRUCTURE_SHARE and quiet:
        statement = (f"the residual left shows no structure: no input carries more than "
                     f"{100 * shares[strongest]:.0f} % of its variance, and its RMS {rms:.3g} N·m is the noise of a "
                     f"block mean ({noise:.3g} N·m)")
        strongest = None
    elif shares[strongest] < STRUCTURE_SHARE:
        statement = (f"the residual left (RMS {rms:.3g} N·m, " + (f"{rms / noise:.1f} × the noise of a block mean"
                                                                 if math.isfinite(noise) and noise > 0 else
                                                                 "no noise estimate")
                     + f") follows none of the inputs by more than {100 * shares[strongest]:.0f} % of its variance: "
                     "something the recorded inputs do not describe")
        strongest = None
    else:
        statement = (f"the residual left depends most on {strongest} ({100 * shares[strongest]:.0f} % of its "
                     f"variance is its mean per {strongest} bin)")
        top = next((p for p in periodic if p["over"] == strongest), None)
        if top is not None:
            statement += f"; {top['text']}"
    return {"explained_share": {k: round(v, 4) for k, v in shares.items()}, "strongest": strongest,
            "statement": statement, "periodic": periodic}


def _physical(name: str) -> bool:
    from ..core.effects import EFFECTS

    return EFFECTS[name].physical


def block_noise(blocks) -> float:
    """The RMS noise of the block means (weighted by their samples) that the scatter of a whole block's
    mean at one operating point implies (a transient's shorter blocks are noisier), else the weights'."""
    if blocks.steady_state or not len(blocks.weight):
        return math.nan
    rep = getattr(blocks, "repeat", None)
    if rep is not None and math.isfinite(rep.se_block_nm):
        var = rep.se_block_nm ** 2 * blocks.full_count / blocks.count
    else:
        var = 1.0 / blocks.weight
    return float(np.sqrt(np.average(var, weights=blocks.count)))


def _motion_axes(blocks) -> dict[str, np.ndarray]:
    """Per block: ``acceleration``, |Δω/Δt| from its first to its last sample (rad/s²; the speed
    reading's noise averages out over a block where a per-sample derivative would multiply it), and
    ``since reversal``, the mean angle turned since the drive last turned round (rad; NaN before a
    recording's first reversal): what a loss that follows acceleration, or a memory, leaves."""
    if blocks.sample_speed is None or blocks.t_s is None or not len(blocks.start):
        return {}
    first = blocks.start
    last = first + blocks.count - 1
    dt = blocks.t_s[last] - blocks.t_s[first]
    same = blocks.bag_id[last] == blocks.bag_id[first]
    with np.errstate(invalid="ignore", divide="ignore"):
        accel = np.where(same & (dt > 0), np.abs(blocks.sample_speed[last] - blocks.sample_speed[first]) / dt,
                         np.nan)
    axes = {"acceleration": accel}
    since = blocks.angle_since_reversal(3.0 * blocks.sign_width_rad_s)
    if np.isfinite(since).any():
        sums = np.add.reduceat(np.where(np.isfinite(since), since, 0.0), first)
        known = np.add.reduceat(np.isfinite(since).astype(float), first)
        with np.errstate(invalid="ignore", divide="ignore"):
            axes["since reversal"] = np.where(known == blocks.count, sums / np.maximum(known, 1), np.nan)
    return axes


def _explained(label: np.ndarray, r: np.ndarray, w: np.ndarray, total: float) -> float:
    sums = np.bincount(label, weights=w * r)
    weights = np.bincount(label, weights=w)
    means = np.divide(sums, weights, out=np.zeros_like(sums), where=weights > 0)
    return float(np.sum(weights * means * means) / total)


def angle_spectrum(t_s: np.ndarray, bag_id: np.ndarray, speed: np.ndarray, out_speed: np.ndarray,
                   residual: np.ndarray) -> dict:
    """What of the samples' residual follows the shaft angle (``∫ω dt`` within each recording).

    A rotating drive (more than :data:`ROTATING_TURNS` turns): orders k = 1…:data:`MAX_ORDER` of the
    input revolution and of the output revolution (``∫ω_out dt``), each the share of the variance its
    sine and cosine carry, and the residual's mean per 16 bins of the angle modulo a revolution.  A
    drive that travels less (a screw, a joint): the residual's mean per 16 bins of the position, and
    the strongest period over the position.  Shares as in :func:`residual_structure`."""
    keep = np.isfinite(residual) & np.isfinite(speed)
    if keep.sum() < 100:
        return {}
    step = max(1, int(keep.sum()) // ANGLE_SAMPLES)
    out = {"shares": {}, "periodic": []}
    theta_in = _angle(t_s, bag_id, speed)
    theta_out = _angle(t_s, bag_id, out_speed)
    idx = np.flatnonzero(keep)[::step]
    r = residual[idx] - float(np.mean(residual[idx]))
    total = float(np.sum(r * r))
    if total <= 0:
        return {}
    turns = _turns(theta_in[idx], bag_id[idx])
    if turns >= ROTATING_TURNS:
        for name, theta in (("input shaft angle", theta_in[idx]), ("output shaft angle", theta_out[idx])):
            if not np.all(np.isfinite(theta)) or _turns(theta, bag_id[idx]) < ROTATING_TURNS:
                continue
            label = np.floor((np.mod(theta, 2 * np.pi)) / (2 * np.pi) * 16).astype(np.int64)
            out["shares"][name] = _explained(label, r, np.ones(len(r)), total)
            best = _best_order(theta, r, total)
            if best is not None:
                k, amp, share = best
                rev = "input" if name.startswith("input") else "output"
                out["periodic"].append({"over": name, "order": k, "period_rad": 2 * np.pi / k, "amplitude_nm": amp,
                                        "share": share,
                                        "text": f"order {k} of the {rev} revolution ({k} per turn) carries "
                                                f"{100 * share:.0f} % of it, amplitude {amp:.3g} N·m (an eccentric "
                                                "disc, a worn spot, a ball's passing)"})
    else:
        pos = theta_in[idx]
        span = float(np.ptp(pos))
        if span > 0:
            edges = np.linspace(pos.min(), pos.max(), 17)
            out["shares"]["position"] = _explained(np.clip(np.digitize(pos, edges[1:-1]), 0, 15), r,
                                                   np.ones(len(r)), total)
            best = _best_period(pos, r, total, span)
            if best is not None:
                period, amp, share = best
                out["periodic"].append({"over": "position", "order": None, "period_rad": period, "amplitude_nm": amp,
                                        "share": share,
                                        "text": f"a ripple of period {period:.3g} rad (of the position; a screw's "
                                                f"lead, a gear's tooth) carries {100 * share:.0f} % of it, amplitude "
                                                f"{amp:.3g} N·m"})
    out["shares"] = {k: round(v, 4) for k, v in out["shares"].items()}
    return out


def _angle(t_s: np.ndarray, bag_id: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """``∫ω dt`` within each recording (trapezoid; steps longer than twice the median count as one)."""
    theta = np.full(len(t_s), np.nan)
    for b in np.unique(bag_id):
        i = np.flatnonzero(bag_id == b)
        if len(i) < 2:
            continue
        dt = np.diff(t_s[i])
        med = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
        dt = np.minimum(dt, 2.0 * med)
        w = np.nan_to_num(speed[i])
        theta[i] = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)])
    return theta


def _turns(theta: np.ndarray, bag_id: np.ndarray) -> float:
    """Revolutions turned (the total travel over 2π)."""
    travel = 0.0
    for b in np.unique(bag_id):
        th = theta[bag_id == b]
        travel += float(np.sum(np.abs(np.diff(th))))
    return travel / (2 * np.pi)


def _best_order(theta: np.ndarray, r: np.ndarray, total: float) -> tuple[int, float, float] | None:
    """The order of the revolution whose sine and cosine carry most of ``r`` (least squares per order,
    the harmonics built by complex powers: one exponential for all orders)."""
    base = np.exp(1j * np.mod(theta, 2 * np.pi))
    z = np.ones(len(theta), complex)
    best = None
    for k in range(1, MAX_ORDER + 1):
        z = z * base
        amp, share = _harmonic_of(z.real, z.imag, r, total)
        if best is None or share > best[2]:
            best = (k, amp, share)
    return best


def _best_period(pos: np.ndarray, r: np.ndarray, total: float, span: float) -> tuple[float, float, float] | None:
    """The period over the position (from the span/2 down to 1/200 of it) that carries most of ``r``."""
    best = None
    for period in span / np.geomspace(2.0, 200.0, 120):
        amp, share = _harmonic(2 * np.pi * pos / period, r, total)
        if best is None or share > best[2]:
            best = (float(period), amp, share)
    return best


def _harmonic(phase: np.ndarray, r: np.ndarray, total: float) -> tuple[float, float]:
    """Amplitude and variance share of the least-squares sine/cosine pair at ``phase``."""
    return _harmonic_of(np.cos(phase), np.sin(phase), r, total)


def _harmonic_of(c: np.ndarray, s: np.ndarray, r: np.ndarray, total: float) -> tuple[float, float]:
    """The least-squares fit of ``r`` by ``a·c + b·s`` (its 2 × 2 normal equations): amplitude, share."""
    cc, ss, cs = float(c @ c), float(s @ s), float(c @ s)
    cr, sr = float(c @ r), float(s @ r)
    det = cc * ss - cs * cs
    if det <= 1e-12 * max(cc * ss, 1e-300):
        return 0.0, 0.0
    a = (ss * cr - cs * sr) / det
    b = (cc * sr - cs * cr) / det
    return float(np.hypot(a, b)), float((a * cr + b * sr) / total)
