"""What the data can tell: the noise of a reading, of a block mean, and the practical minimum effect size.

Three estimates that the misfit of the model cannot inflate, because each looks only where the
model predicts the same thing:

* :func:`~core.speednoise.reading_noise` -- a reading's noise from its second differences (a smooth
  signal's are next to nothing, a ramp's are 0).
* :func:`difference_variance` -- each block's noise variance from the differences of its samples'
  residual (a slow trend -- what the model still lacks, changing through a ramp -- barely shows in
  them): the median block's, or a clearly noisier block's own; with the residual's AR(1) colour from
  the autocorrelation of the differences (``ρ = 1 + 2·r₁(Δy)``).
* :func:`repeatability` -- the scatter of consecutive block means within a dwell: the same operating
  point measured again a moment later.  Its standard error of a block mean sets the practical
  minimum effect size ``δ = 3·SE`` (:func:`minimum_effect`), unless the sensors' stated accuracy says
  more or the user gives ``--delta``.

No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.speednoise import reading_noise

__all__ = ["MinimumEffect", "difference_variance", "minimum_effect", "reading_noise", "repeatability", "sensor_delta"]

#: a block's own noise variance counts from this many differences on ...
OWN_DIFFERENCES = 10
#: ... when it is more than this many times the median block's
NOISIER = 4.0
#: δ is this many standard errors of a block mean (the scatter of the same operating point)
DELTA_STANDARD_ERRORS = 3.0
#: ... or this share of the RMS measured loss where that is smaller (a table's rows: that share)
MATERIAL_LOSS_SHARE = 0.02


def difference_variance(y: np.ndarray, start: np.ndarray, count: np.ndarray,
                        first: np.ndarray) -> tuple[np.ndarray, float]:
    """The noise variance of each block's samples and the AR(1) inflation ``(1 + ρ)/(1 − ρ)`` of a
    block mean's variance; ``first`` marks each block's first sample (no difference across blocks).

    From the first differences within blocks: ``var Δy = 2σ²(1 − ρ)`` and the differences' lag-1
    autocorrelation ``r₁ = −(1 − ρ)/2`` for an AR(1) residual.  Every block has the median block's
    variance unless its own, from at least :data:`OWN_DIFFERENCES` differences, is more than
    :data:`NOISIER` times that: then its own (a spike, a rough patch weighs less; the rest weigh by
    their samples, as the held-out errors count them)."""
    n = len(y)
    dy = np.zeros(n)
    dy[1:] = np.diff(y)
    inside = ~first
    dy[~inside] = 0.0
    m = np.add.reduceat(inside.astype(float), start)
    ss = np.add.reduceat(dy * dy, start)
    both = inside[1:] & inside[:-1]  # two differences in a row within a block
    rho = 0.0
    if both.sum() > 10:
        a, b = dy[1:][both], dy[:-1][both]
        r1 = float(np.dot(a, b) / max(math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b))), 1e-300))
        rho = min(max(1.0 + 2.0 * r1, 0.0), 0.98)
    own = np.divide(ss, 2.0 * (1.0 - rho) * m, out=np.full(len(start), np.nan), where=m > 0)
    ok = np.isfinite(own) & (m >= OWN_DIFFERENCES)
    if not ok.any():
        ok = np.isfinite(own)
    median = max(float(np.median(own[ok])) if ok.any() else 1e-12, 1e-30)
    noisier = ok & (own > NOISIER * median)
    return np.where(noisier, own, median), (1.0 + rho) / (1.0 - rho)


@dataclass(frozen=True)
class Repeatability:
    """The scatter of a block mean at one operating point (consecutive block means of a dwell)."""

    se_block_nm: float  #: standard error of a block mean (NaN: no dwell of two blocks)
    pairs: int  #: pairs of consecutive blocks it comes from (cells: the blocks)
    dwells: int  #: dwells they lie in (cells: the cells)
    cells: bool = False  #: from blocks of one operating-point cell (no dwell held two blocks often enough)


def repeatability(measured: np.ndarray, dwell: np.ndarray, count: np.ndarray, full: float,
                  cells: np.ndarray | None = None) -> Repeatability:
    """The standard error of a whole block's mean (``full`` samples) at one operating point.

    From consecutive whole blocks of one dwell (the operating point held; a transient's shorter parts
    are no repetition of anything): ``SE² = median(Δm²)/(2·0.455)`` -- the median of a χ²₁ is 0.455: a
    robust mean square that a dwell's one step or a passing spike does not carry.  With fewer than
    :data:`MIN_PAIRS` such pairs, from the blocks that share an operating-point cell (``cells``: a
    label per block, -1 for none; the operating point visited again, as a back-and-forth drive does):
    each visit against the one before it, as a dwell's pairs, each scaled to a whole block."""
    whole = count >= 0.8 * full
    same = (dwell[1:] == dwell[:-1]) & whole[1:] & whole[:-1]
    if same.sum() >= MIN_PAIRS or cells is None:
        if same.sum() < 3:
            return Repeatability(math.nan, int(same.sum()), 0)
        d = (measured[1:] - measured[:-1])[same]
        n_pair = 2.0 / (1.0 / count[1:][same] + 1.0 / count[:-1][same])
        d = d * np.sqrt(n_pair / full)  # var(mean) ∝ 1/n: each pair scaled to whole blocks
        ms = float(np.median(d * d)) / 0.4549
        return Repeatability(math.sqrt(ms / 2.0), int(same.sum()), int(len(np.unique(dwell[1:][same]))))
    # each visit of a cell against the one before it (the blocks in time order): as a dwell's pairs
    order = np.lexsort((np.arange(len(cells)), cells))
    c, m, n = cells[order], measured[order], count[order].astype(float)
    same = (c[1:] == c[:-1]) & (c[1:] >= 0)
    if same.sum() < MIN_PAIRS:
        return Repeatability(math.nan, int(same.sum()), 0, cells=True)
    d = (m[1:] - m[:-1])[same] * np.sqrt((2.0 / (1.0 / n[1:] + 1.0 / n[:-1]))[same] / full)
    ms = float(np.median(d * d)) / 0.4549
    return Repeatability(math.sqrt(ms / 2.0), int(same.sum()), int(len(np.unique(c[1:][same]))), cells=True)


