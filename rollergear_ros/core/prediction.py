"""What a planned drive will cost: loss power and energy over a profile, with their 95 % band.

The loss is the estimator's -- the paper's model with the accepted effects, the one forward path.
A **plan** (no measured output torque: planned torque and speed) is evaluated at its true torque:
the rig's torque-sensor errors are not applied, as in ``map``, and nothing adapts.  A **recorded
drive** (a profile with measured output torque) is evaluated exactly as ``replay`` evaluates it:
its torques are the rig's readings, corrected by the file's sensor errors, and the file's
coefficients adapt online where it says ``estimator.adapt: true`` (``adapt=False``: held as
written) -- so ``predict`` of a recorded drive is its ``replay``.  Each prediction says which.

The band propagates the calibration's parameter
covariance (``calibration.covariance``, :mod:`.covariance`) to first order (the delta method): for
each covaried parameter ``θ_k`` the change of every sample's loss power per unit of it,
``J_ik = ∂P_i/∂θ_k`` (numerically: the estimator of the written file at ``θ_k + h``), then

* a sample's loss power: ``var P_i = J_i·C·J_iᵀ``;
* the energy ``E = Σ P_i·Δt_i``: ``g = Jᵀ·Δt``, ``var E = gᵀ·C·g``;

each band ``± 1.96 σ``.  ``Δt_i`` is replay's rule: the time since the previous sample, nothing
across a gap longer than five typical periods (so ``predict`` of a recording equals ``replay``'s
energy of it).  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..base.text import printable
from ..base.errors import ParameterError
from .covariance import ParameterCovariance
from .estimator import BatchEstimate, Estimator
from .effects import EFFECTS
from .measured import energy_steps_s
from .modelform import ModelForm
from .operating_points import map_config, only, temperature_effects
from .params import Config

__all__ = ["METHOD", "Prediction", "PredictionSums", "prediction_config"]

#: how the band is propagated (said with every prediction)
METHOD = "first-order propagation (delta method) of the calibration's parameter covariance"
Z95 = 1.959963984540054
#: a parameter's step for its derivative, relative to its size (the loss is linear in a coefficient)
STEP = 1e-6


def prediction_config(config: Config, adapt: bool = True, recorded: bool = False) -> Config:
    """``config`` as a prediction evaluates it: a recorded drive as replay does (the sensor errors
    applied, online adaptation as the file says, or off with ``adapt`` false); a plan as a map (the
    sensor errors off, nothing adapts)."""
    if not recorded:
        return replace(map_config(config), estimator=replace(config.estimator, adapt=False))
    return replace(config, estimator=replace(config.estimator, adapt=config.estimator.adapt and adapt))


@dataclass
class Prediction:
    """Loss energy and power over a profile, with their 95 % bands (:data:`METHOD`)."""

    samples: int
    duration_s: float
    energy_lost_j: float
    energy_lost_sd_j: float  #: the standard deviation the covariance propagates to
    energy_in_j: float  #: ∫|T·ω| dt
    peak_loss_power_w: float
    parameters: tuple[str, ...]  #: the covaried parameters (empty: the file holds no covariance)
    method: str = METHOD
    #: the share of the recording lost to damage (:func:`base.errors.lost_share`; 0: none found)
    lost_share: float = 0.0
    #: samples whose estimate adapted the file's coefficients to a measured output torque (as replay)
    adapted_samples: int = 0
    #: a recorded drive (measured output torque: evaluated as replay does) rather than a plan
    recorded: bool = False
    #: how far the energy moves with the calibration's unresolved alternatives (down, up; 0: none)
    model_form_j: tuple[float, float] = (0.0, 0.0)
    alternatives: dict[str, float] = field(default_factory=dict)  #: alternative -> its energy shift [J]
    beyond_samples: int = 0  #: samples beyond what the calibration saw or the rating
    beyond_effects_j: float = 0.0  #: the accepted effects' energy there (counted as unknown)
    limits: tuple[float, float] = (math.inf, math.inf)  #: |ω| [rad/s] and |T| [N·m] seen and rated
    #: the oil temperatures the calibration saw [°C] (None: not said, or the model follows no oil)
    oil_limits: tuple[float, float] | None = None
    #: samples beyond on each axis ("speed", "torque", "oil temperature"; a sample may count on several)
    beyond_by_axis: dict[str, int] = field(default_factory=dict)
    band_refused: str = ""  #: why there is no band ('': there is one)
    notes: list[str] = field(default_factory=list)
    #: per sample, with ``collect``: times, loss power and its standard deviation
    t_ns: np.ndarray | None = field(default=None, repr=False)
    loss_power_w: np.ndarray | None = field(default=None, repr=False)
    loss_power_sd_w: np.ndarray | None = field(default=None, repr=False)
    #: per sample, with ``collect``: how far the unresolved alternatives move the loss power (down, up)
    loss_power_form_low_w: np.ndarray | None = field(default=None, repr=False)
    loss_power_form_high_w: np.ndarray | None = field(default=None, repr=False)
    #: per sample, with ``collect``: the accepted effects' loss power where it is extrapolated (0 elsewhere)
    loss_power_beyond_w: np.ndarray | None = field(default=None, repr=False)

    def loss_power_band_w(self) -> tuple[np.ndarray, np.ndarray]:
        """Each sample's 95 % band of the loss power (with ``collect``; NaN where the band is refused): never below
        0, nor below the loss without the effects where they are extrapolated."""
        half = Z95 * self.loss_power_sd_w
        low = self.loss_power_w + self.loss_power_form_low_w - half
        high = self.loss_power_w + self.loss_power_form_high_w + half
        if self.band_refused:
            return np.full(len(low), np.nan), np.full(len(high), np.nan)
        floor = np.where(self.loss_power_beyond_w > 0,
                         self.loss_power_w + self.loss_power_form_low_w - self.loss_power_beyond_w, -np.inf)
        return np.maximum(np.maximum(low, floor), 0.0), high

    @property
    def energy_band_j(self) -> tuple[float, float]:
        """The energy's 95 % band: the covariance's (and the extrapolated effects') spread around the
        written file's and every unresolved alternative's energy; NaN where it is refused."""
        if self.band_refused:
            return math.nan, math.nan
        half = Z95 * self.energy_lost_sd_j
        low = self.energy_lost_j + self.model_form_j[0] - half
        if self.beyond_effects_j > 0:  # the effects extrapolated: as large as they are, or none -- never negative
            low = max(low, self.energy_lost_j + self.model_form_j[0] - self.beyond_effects_j)
        return max(low, 0.0), self.energy_lost_j + self.model_form_j[1] + half

    @property
    def mean_loss_power_w(self) -> float:
        return self.energy_lost_j / self.duration_s if self.duration_s > 0 else math.nan

    def to_json(self) -> dict:
        lo, hi = (_finite(v) for v in self.energy_band_j)
        return {"samples": self.samples, "duration_s": self.duration_s, "energy_lost_j": self.energy_lost_j,
                "energy_lost_band95_j": [lo, hi], "energy_lost_sd_j": self.energy_lost_sd_j,
                "energy_in_j": self.energy_in_j, "mean_loss_power_w": _finite(self.mean_loss_power_w),
                "peak_loss_power_w": self.peak_loss_power_w, "parameters": list(self.parameters),
                "method": self.method, "lost_share": self.lost_share, "adapted_samples": self.adapted_samples,
                "recorded": self.recorded, "alternatives_j": self.alternatives,
                "beyond_calibration": {"samples": self.beyond_samples, "effects_energy_j": self.beyond_effects_j,
                                       "speed_limit_rad_s": _finite(self.limits[0]),
                                       "torque_limit_nm": _finite(self.limits[1]),
                                       "oil_temperature_c": list(self.oil_limits) if self.oil_limits else None,
                                       "samples_by_axis": self.beyond_by_axis},
                "band_refused": self.band_refused or None, "notes": self.notes}

    def text(self) -> str:
        lo, hi = self.energy_band_j
        wh = 1 / 3600.0
        lines = [f"{self.samples:,} samples over {self.duration_s:.1f} s",
                 f"energy lost {self.energy_lost_j:,.1f} J ({self.energy_lost_j * wh:.4g} Wh), "
                 + (f"95 % band {lo:,.1f} … {hi:,.1f} J" if math.isfinite(lo) else "no band (below)")
                 + f"; energy through the gearbox {self.energy_in_j:,.0f} J",
                 f"loss power: mean {self.mean_loss_power_w:.4g} W, peak {self.peak_loss_power_w:.4g} W"]
        if self.recorded:
            lines.append("a recorded drive (measured output torque): evaluated as replay evaluates it, its torques "
                         "corrected by the file's sensor errors"
                         + (f", the file's coefficients adapted online at {self.adapted_samples:,} samples "
                            "(estimator.adapt: true; --no-adapt: as written)" if self.adapted_samples else
                            ", the file's coefficients as written"))
        else:
            lines.append("a plan: its torques are the true ones (no sensor errors applied), nothing adapts")
        if self.lost_share:
            lines.append(f"predicted from what was readable: {100 * self.lost_share:.1f} % of the recording is damaged")
        if self.band_refused:
            lines.append(f"band: refused -- {self.band_refused}")
        elif self.parameters:
            lines.append(f"band: {self.method} over {', '.join(self.parameters)}")
        else:
            lines.append("band: none -- the parameter file holds no calibration.covariance (write it with "
                         "rollergear calibrate): the loss as if its parameters were exact")
        if self.alternatives and not self.band_refused:
            lines.append("band spans what the calibration could not tell apart: "
                         + ", ".join(f"with {n} {v:+,.1f} J" for n, v in self.alternatives.items()))
        if self.beyond_samples:
            speed, torque = self.limits
            axes = {"speed": f"|ω| > {speed:.4g} rad/s", "torque": f"|T| > {torque:.4g} N·m"}
            if self.oil_limits:
                axes["oil temperature"] = f"oil outside {self.oil_limits[0]:g} … {self.oil_limits[1]:g} °C"
            said = "; ".join(f"{axes[a]}: {n:,}" for a, n in self.beyond_by_axis.items() if n)
            lines.append(f"{self.beyond_samples:,} samples lie beyond what the calibration saw or the rating "
                         f"({said}): the accepted effects' {self.beyond_effects_j:,.1f} J there are extrapolated, "
                         "counted in the band as unknown (as large as they are, or none: the band's lower end "
                         "stays above the energy without them)")
        lines.extend(self.notes)
        return "\n".join(lines)


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


class PredictionSums:
    """The running sums of a prediction, fed batch by batch with the base estimates (``add``)."""

    def __init__(self, config: Config, collect: bool = False, adapt: bool = True, recorded: bool = False) -> None:
        self.recorded = recorded
        self.config = prediction_config(config, adapt, recorded)
        fixed = prediction_config(config, False, recorded)  # the file's coefficients as written
        #: where the estimates adapt, the base of the band's derivatives (they are the written file's)
        self._written = Estimator(fixed) if self.config.estimator.adapt else None
        self.adapted_samples = 0
        self.covariance = ParameterCovariance.from_text(config.calibration.covariance)
        self._perturbed: list[tuple[float, Estimator]] = []
        for key in self.covariance.keys if self.covariance else ():
            value = float(fixed.value(key))
            step = STEP * max(abs(value), 1e-9)
            try:
                moved = fixed.with_values({key: value + step})
            except ParameterError:  # at the top of its range: step down
                step = -step
                moved = fixed.with_values({key: value + step})
            self._perturbed.append((step, Estimator(moved)))
        self._model_form(config, fixed)
        aligner = Estimator(self.config).aligner if recorded else None
        self._lags = aligner.describe() if aligner is not None else ""  #: a plan is not read late
        k = len(self._perturbed)
        self.gradient = np.zeros(k)  #: d E / d θ
        self.energy = self.energy_in = self.peak = 0.0
        self.samples = 0
        self.first_t: int | None = None
        self.last_t: int | None = None
        self._dt_ns = 0.0
        self._collect = collect
        self._parts: list[tuple[np.ndarray, ...]] = []

    def _model_form(self, config: Config, fixed: Config) -> None:
        """The calibration's unresolved alternatives (an estimator each, the written file with it added),
        the range it saw and the rating (beyond either, the accepted effects are extrapolated: the paper's
        model alone tells their share)."""
        self.form = ModelForm.from_text(config.calibration.model_form)
        self._alternatives: list[tuple[str, Estimator]] = []
        self.alternative_notes: list[str] = []
        for name, params in self.form.alternatives if self.form else ():
            effect = EFFECTS[name]
            values = {f"effects.{name}.enabled": True} | {
                f"effects.{name}.{p.key}": params[p.short] for p in effect.parameters if p.short in params}
            try:
                self._alternatives.append((name, Estimator(fixed.with_values(values))))
            except ParameterError as exc:
                self.alternative_notes.append(f"{name} not spanned: {exc}")
        self.alternative_shift_j = np.zeros(len(self._alternatives))  #: E(with it) − E(written)
        g = fixed.gearbox
        self.speed_limit = min(self.form.seen_speed_rad_s if self.form else math.inf,
                               g.rated_speed_rpm * math.pi / 30.0 if g.rated_speed_rpm > 0 else math.inf)
        self.torque_limit = min(self.form.seen_torque_nm if self.form else math.inf,
                                g.rated_torque_nm if g.rated_torque_nm > 0 else math.inf)
        self.oil_limits = self.form.seen_oil_c if self.form and temperature_effects(fixed) else None
        self._paper_only = Estimator(only(fixed, ())) if fixed.effects.enabled() else None
        self.beyond_samples = 0
        self.beyond_by_axis = {"speed": 0, "torque": 0, "oil temperature": 0}
        self.beyond_effects_j = 0.0  #: the accepted effects' energy beyond what was seen or rated

    def base_estimator(self, **kwargs) -> Estimator:
        """An estimator of the prediction's model (for the caller's pairing and base estimates)."""
        return Estimator(self.config, **kwargs)

    def add(self, b: BatchEstimate | None) -> None:
        """The base estimates of one batch of samples, in time order."""
        if b is None or not len(b.t_ns):
            return
        t = np.asarray(b.t_ns, dtype=np.int64)
        if self.first_t is None:
            self.first_t = int(t[0])
        dt, self._dt_ns = energy_steps_s(t, self.last_t, self._dt_ns)
        power = np.asarray(b.loss_power_w, dtype=float)
        self.energy += float(np.sum(power * dt))
        self.energy_in += float(np.sum(np.abs(b.torque_nm * b.speed_rad_s) * dt))
        self.peak = max(self.peak, float(np.max(power)))
        self.samples += len(t)
        self.last_t = int(t[-1])
        if self._written is not None and b.out_torque_nm is not None:
            self.adapted_samples += int(np.count_nonzero(np.isfinite(b.out_torque_nm)))
        def evaluate(estimator: Estimator) -> np.ndarray:
            return estimator.process_batch(t, b.torque_nm, b.speed_rad_s, temperature=b.temperature_c,
                                           breakdown=False).loss_power_w

        written = power if self._written is None else evaluate(self._written)
        jac = np.empty((len(t), len(self._perturbed)))
        for j, (step, estimator) in enumerate(self._perturbed):
            jac[:, j] = (evaluate(estimator) - written) / step
        self.gradient += jac.T @ dt
        shifts = np.zeros((len(t), len(self._alternatives)))
        for j, (_name, estimator) in enumerate(self._alternatives):
            shifts[:, j] = evaluate(estimator) - written
        self.alternative_shift_j += shifts.T @ dt
        axes = {"speed": np.abs(b.speed_rad_s) > self.speed_limit, "torque": np.abs(b.torque_nm) > self.torque_limit}
        if self.oil_limits is not None and b.temperature_c is not None:
            theta = np.asarray(b.temperature_c, dtype=float)
            axes["oil temperature"] = (theta < self.oil_limits[0]) | (theta > self.oil_limits[1])
        beyond = np.logical_or.reduce(list(axes.values()))
        effects_w = np.zeros(len(t))
        if self._paper_only is not None and beyond.any():
            effects_w = np.where(beyond, np.abs(written - evaluate(self._paper_only)), 0.0)
            self.beyond_samples += int(beyond.sum())
            for axis, mask in axes.items():
                self.beyond_by_axis[axis] += int(mask.sum())
            self.beyond_effects_j += float(np.sum(effects_w * dt))
        if self._collect:
            cov = self.covariance.matrix if self.covariance else np.zeros((0, 0))
            sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, cov, jac), 0.0) + effects_w * effects_w)
            low = np.minimum(shifts.min(axis=1), 0.0) if shifts.shape[1] else np.zeros(len(t))
            high = np.maximum(shifts.max(axis=1), 0.0) if shifts.shape[1] else np.zeros(len(t))
            self._parts.append((t, power, sd, low, high, effects_w))

    def finish(self) -> Prediction:
        """The prediction of everything added."""
        var = float(self.gradient @ self.covariance.matrix @ self.gradient) if self.covariance else 0.0
        var += self.beyond_effects_j ** 2  # the effects' share beyond what was seen: as large as it is, or none
        duration = ((self.last_t or 0) - (self.first_t or 0)) * 1e-9
        shifts = self.alternative_shift_j
        out = Prediction(self.samples, duration, self.energy, math.sqrt(max(var, 0.0)), self.energy_in, self.peak,
                         self.covariance.keys if self.covariance else (), adapted_samples=self.adapted_samples,
                         recorded=self.recorded)
        out.model_form_j = (min(0.0, float(shifts.min())) if len(shifts) else 0.0,
                            max(0.0, float(shifts.max())) if len(shifts) else 0.0)
        out.alternatives = {name: float(v) for (name, _e), v in zip(self._alternatives, shifts)}
        out.beyond_samples, out.beyond_effects_j = self.beyond_samples, self.beyond_effects_j
        out.limits, out.oil_limits = (self.speed_limit, self.torque_limit), self.oil_limits
        out.beyond_by_axis = {k: v for k, v in self.beyond_by_axis.items() if v}
        form = self.form
        if form and form.unresolved and not self._alternatives:
            out.band_refused = (f"the calibration left {form.unresolved} unresolved, with no alternative written to "
                                "span: a band of the written parameters alone would claim more than is known")
        out.notes = list(self.alternative_notes)
        if self._lags:
            out.notes.append(f"channel lags (the parameter file's): {self._lags}")
        if form and form.segment:
            out.notes.append(f"the parameter file describes the gearbox of {printable(form.segment)} (it changed "
                             "inside the "
                             "recordings calibrated on)")
        if self._collect:
            cat = [np.concatenate(p) if p else np.zeros(0) for p in zip(*self._parts)] if self._parts else \
                [np.zeros(0, dtype=np.int64), *(np.zeros(0) for _ in range(5))]
            out.t_ns, out.loss_power_w, out.loss_power_sd_w, out.loss_power_form_low_w, out.loss_power_form_high_w, \
                out.loss_power_beyond_w = cat
        return out
