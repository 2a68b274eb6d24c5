"""What a replay did: the running sums over its estimates (:class:`Accumulator`) and the summary
they end in (:class:`ReplaySummary`, printed by ``rollergear replay``).  No rclpy import."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.batchpath import BatchEstimate
from ..core.measured import EnergyBalance, MeasuredEfficiency, energy_steps_s
from ..core.pairing import ARRIVAL_PAIRINGS
from ..core.params import Config

#: the summary lists the operating-point cells that hold the most supplied energy, at most this many
SUMMARY_CELLS = 8
#: a cell with fewer samples (or less than this share of the energy) is not listed
CELL_MIN_SAMPLES = 100

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
    #: where the output torque was measured: energy supplied and delivered (:mod:`core.measured`)
    measured: EnergyBalance = field(default_factory=EnergyBalance)
    #: ... split by the end power came in at: ``(motoring, regenerating)`` with their uncertainties
    measured_quadrants: tuple[tuple[EnergyBalance, float], tuple[EnergyBalance, float]] | None = None
    #: the measured efficiency's standard uncertainty (0: no sensor accuracy stated, NaN: no efficiency)
    measured_uncertainty: float = math.nan
    sensors_stated: bool = False  #: whether ``sensors.*`` states an accuracy
    #: per operating-point cell (the map grid's nearest node): ``(speed rpm, torque N·m, balance, uncertainty)``
    measured_cells: list[tuple[float, float, EnergyBalance, float]] = field(default_factory=list)
    mean_efficiency: float = math.nan
    residual_rms_nm: float = math.nan
    residual_mean_nm: float = math.nan
    residual_samples: int = 0
    efficiency_samples: int = 0  #: estimates with a finite efficiency (the mean's weight)
    duration_s: float = 0.0
    start_ns: int | None = None  #: first estimated sample
    end_ns: int | None = None  #: last estimated sample
    alarms: int = 0
    #: the change detector's alarms (sample times) and whether each came before the residual was ever
    #: within its threshold (off from the start: the parameters lack an effect, no change)
    alarm_times_ns: list[int] = field(default_factory=list)
    alarm_from_start: list[bool] = field(default_factory=list)
    interrupted: bool = False
    #: the share of the recording lost to damage (:func:`base.errors.lost_share`; 0: none found)
    lost_share: float = 0.0
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
    lags_text: str = ""  #: the channel lags the file's estimator aligned ('': none)
    beyond_text: str = ""  #: the samples beyond a plausibility limit, by limit, and the setting to raise
    #: the adapted coefficients kept within the range a parameter file may hold ('': none needed it)
    adaptation_text: str = ""
    #: the channels at another rate, resampled onto the drive torque's stamps ('': none)
    resampled_text: str = ""
    #: per resampled channel: its samples by how they were made (exact, interpolated, held, none)
    resampled: dict[str, dict[str, int]] = field(default_factory=dict)
    describes: str = ""  #: the stretch of its calibration's recordings the parameter file describes

    @property
    def energy_in_measured_j(self) -> float:
        """Energy supplied to the gearbox where the output torque was measured."""
        return self.measured.supplied_j

    @property
    def energy_lost_measured_j(self) -> float:
        """... and the measured energy lost there (supplied − delivered)."""
        return self.measured.lost_j

    @property
    def efficiency_measured(self) -> float:
        """The measured efficiency, energy-weighted over the recording (NaN without measured output)."""
        return self.measured.efficiency

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
        if self.lags_text:
            lines.append(f"channel lags (the parameter file's): {self.lags_text}")
        if self.resampled_text:
            lines.append(self.resampled_text)
        if self.describes:
            lines.append(f"the parameter file describes the gearbox of {self.describes} (it changed inside the "
                         "recordings calibrated on)")
        skipped = {k: v for k, v in self.skipped.items() if v}
        lines.append("skipped: " + (", ".join(f"{v:,} {k.replace('_', ' ')}" for k, v in skipped.items()) or "none"))
        if self.beyond_text:
            lines.append(f"implausible: {self.beyond_text}")
        if self.adaptation_text:
            lines.append(f"adaptation: {self.adaptation_text}")
        spin = self.measured.samples > 0 and self.measured.no_output
        lines.append(
            f"loss torque: mean {self.mean_loss_nm:.4f} N·m, peak {self.peak_loss_nm:.4f} N·m; "
            f"energy lost {self.energy_lost_j:.1f} J; model efficiency: "
            + ("none (no power leaves the output)" if spin else "mean " + (
                "n/a" if math.isnan(self.mean_efficiency) else f"{100 * self.mean_efficiency:.2f} %")
               + " over the samples")
        )
        if self.measured.samples:
            lines.extend(self._measured_lines())
        if self.residual_samples:
            lines.append(
                f"residual (measured − estimated loss): RMS {self.residual_rms_nm:.4f} N·m over "
                f"{self.residual_samples:,} samples; change alarms: {self.alarms}{self._alarm_times()}"
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


    def _alarm_times(self) -> str:
        """When the alarms came (seconds into the recording) and what each means."""
        if not self.alarm_times_ns or self.start_ns is None:
            return ""
        said = []
        for t, from_start in list(zip(self.alarm_times_ns, self.alarm_from_start))[:10]:
            what = "the residual off from the start: the parameters lack an effect, not a change" if from_start \
                else "the residual changed"
            said.append(f"{(t - self.start_ns) * 1e-9:.1f} s ({what})")
        more = f", … {len(self.alarm_times_ns) - 10} more" if len(self.alarm_times_ns) > 10 else ""
        return " at " + ", ".join(said) + more

    def _measured_lines(self) -> list[str]:
        """The measured efficiency beside the model's, over the recording and per operating point."""
        m, stated = self.measured, self.sensors_stated
        if m.no_output:  # a spin test: the loss, not an efficiency
            return [f"measured: no power leaves the output (a spin test: {m.delivered_j:,.2g} J delivered of "
                    f"{m.supplied_j:,.0f} J supplied over {m.seconds:,.1f} s): the drive power is all loss, "
                    f"{m.supplied_j / m.seconds if m.seconds > 0 else math.nan:.4g} W on average; the model's loss "
                    f"over the same samples {m.model_loss_j:,.0f} J -- no efficiency where no power flows out"]
        unknown = "" if stated else " (its uncertainty not known: state the sensors' accuracy in sensors.*)"
        both = bool(self.measured_quadrants) and all(b.supplied_j > 0 for b, _ in self.measured_quadrants)
        cancels = ""
        if both and stated and math.isfinite(self.measured_uncertainty):
            smallest = min(u for _, u in self.measured_quadrants)
            if self.measured_uncertainty < 0.5 * smallest:  # the gain errors cancel between the directions
                cancels = (f" (either direction alone ± {100 * smallest:.2g} % or more: a torque sensor's gain "
                           "error moves motoring and regenerating apart and cancels in the recording's sum)")
        lines = [f"measured efficiency: {_pct(m.efficiency, self.measured_uncertainty, stated)}{unknown}{cancels}, "
                 f"energy-weighted: {m.delivered_j:,.0f} J delivered of {m.supplied_j:,.0f} J supplied over "
                 f"{m.seconds:,.1f} s with measured output; the model's over the same samples "
                 f"{100 * m.model_efficiency:.2f} %"]
        if both:
            (mot, u_mot), (reg, u_reg) = self.measured_quadrants
            lines.append(f"  motoring {_pct(mot.efficiency, u_mot, stated)} "
                         f"(model {100 * mot.model_efficiency:.2f} %), "
                         f"regenerating {_pct(reg.efficiency, u_reg, stated)} "
                         f"(model {100 * reg.model_efficiency:.2f} %)"
                         f": a torque sensor's gain error moves these two apart and cancels in their sum")
        cells = [c for c in self.measured_cells if c[2].samples >= CELL_MIN_SAMPLES and c[2].supplied_j > 0]
        if len(cells) > 1:
            shown = sorted(cells, key=lambda c: -c[2].supplied_j)[:SUMMARY_CELLS]
            share = sum(c[2].supplied_j for c in shown) / m.supplied_j if m.supplied_j > 0 else math.nan
            lines.append(f"  per operating point (input speed, torque; the {len(shown)} of {len(cells)} cells with the "
                         f"most energy, {100 * share:.0f} % of it): measured | model")
            lines.extend(f"  {rpm:7.0f} rpm {torque:8.1f} N·m   {_pct(b.efficiency, u, stated)} | "
                         f"{100 * b.model_efficiency:.2f} %   {b.samples:,} samples"
                         for rpm, torque, b, u in sorted(shown, key=lambda c: (c[0], c[1])))
        return lines


