"""What a replay did: the running sums over its estimates (:class:`Accumulator`) and the summary
they end in (:class:`ReplaySummary`, printed by ``rollergear replay``).  No rclpy import."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.estimator import BatchEstimate
from ..core.pairing import ARRIVAL_PAIRINGS

__all__ = ["Accumulator", "ReplaySummary"]


@dataclass
class ReplaySummary:
    """What a replay did (printed, and returned for tests)."""

    bag: str
    input_messages: int = 0
    samples: int = 0
    estimated: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    mean_loss_nm: float = math.nan
    peak_loss_nm: float = math.nan
    energy_lost_j: float = 0.0
    energy_in_j: float = 0.0  #: ∫|T_in·ω_in| dt, the energy through the gearbox
    #: over the samples with a measured loss: the energy through the gearbox and the measured energy lost
    energy_in_measured_j: float = 0.0
    energy_lost_measured_j: float = 0.0
    mean_efficiency: float = math.nan
    residual_rms_nm: float = math.nan
    residual_mean_nm: float = math.nan
    residual_samples: int = 0
    efficiency_samples: int = 0  #: estimates with a finite efficiency (the mean's weight)
    duration_s: float = 0.0
    start_ns: int | None = None  #: first estimated sample
    end_ns: int | None = None  #: last estimated sample
    alarms: int = 0
    interrupted: bool = False
    sync_tolerance_s: float = math.nan  #: the pairing tolerance used
    sample_period_s: float | None = None  #: the motor torque's median message period in the bag
    pairing: str = "timestamp"  #: ``arrival`` for a recording of the node that paired by arrival
    warnings: list[str] = field(default_factory=list)
    coefficients: dict[str, float] = field(default_factory=dict)
    summary_png: str | None = None  #: the summary picture, when one was drawn
    #: the recording's run-time parameter changes applied where the node applied them (:mod:`.switches`)
    parameter_changes: list[str] = field(default_factory=list)
    speed_noise_rad_s: float = 0.0  #: the speed reading's noise the estimator used (at the end)
    speed_noise_text: str = ""  #: ... and where it came from (the file, or learned)

    def text(self) -> str:
        lines = [
            f"bag: {self.bag}",
            f"input messages: {self.input_messages:,} ({self.samples:,} motor torque); "
            f"estimated: {self.estimated:,}; log duration {self.duration_s:.1f} s",
        ]
        if self.pairing in ARRIVAL_PAIRINGS:
            lines.append(
                f"pairing: by arrival, as loss_estimator paired them when it recorded this bag (its sample "
                f"period {1e3 * (self.sample_period_s or 0):.3g} ms, arrivals within "
                f"{1e3 * self.sync_tolerance_s:.3g} ms)"
            )
        elif self.sample_period_s:
            lines.append(
                f"pairing: sample period {1e3 * self.sample_period_s:.3g} ms, inputs within "
                f"{1e3 * self.sync_tolerance_s:.3g} ms form one sample"
            )
        if self.speed_noise_text:
            lines.append(f"speed reading's noise: {self.speed_noise_text}")
        skipped = {k: v for k, v in self.skipped.items() if v}
        lines.append("skipped: " + (", ".join(f"{v:,} {k.replace('_', ' ')}" for k, v in skipped.items()) or "none"))
        lines.append(
            f"loss torque: mean {self.mean_loss_nm:.4f} N·m, peak {self.peak_loss_nm:.4f} N·m; "
            f"energy lost {self.energy_lost_j:.1f} J; mean efficiency "
            + ("n/a" if math.isnan(self.mean_efficiency) else f"{100 * self.mean_efficiency:.2f} %")
        )
        if self.residual_samples:
            lines.append(
                f"residual (measured − estimated loss): RMS {self.residual_rms_nm:.4f} N·m over "
                f"{self.residual_samples:,} samples; change alarms: {self.alarms}"
            )
        if self.parameter_changes:
            lines.append(f"parameter changes the node made, applied where it made them: "
                         f"{'; '.join(self.parameter_changes)}")
        if self.coefficients:
            lines.append("adapted coefficients: " + ", ".join(f"{k} {v:.4g}" for k, v in self.coefficients.items()))
        if self.interrupted:
            lines.append("INTERRUPTED: outputs hold everything processed up to the interrupt")
        lines.extend(f"warning: {w}" for w in self.warnings)
        return "\n".join(lines)


class Accumulator:
    """Running sums for the summary."""

    def __init__(self) -> None:
        self.n = 0
        self.loss_sum = 0.0
        self.peak = 0.0
        self.energy = 0.0
        self.energy_in = 0.0
        self.energy_in_meas = 0.0
        self.energy_lost_meas = 0.0
        self.res_sum = 0.0
        self.eta_sum = 0.0
        self.eta_n = 0
        self.res_sq = 0.0
        self.res_n = 0
        self.last_t: int | None = None
        self.first_t: int | None = None
        self.dt_ns = 0
        self.trace = None  #: a :class:`.plot.SummaryTrace` when a summary picture is drawn

    def prime(self, last_t_ns: int) -> None:
        """A sample before a time slice: the slice's first sample integrates from it."""
        self.last_t = last_t_ns

    def add(self, b: BatchEstimate) -> None:
        if len(b.t_ns) == 0:
            return
        if self.trace is not None:
            self.trace.add(b)
        mag = np.abs(b.loss_torque_nm)
        self.n += len(mag)
        self.loss_sum += float(mag.sum())
        self.peak = max(self.peak, float(mag.max()))
        t = np.asarray(b.t_ns, dtype=np.int64)
        if self.first_t is None:
            self.first_t = int(t[0])
        prev = self.last_t if self.last_t is not None else int(t[0])
        dt = np.diff(np.concatenate([[prev], t])).astype(float)
        typical = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
        if typical > 0:
            self.dt_ns = typical
        # integrate P·dt; gaps longer than 5 sample periods (missing data) are not integrated
        dt = np.where((dt > 0) & (dt <= 5 * max(self.dt_ns, 1.0)), dt, 0.0)
        self.energy += float(np.sum(b.loss_power_w * dt) * 1e-9)
        p_in = np.abs(b.torque_nm * b.speed_rad_s)
        self.energy_in += float(np.sum(p_in * dt) * 1e-9)
        meas = np.isfinite(b.measured_loss_nm)
        if meas.any():
            self.energy_in_meas += float(np.sum(p_in[meas] * dt[meas]) * 1e-9)
            p_lost = b.measured_loss_nm[meas] * np.abs(b.speed_rad_s[meas])
            self.energy_lost_meas += float(np.sum(p_lost * dt[meas]) * 1e-9)
        self.last_t = int(t[-1])
        eta = b.efficiency[np.isfinite(b.efficiency)]
        self.eta_sum += float(eta.sum())
        self.eta_n += len(eta)
        r = b.residual_nm[np.isfinite(b.residual_nm)]
        self.res_sq += float(np.sum(r * r))
        self.res_sum += float(np.sum(r))
        self.res_n += len(r)

    def fill(self, summary: ReplaySummary) -> None:
        """The sums' means, energies and span in ``summary`` (what has been estimated)."""
        if self.n:
            summary.mean_loss_nm = self.loss_sum / self.n
            summary.peak_loss_nm = self.peak
            summary.energy_lost_j = self.energy
            summary.energy_in_j = self.energy_in
            summary.energy_in_measured_j = self.energy_in_meas
            summary.energy_lost_measured_j = self.energy_lost_meas
            summary.duration_s = ((self.last_t or 0) - (self.first_t or 0)) * 1e-9
            summary.start_ns, summary.end_ns = self.first_t, self.last_t
        if self.eta_n:
            summary.mean_efficiency = self.eta_sum / self.eta_n
            summary.efficiency_samples = self.eta_n
        if self.res_n:
            summary.residual_rms_nm = math.sqrt(self.res_sq / self.res_n)
            summary.residual_mean_nm = self.res_sum / self.res_n
            summary.residual_samples = self.res_n
