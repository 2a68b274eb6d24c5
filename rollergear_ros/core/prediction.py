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

from ..base.errors import ParameterError
from .covariance import ParameterCovariance
from .estimator import BatchEstimate, Estimator
from .measured import energy_steps_s
from .operating_points import map_config
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
    #: per sample, with ``collect``: times, loss power and its standard deviation
    t_ns: np.ndarray | None = field(default=None, repr=False)
    loss_power_w: np.ndarray | None = field(default=None, repr=False)
    loss_power_sd_w: np.ndarray | None = field(default=None, repr=False)

    @property
    def energy_band_j(self) -> tuple[float, float]:
        """The energy's 95 % band."""
        half = Z95 * self.energy_lost_sd_j
        return self.energy_lost_j - half, self.energy_lost_j + half

    @property
    def mean_loss_power_w(self) -> float:
        return self.energy_lost_j / self.duration_s if self.duration_s > 0 else math.nan

    def to_json(self) -> dict:
        lo, hi = self.energy_band_j
        return {"samples": self.samples, "duration_s": self.duration_s, "energy_lost_j": self.energy_lost_j,
                "energy_lost_band95_j": [lo, hi], "energy_lost_sd_j": self.energy_lost_sd_j,
                "energy_in_j": self.energy_in_j, "mean_loss_power_w": self.mean_loss_power_w,
                "peak_loss_power_w": self.peak_loss_power_w, "parameters": list(self.parameters),
                "method": self.method, "lost_share": self.lost_share, "adapted_samples": self.adapted_samples,
                "recorded": self.recorded}

    def text(self) -> str:
        lo, hi = self.energy_band_j
        wh = 1 / 3600.0
        lines = [f"{self.samples:,} samples over {self.duration_s:.1f} s",
                 f"energy lost {self.energy_lost_j:,.1f} J ({self.energy_lost_j * wh:.4g} Wh), 95 % band "
                 f"{lo:,.1f} … {hi:,.1f} J; energy through the gearbox {self.energy_in_j:,.0f} J",
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
        if self.parameters:
            lines.append(f"band: {self.method} over {', '.join(self.parameters)}")
        else:
            lines.append("band: none -- the parameter file holds no calibration.covariance (write it with "
                         "rollergear calibrate): the loss as if its parameters were exact")
        return "\n".join(lines)


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
        k = len(self._perturbed)
        self.gradient = np.zeros(k)  #: d E / d θ
        self.energy = self.energy_in = self.peak = 0.0
        self.samples = 0
        self.first_t: int | None = None
        self.last_t: int | None = None
        self._dt_ns = 0.0
        self._collect = collect
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

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
        jac = np.empty((len(t), len(self._perturbed)))
        written = power if self._written is None or not self._perturbed else self._written.process_batch(
            t, b.torque_nm, b.speed_rad_s, temperature=b.temperature_c, breakdown=False).loss_power_w
        for j, (step, estimator) in enumerate(self._perturbed):
            moved = estimator.process_batch(t, b.torque_nm, b.speed_rad_s, temperature=b.temperature_c,
                                            breakdown=False)
            jac[:, j] = (moved.loss_power_w - written) / step
        self.gradient += jac.T @ dt
        if self._collect:
            cov = self.covariance.matrix if self.covariance else np.zeros((0, 0))
            sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, cov, jac), 0.0))
            self._parts.append((t, power, sd))

    def finish(self) -> Prediction:
        """The prediction of everything added."""
        var = float(self.gradient @ self.covariance.matrix @ self.gradient) if self.covariance else 0.0
        duration = ((self.last_t or 0) - (self.first_t or 0)) * 1e-9
        out = Prediction(self.samples, duration, self.energy, math.sqrt(max(var, 0.0)), self.energy_in, self.peak,
                         self.covariance.keys if self.covariance else (), adapted_samples=self.adapted_samples,
                         recorded=self.recorded)
        if self._collect:
            cat = [np.concatenate(p) if p else np.zeros(0) for p in zip(*self._parts)] if self._parts else \
                [np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0)]
            out.t_ns, out.loss_power_w, out.loss_power_sd_w = cat
        return out