def _pct(eta: float, u: float, stated: bool) -> str:
    """``98.04 % ± 0.21 %`` (standard uncertainty to two significant digits, two or three decimals;
    the efficiency to as many), without it when no accuracy is stated."""
    if not math.isfinite(eta):
        return "n/a"
    if not (stated and math.isfinite(u)):
        return f"{100 * eta:.2f} %"
    decimals = 2 if u <= 0 else min(max(2, 1 - math.floor(math.log10(100 * u))), 3)
    return f"{100 * eta:.{decimals}f} % ± {100 * u:.{decimals}f} %"


class Accumulator:
    """Running sums for the summary (``config``: the measured efficiency's ratio, sensors, window and
    cells; ``sample_period_s``: the estimator's, the measured efficiency's gaps)."""

    def __init__(self, config: Config | None = None, sample_period_s: float | None = None) -> None:
        config = config or Config()
        self.config = config
        self.measured = MeasuredEfficiency(config.gearbox.ratio_effective, sample_period_s or 1e-3,
                                           config.node.efficiency_window_s, config.map.speed_step_rpm,
                                           config.map.torque_step_nm)
        self.n = 0
        self.loss_sum = 0.0
        self.peak = 0.0
        self.energy = 0.0
        self.energy_in = 0.0
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
        self.measured.prime(last_t_ns)

    def add(self, b: BatchEstimate) -> None:
        if len(b.t_ns) == 0:
            return
        mag = np.abs(b.loss_torque_nm)
        self.n += len(mag)
        self.loss_sum += float(mag.sum())
        self.peak = max(self.peak, float(mag.max()))
        t = np.asarray(b.t_ns, dtype=np.int64)
        if self.first_t is None:
            self.first_t = int(t[0])
        dt_s, self.dt_ns = energy_steps_s(t, self.last_t, self.dt_ns)  # P·dt, not across gaps
        self.energy += float(np.sum(b.loss_power_w * dt_s))
        self.energy_in += float(np.sum(np.abs(b.torque_nm * b.speed_rad_s) * dt_s))
        if b.out_torque_nm is not None:  # the samples with a measured loss, as the node's window takes them
            out = np.where(np.isfinite(b.measured_loss_nm), b.out_torque_nm, np.nan)
            self.measured.add(t, b.torque_nm, b.speed_rad_s, out, b.out_speed_rad_s, b.loss_power_w)
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
            sensors = self.config.sensors
            summary.measured = self.measured.total
            summary.measured_uncertainty = self.measured.total.uncertainty(sensors)
            summary.measured_quadrants = tuple((b, b.uncertainty(sensors))
                                               for b in (self.measured.motoring, self.measured.regenerating))
            summary.sensors_stated = sensors.stated
            summary.measured_cells = [(rpm, torque, b, b.uncertainty(sensors))
                                      for rpm, torque, b in self.measured.cells()]
            summary.duration_s = ((self.last_t or 0) - (self.first_t or 0)) * 1e-9
            summary.start_ns, summary.end_ns = self.first_t, self.last_t
        if self.eta_n:
            summary.mean_efficiency = self.eta_sum / self.eta_n
            summary.efficiency_samples = self.eta_n
        if self.res_n:
            summary.residual_rms_nm = math.sqrt(self.res_sq / self.res_n)
            summary.residual_mean_nm = self.res_sum / self.res_n
            summary.residual_samples = self.res_n