#: consecutive pairs of whole blocks in dwells needed before the cells are not asked
MIN_PAIRS = 20


@dataclass(frozen=True)
class MinimumEffect:
    """The practical minimum effect size δ (RMS N·m) and where it came from."""

    delta_nm: float
    source: str  #: user | sensors | repeatability | table | noise
    text: str  #: a sentence for the output

    def to_json(self) -> dict:
        return {"delta_nm": self.delta_nm, "source": self.source, "text": self.text}


def minimum_effect(user_delta_nm: float | None, rep: Repeatability, sensors_nm: float | None,
                   noise_se_nm: float, rms_measured_nm: float, table: bool, block_s: float) -> MinimumEffect:
    """δ: the user's ``--delta``; else 3 × the standard error of a block mean at one operating point
    (:func:`repeatability`; without a dwell of two blocks, 3 × that from the samples' noise), or 2 % of
    the RMS measured loss where that is smaller -- an effect of 2 % of the loss is material however
    much a block of slow, coarse or coloured readings scatters (its significance and held-out
    improvement are tested apart); never below the sensors' stated accuracy (RMS of the loss's
    uncertainty over the samples).  A table's rows (dwell means without a noise estimate): 2 % of the
    RMS measured loss."""
    if user_delta_nm is not None:
        return MinimumEffect(user_delta_nm, "user", f"delta = {user_delta_nm:.4g} N·m (--delta)")
    if table:
        d = MATERIAL_LOSS_SHARE * rms_measured_nm
        return MinimumEffect(d, "table", f"delta = {d:.4g} N·m: 2 % of the RMS measured loss (a table's rows carry "
                                         "no noise estimate)")
    k = DELTA_STANDARD_ERRORS
    if math.isfinite(rep.se_block_nm) and rep.se_block_nm > 0:
        base = k * rep.se_block_nm
        where = (f"{rep.pairs} pairs of visits to {rep.dwells} operating-point cells" if rep.cells else
                 f"{rep.pairs} pairs of consecutive blocks in {rep.dwells} dwells")
        text = (f"{k:g} × the standard error of a {block_s:g} s mean at one operating point ({rep.se_block_nm:.3g} "
                f"N·m, from {where})")
        source = "repeatability"
    else:
        base = k * noise_se_nm
        text = (f"{k:g} × the standard error of a {block_s:g} s mean from the samples' noise ({noise_se_nm:.3g} N·m; "
                "no operating point was held or visited again)")
        source = "noise"
    share = MATERIAL_LOSS_SHARE * rms_measured_nm
    if share < base:  # a block scatters more than a material share of the loss
        text = (f"{100 * MATERIAL_LOSS_SHARE:g} % of the RMS measured loss ({rms_measured_nm:.3g} N·m), below {text} = "
                f"{base:.3g} N·m")
        base, source = share, "loss share"
    if sensors_nm is not None and sensors_nm > base:
        return MinimumEffect(sensors_nm, "sensors", f"delta = {sensors_nm:.4g} N·m: the loss's expanded uncertainty "
                                                    f"(k = 2) from the sensors' stated accuracy (sensors.*; RMS over "
                                                    f"the samples), above {text} = {base:.3g} N·m")
    extra = f"; the sensors' stated accuracy gives {sensors_nm:.3g} N·m" if sensors_nm is not None else ""
    return MinimumEffect(base, source, f"delta = {base:.4g} N·m: {text}{extra}")


def sensor_delta(data, config) -> float | None:
    """The expanded (k = 2) RMS over the samples of the measured loss's uncertainty from the sensors'
    stated accuracy (:mod:`core.uncertainty`); None where none is stated or for a table's rows."""
    if not config.sensors.stated or data.steady_state or data.out_torque is None:
        return None
    from ..core.uncertainty import loss_uncertainty

    u = loss_uncertainty(config.sensors, data.torque, data.speed, data.out_torque,
                         data.out_speed if data.out_speed is not None else np.full(len(data.speed), np.nan),
                         data.speed_ratio or 1.0)
    u = u[np.isfinite(u)]
    return 2.0 * float(np.sqrt(np.mean(u * u))) if len(u) else None
