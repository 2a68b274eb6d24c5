"""The one estimator: model + accepted effects + residual + online adaptation, per sample or batch.

Used by the live node (:meth:`Estimator.push`, one message at a time) and by offline replay
(:meth:`Estimator.push_many` and :meth:`Estimator.flush`, whole arrays); there is no second code
path: both go through the same :class:`~.pairing.SampleSynchronizer`, and the vectorised
:meth:`Estimator.process_batch` gives the numbers of the per-sample :meth:`Estimator.process`
(tested).  Data flows one way: messages -> pairing (:mod:`.pairing`) -> estimates (here, with
:mod:`.adaptation`) -> the caller's writers.  No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .adaptation import (
    ChangeDetector,
    RecursiveLeastSquares,
    ResidualStats,
    adaptive_effects,
    coefficient_bounds,
    effect_coefficients,
    regressor_plan,
)
from .batchpath import BatchEstimate, BatchPath
from .effects import (
    EFFECTS,
    STATE_STILL_WIDTHS,
    EffectInputs,
    corrected_torque,
    reading_errors,
    takes_load,
)
from .effectsum import additive_terms, fr_scale
from .lagalign import LAG_CHANNELS, LagAligner, max_gap_s
from .model import LossModel, rotation_sign_scalar
from .pairing import (ARRIVAL_PAIRINGS, ARRIVAL_TOLERANCE_S, LOSSLESS_PAIRINGS, TORQUE, SampleSynchronizer,
                      SyncedSample, pairing_tolerance_s, samples_to_arrays)
from .lostmarks import is_lost
from .params import Config
from .resample import Message, RateResampler, is_stale
from .speednoise import DirectionRun, SpeedNoise


@dataclass(slots=True)
class Estimate:
    """Estimator output for one sample (the node publishes these)."""

    t_ns: int
    torque_nm: float
    speed_rad_s: float
    loss_torque_nm: float  #: signed, input-referred, opposes rotation
    loss_power_w: float
    efficiency: float  #: NaN where undefined
    measured_loss_nm: float  #: NaN without measured output
    residual_nm: float  #: measured − expected measured loss; NaN without measured output
    out_torque_nm: float = math.nan  #: the measured output torque it was paired with (NaN: none)
    out_speed_rad_s: float = math.nan  #: the measured output speed (NaN: none)
    temperature_c: float = math.nan  #: the oil temperature (NaN: none)
    #: P_out/P_in (motoring) or P_in/P_out (regenerating) as the sensors read them (:mod:`.measured`);
    #: NaN without measured output or where undefined
    efficiency_measured: float = math.nan
    sign: float = math.nan  #: the direction the loss opposes, as the estimate took it (:attr:`BatchEstimate.sign`)


def _synced(paired: tuple[np.ndarray, ...]) -> list[SyncedSample]:
    """Paired arrays as samples (the node's one-by-one path)."""
    t, *values = paired
    return [SyncedSample(int(t[i]), *(float(v[i]) for v in values)) for i in range(len(t))]


def balance_below(min_speed_rad_s: float, min_measured_rad_s: float) -> float:
    """Below this |ω| the measured loss is the torque balance where the direction is known, else none: the
    efficiency's speed threshold, or 3 × the speed reading's noise where that is higher (once the noise is
    known) -- a drive at rest reads speeds of either sign up to there, and their sign is no direction of a
    sliding friction."""
    return max(min_speed_rad_s, 1e-9, min_measured_rad_s if math.isfinite(min_measured_rad_s) else 0.0)


class Estimator(BatchPath):
    """Model + accepted effects + residual + online adaptation, for one :class:`Config`."""

    def __init__(self, config: Config, pairing: str = "timestamp", sample_period_s: float | None = None,
                 operating_points: bool = False) -> None:
        """``operating_points``: each sample is an operating point of its own (a steady-state table's
        row, a dwell mean, a point of a map): its direction is its speed's sign, a measured loss wherever
        it moves, and no run of samples tells a direction (:class:`~.speednoise.DirectionRun`).
        ``pairing``: ``timestamp`` (bags; live with publisher timestamps), ``arrival`` or
        ``arrival_reliable`` / ``arrival_sequenced`` (arrival order over a delivery that loses
        nothing, or whose losses are filled in; see :class:`~.pairing.SampleSynchronizer`);
        ``sample_period_s``: the motor torque's median message period, for the automatic pairing
        tolerance (:func:`pairing_tolerance_s`; 1 ms when not given)."""
        self.config = config
        self.pairing, self.sample_period_s = pairing, sample_period_s  # for an estimator that takes over
        self.operating_points = operating_points
        est = config.estimator
        self.sync_tolerance_s = pairing_tolerance_s(est.sync_tolerance_s, sample_period_s)
        self.model = LossModel(config.gearbox, est.min_torque_for_efficiency_nm, est.min_speed_for_efficiency_rad_s,
                               est.paper_model)
        self.ratio = config.gearbox.ratio_effective
        #: the loss torque's sign runs through 0 as tanh(ω/width) near standstill, width the speed
        #: reading's noise σ: about the sign such a reading has on average (erf(ω/(σ√2))), so that a
        #: direction the reading cannot tell is no reversal; measured losses start at 3σ
        self.speed_noise = SpeedNoise(est.speed_noise_rad_s)  # given, or learned from the first samples
        self.sign_width_rad_s = self.speed_noise.value
        self.min_measured_speed_rad_s = self.speed_noise.min_measured_rad_s
        self.balance_below_rad_s = balance_below(self.model.min_speed_rad_s, self.min_measured_speed_rad_s)
        self._still_rad_s = STATE_STILL_WIDTHS * self.sign_width_rad_s  # a memory does not step within it
        if pairing in ARRIVAL_PAIRINGS:
            self.sync_tolerance_s = max(self.sync_tolerance_s, ARRIVAL_TOLERANCE_S)
            self.sync = SampleSynchronizer(self.sync_tolerance_s, est.staleness_s, arrival=True,
                                           lossless=pairing in LOSSLESS_PAIRINGS, sample_period_s=sample_period_s)
        elif pairing == "timestamp":
            self.sync = SampleSynchronizer(self.sync_tolerance_s, est.staleness_s)
        else:
            raise ValueError(f"pairing must be 'timestamp' or one of {', '.join(ARRIVAL_PAIRINGS)}, not {pairing!r}")
        self.counts = self.sync.counts  # skip reasons (shared with the synchroniser)
        #: channels at another rate than the motor torque, resampled onto its stamps before the pairing
        # (the pairing tolerance of stamps, by arrival too: whether a channel is in step is told the same way)
        self.resampler = RateResampler(est.resample_max_age_s,
                                       int(round(pairing_tolerance_s(est.sync_tolerance_s, sample_period_s) * 1e9)))
        #: a channel that reads late, aligned between the pairing and the estimate (None: none lags)
        lags = {c: getattr(est, f"{c}_lag_s") for c in LAG_CHANNELS}
        self.aligner = LagAligner(lags, max_gap_s(est.staleness_s, sample_period_s), sample_period_s) \
            if any(lags.values()) else None
        self.adaptive = adaptive_effects(config) if est.adapt else ()
        coef = effect_coefficients(config)
        self._regressor_plan = regressor_plan(self.adaptive, config)
        self._scales = [scale for _term, scale in self._regressor_plan]
        self.rls = RecursiveLeastSquares([coef[n] * s for n, s in zip(self.adaptive, self._scales)],
                                         est.rls_forgetting, 1.0, est.rls_max_covariance,
                                         [(low * s, high * s) for (low, high), s
                                          in zip(coefficient_bounds(self.adaptive), self._scales)])
        self.detector = ChangeDetector(est.change_block_samples, est.change_threshold_nm)
        self._active = config.effects.active()  # enabled effect -> its parameters
        self._additive = any(not EFFECTS[n].scales_fr for n in self._active)
        self._fr_scaling = any(EFFECTS[n].scales_fr for n in self._active)
        self._needs_temperature = any(EFFECTS[n].needs_temperature for n in self._active)
        self._sensor = [not EFFECTS[n].physical for n in self.adaptive]
        self._one_physical = self._sensor == [False]
        # effects with their configured coefficients (all of them when adaptation is off)
        self._fixed = {n: p for n, p in self._active.items() if n not in self.adaptive}
        self._fixed_additive = any(not EFFECTS[n].scales_fr for n in self._fixed)
        self._load_laws = any(takes_load(EFFECTS[n]) for n in self._active)
        # effects with memory: their states, advanced sample by sample in time order (node and replay
        # alike: the same step, in the same float arithmetic, so a replay reproduces the node exactly)
        self._stateful = {n: p for n, p in self._active.items() if EFFECTS[n].state_step is not None}
        self._states: dict[str, float] = dict.fromkeys(self._stateful, 0.0)
        self._steppers = [(n, EFFECTS[n].state_step, p) for n, p in self._stateful.items()]
        self._state_t_ns: int | None = None
        self._previous_speed = 0.0  # of the last sample estimated: a direction known twice in a row
        self._run = DirectionRun()  # the last readings: a direction a run of them tells
        self._sensor_offset, self._sensor_gain = reading_errors(self._active)
        self.residual_stats = ResidualStats()
        self.estimated = 0
        self.last: Estimate | None = None
        #: the samples beyond a plausibility limit, per input: their count and the largest magnitude seen
        self.beyond: dict[str, list[float]] = {"speed": [0, 0.0], "torque": [0, 0.0]}

    def take_over_inputs(self, previous: Estimator) -> None:
        """Continue the input stream of ``previous`` (a parameter change at run time): keep its
        queued messages, skip counters and sample count, under this estimator's pairing limits."""
        self.sync = previous.sync
        self.sync.set_limits(self.sync_tolerance_s, self.config.estimator.staleness_s)
        self.resampler = previous.resampler  # what it holds and has told goes on, under the new age limit
        self.resampler.max_age_ns = int(round(self.config.estimator.resample_max_age_s * 1e9))
        if previous.aligner is not None and self.aligner is not None \
                and previous.aligner.lags_ns == self.aligner.lags_ns:
            self.aligner = previous.aligner  # the samples it holds go on
        self._states.update({n: z for n, z in previous._states.items() if n in self._states})  # memory goes on
        self._state_t_ns = previous._state_t_ns
        self._previous_speed = previous._previous_speed
        self._run.take_over(previous._run)
        self.speed_noise.take_over(previous.speed_noise)
        self._noise_changed()
        self.counts = self.sync.counts
        self.estimated = previous.estimated
        self.beyond = previous.beyond

    # ------------------------------------------------------------------ helpers
    def coefficients(self) -> dict[str, float]:
        """Current (adapted) coefficients of the adaptive effects, in physical units."""
        return {n: t / s for n, t, s in zip(self.adaptive, self.rls.theta, self._scales)}

    def coefficient_intervals(self) -> dict[str, tuple[float, float]]:
        """95 % interval of each adapted coefficient, in physical units: ``θ ± 1.96·σ·√P_ii`` over
        the regressor's scale, ``σ²`` the residual's variance (the RLS covariance is ``σ²·P``).
        Before any residual: unbounded."""
        stats = self.residual_stats
        var = max(stats.mean_sq - stats.mean ** 2, 0.0) if stats.count > 1 else math.inf
        return {n: (t / s - 1.96 * math.sqrt(var * self.rls.P[i][i]) / s,
                    t / s + 1.96 * math.sqrt(var * self.rls.P[i][i]) / s)
                for i, (n, t, s) in enumerate(zip(self.adaptive, self.rls.theta, self._scales))}

    def beyond_text(self) -> str:
        """The samples skipped as implausible, by the limit they passed: its name and value, the largest seen,
        and the setting to raise ('' where none)."""
        est = self.config.estimator
        said = []
        for name, key, limit, unit in (("speed", "max_abs_speed_rad_s", est.max_abs_speed_rad_s, "rad/s"),
                                       ("torque", "max_abs_torque_nm", est.max_abs_torque_nm, "N·m")):
            n, largest = self.beyond[name]
            if n:
                said.append(f"{int(n):,} samples with |{name}| above estimator.{key} = {limit:g} {unit} (up to "
                            f"{largest:.4g}): raise estimator.{key} to {_raise_to(largest):g} to estimate them")
        return "; ".join(said)

    def adaptation_text(self) -> str:
        """The adapted coefficients projected back into the range a parameter file may hold, with how
        often ('' where none was): online adaptation wanted a value no written file could carry."""
        said = []
        for i, (name, held) in enumerate(zip(self.adaptive, self.rls.held)):
            if held:
                low, high = (b / self._scales[i] for b in self.rls.bounds[i])
                key = EFFECTS[name].parameter(EFFECTS[name].coefficient).key
                said.append(f"effects.{name}.{key} kept within the range a parameter file may hold "
                            f"[{low:g}, {high:g}] at {held:,} updates (now {self.rls.theta[i] / self._scales[i]:.4g})")
        return "; ".join(said)

    def corrected_torque(self, torque_meas):
        """Drive torque with the accepted torque-sensor errors removed (:func:`.effects.corrected_torque`)."""
        return corrected_torque(torque_meas, self._sensor_offset, self._sensor_gain)

    def screen(self, torque: float, speed: float) -> str | None:
        """Reason a motor sample cannot be estimated, or None."""
        if not (math.isfinite(torque) and math.isfinite(speed)):
            if is_lost(torque) or is_lost(speed):
                return "lost"
            return "stale" if is_stale(speed) else "non_finite"
        est = self.config.estimator
        if abs(torque) > est.max_abs_torque_nm or abs(speed) > est.max_abs_speed_rad_s:
            for name, value, limit in (("speed", speed, est.max_abs_speed_rad_s),
                                       ("torque", torque, est.max_abs_torque_nm)):
                if abs(value) > limit:
                    seen = self.beyond[name]
                    seen[0] += 1
                    seen[1] = max(seen[1], abs(value))
            return "implausible"
        return None

    def measured_loss(self, torque, speed, out_torque, out_speed, previous_speed=None, run=None):
        """``T_loss,meas = (T_in·ω_in − T_out·ω_out)/|ω_in|``; ``ω_out = ω_in/ratio`` when not measured.

        Below :attr:`balance_below_rad_s` (the efficiency speed threshold, or 3 × the speed reading's
        noise where higher: :func:`balance_below`) the quotient of two noisy speeds is noise: the torque
        balance ``(T_in − T_out/ratio)·sgn ω`` instead (a spin test: ``T_in·sgn ω``), where the
        direction is known -- ``|ω|`` and the previous sample's (``previous_speed``, in the same
        direction) at least 3 × the speed reading's noise: a reading at rest is beyond 3σ once in 400
        samples, twice in a row in the same direction once in 300 000 -- or a run of readings tells it
        (``run``: :class:`~.speednoise.DirectionRun`'s ±1, 0 where it does not); NaN elsewhere.
        Operating points (:attr:`operating_points`) are dwell means, without a speed reading's noise:
        the power balance wherever they move.
        """
        w_out = np.where(np.isnan(out_speed), speed / self.ratio, out_speed)
        with np.errstate(divide="ignore", invalid="ignore"):
            m = (torque * speed - out_torque * w_out) / np.abs(speed)
        if self.operating_points:  # dwell means: no speed noise to divide by, the power balance throughout
            return np.where(speed != 0, m, np.nan)
        slow = np.abs(speed) < self.balance_below_rad_s
        if np.any(slow):
            prev = previous_speed if previous_speed is not None else speed
            least = self.min_measured_speed_rad_s
            known = (np.abs(speed) >= least) & (np.abs(prev) >= least) & (np.sign(prev) == np.sign(speed)) \
                & (speed != 0)
            direction = np.where(known, np.sign(speed), 0.0 if run is None else run)
            m = np.where(slow, np.where(direction != 0, (torque - out_torque / self.ratio) * direction, np.nan), m)
        return m

    def _measured_loss_scalar(self, torque, speed, out_torque, out_speed, previous_speed, run: int) -> float:
        if not math.isfinite(out_torque):
            return math.nan
        if speed == 0 and self.operating_points:
            return math.nan
        if abs(speed) < self.balance_below_rad_s and not self.operating_points:  # the torque balance, where
            least = self.min_measured_speed_rad_s  # the direction is known
            if abs(speed) < least or abs(previous_speed) < least or (speed > 0) != (previous_speed > 0) \
                    or speed == 0:
                return (torque - out_torque / self.ratio) * float(run) if run else math.nan
            return (torque - out_torque / self.ratio) * (1.0 if speed > 0 else -1.0)
        w_out = speed / self.ratio if math.isnan(out_speed) else out_speed
        return (torque * speed - out_torque * w_out) / abs(speed)

    def _measured_efficiency_scalar(self, torque, speed, out_torque, out_speed) -> float:
        """Per-sample :func:`.measured.measured_efficiency` (the same arithmetic, one sample)."""
        if abs(torque) < self.model.min_torque_nm or abs(speed) < self.model.min_speed_rad_s:
            return math.nan
        p_in = torque * speed
        p_out = out_torque * (speed / self.ratio if math.isnan(out_speed) else out_speed)
        if p_in > 0:
            return p_out / p_in
        return p_in / p_out if p_in < 0 and p_out < 0 else math.nan

    # ------------------------------------------------------------------ streaming (node)
    def push(self, channel: str, t_ns: int, value: float, source_ns: int | None = None) -> Sequence[Estimate]:
        """Feed one input message (``source_ns``: its publisher's timestamp, by arrival); returns the
        estimates it completes."""
        if self.resampler.direct(channel):
            samples = self.sync.push(channel, t_ns, value, source_ns)
        else:
            samples = self._push_resampled(self.resampler.push(Message(channel, t_ns, value, source_ns)))
        if samples and self.aligner is not None:
            samples = _synced(self._aligned(samples_to_arrays(samples)))
        if not samples:
            return ()
        out = []
        for s in samples:
            e = self.process(s)
            if e is not None:
                out.append(e)
        return out

    def finish(self) -> list[Estimate]:
        """At the end of a live run: estimate, one by one, what can still be paired -- the samples held
        for a measured output -- exactly as :meth:`flush` does at the end of a recording."""
        samples = self._push_resampled(self.resampler.flush())
        samples.extend(self.sync.flush())
        if self.aligner is not None:
            samples = _synced(self._aligned(samples_to_arrays(samples), final=True))
        return [e for e in map(self.process, samples) if e is not None]


    def _push_resampled(self, messages: list[Message]) -> list[SyncedSample]:
        """The resampler's messages through the pairing, one by one."""
        out: list[SyncedSample] = []
        push = self.sync.push
        for m in messages:
            out.extend(push(*m))
        return out


    def _aligned(self, paired: tuple[np.ndarray, ...], final: bool = False) -> tuple[np.ndarray, ...]:
        """Paired samples through the lag alignment (:mod:`.lagalign`; as they are where nothing lags);
        the samples it finds too late to order are counted as ``out_of_order``."""
        aligner = self.aligner
        if aligner is None:
            return paired
        late = aligner.late
        out = aligner.push(paired)
        if final:
            rest = aligner.flush()
            out = tuple(np.concatenate([a, b]) for a, b in zip(out, rest))
        self.counts["out_of_order"] += aligner.late - late
        return out

    def _estimate(self, paired: tuple[np.ndarray, ...], breakdown: bool = True) -> BatchEstimate | None:
        t, tq, w, tq_out, w_out, theta = paired
        return self.process_batch(t, tq, w, tq_out, w_out, theta, breakdown=breakdown) if len(t) else None

    @property
    def motor_messages(self) -> int:
        """Motor torque messages received so far (the samples offered)."""
        return self.sync.received[TORQUE]

    def process(self, s: SyncedSample) -> Estimate | None:
        """Estimate one paired sample (scalar path); None (and counted) when it is invalid."""
        t_meas, w = s.torque_nm, s.speed_rad_s
        reason = self.screen(t_meas, w)
        if reason:
            self.counts[reason] += 1
            return None
        if self.speed_noise.schedule and self.speed_noise.reach(s.t_ns):
            self._noise_changed()
        t = t_meas if self._sensor_offset == 0.0 and self._sensor_gain == 0.0 else self.corrected_torque(t_meas)
        at, aw = abs(t), abs(w)
        run = 0 if self.operating_points else self._run.step(w, self.sign_width_rad_s, self.speed_noise.known)
        sg = float(run) if run and aw < self.min_measured_speed_rad_s \
            else rotation_sign_scalar(w, t, self.sign_width_rad_s)
        vscale = 1.0
        if self._fr_scaling:
            if math.isfinite(s.temperature_c) or not self._needs_temperature:
                vscale = fr_scale(self._active, EffectInputs(at, aw, t, sg, s.temperature_c))
            else:
                self.counts["temperature_missing"] += 1
        mag = self.model.loss_magnitude_scalar(t, w, vscale)
        # the effects' inputs, fixed terms and regressors, once per sample for the estimate and the RLS
        state = self._advance(s.t_ns, w) if self._stateful else {}
        x = EffectInputs(at, aw, t, sg, s.temperature_c, 1.0, state) if self._additive or self.adaptive else None
        meas = self._measured_loss_scalar(t_meas, w, s.out_torque_nm, s.out_speed_rad_s, self._previous_speed, run)
        self._previous_speed = w
        if math.isnan(s.out_torque_nm):
            pass
        elif not math.isfinite(s.out_torque_nm) or not math.isfinite(s.out_speed_rad_s) and not math.isnan(
                s.out_speed_rad_s):
            self.counts["output_non_finite"] += 1
            meas = math.nan
        if self.adaptive:  # regressors(): the laws in the load at the measured load, else the one solved
            if self._load_laws:
                x = x._replace(abs_load=abs(t_meas - sg * meas)) if math.isfinite(meas) \
                    else self.solved_load(x, mag, self.rls.theta)
            phi = [term(x) / scale for term, scale in self._regressor_plan]
        else:
            phi = ()
        fixed = additive_terms(self._fixed, x, mag) if self._fixed_additive else None
        phys, sens = self._effects_scalar(fixed, phi)
        loss = mag + phys
        if self._load_laws and loss != loss and mag == mag:
            self.counts["load_unbalanced"] += 1
        residual = meas - (loss + sens) if math.isfinite(meas) else math.nan
        if math.isfinite(residual):
            self._adapt_scalar(fixed, phi, meas - mag, s.t_ns)
            self.residual_stats.add(residual)
        self.estimated += 1
        eta_meas = self._measured_efficiency_scalar(t_meas, w, s.out_torque_nm, s.out_speed_rad_s) \
            if math.isfinite(meas) else math.nan
        est = Estimate(s.t_ns, t_meas, w, loss * sg, loss * aw, self.model.efficiency_scalar(t, w, loss), meas,
                       residual, s.out_torque_nm, s.out_speed_rad_s, s.temperature_c, eta_meas, sg)
        self.last = est
        if self.speed_noise.learning and self.speed_noise.add((w,), s.t_ns):
            self._noise_changed()
        return est

    def follow_speed_noise(self, learned: Estimator) -> None:
        """Apply the speed noise ``learned`` learned, at its checkpoints' times (a time slice of a
        recording whose first samples it did not see; :meth:`~.speednoise.SpeedNoise.follow`)."""
        self.speed_noise.follow(learned.speed_noise.learned)

    def _noise_changed(self) -> None:
        """The sign's width and the least measured speed after the speed noise was (re)learned."""
        self.sign_width_rad_s = self.speed_noise.value
        self.min_measured_speed_rad_s = self.speed_noise.min_measured_rad_s
        self.balance_below_rad_s = balance_below(self.model.min_speed_rad_s, self.min_measured_speed_rad_s)
        self._still_rad_s = STATE_STILL_WIDTHS * self.sign_width_rad_s

    @property
    def has_memory(self) -> bool:
        """Whether an accepted effect has a state carried from sample to sample."""
        return bool(self._stateful)

    def _advance(self, t_ns: int, speed: float) -> dict[str, float]:
        """The states of the effects with memory after this sample (one step from the last one, at the
        speed :func:`~.effects.state_speed` makes of the reading: none at rest)."""
        dt = 0.0 if self._state_t_ns is None else (t_ns - self._state_t_ns) * 1e-9
        states = self._states
        w = speed if abs(speed) >= self._still_rad_s else 0.0  # state_speed, inline: once per sample
        for name, step, params in self._steppers:
            states[name] = step(states[name], w, dt, params)
        self._state_t_ns = t_ns
        return states  # read within this sample only (the next one steps it on)


    def solved_load(self, x: EffectInputs, mag, theta) -> EffectInputs:
        """``x`` with the load the laws in it take where no loss is measured: solved with the fixed effects
        and the adaptive ones at the RLS's coefficients ``theta`` (a list; per sample in a batch, arrays),
        :func:`~.effectsum.output_load`."""
        enabled = dict(self._fixed)
        for i, name in enumerate(self.adaptive):
            enabled[name] = dict(self._active[name]) | {EFFECTS[name].coefficient: theta[i] / self._scales[i]}
        return additive_terms(enabled, x, mag).inputs

    def _effects_scalar(self, fixed, phi) -> tuple[float, float]:
        """(physical, sensor) contributions of the additive effects: the ``fixed`` terms as
        configured, the adaptive ones (regressors ``phi``) with the RLS's current coefficients."""
        if not self._additive:
            return 0.0, 0.0
        phys, sens = (fixed.physical_nm, fixed.sensor_nm) if fixed is not None else (0.0, 0.0)
        if self._one_physical:  # the usual case: the loop below for one physical effect
            return phys + self.rls.theta[0] * phi[0], sens
        for is_sensor, th, f in zip(self._sensor, self.rls.theta, phi):
            if is_sensor:
                sens += th * f
            else:
                phys += th * f
        return phys, sens

    def _adapt_scalar(self, fixed, phi, y, t_ns) -> None:
        """RLS on ``y = measured − model − fixed effects``; the detector sees the a-priori error."""
        if fixed is not None:
            y = y - fixed.physical_nm - fixed.sensor_nm
        err = self.rls.update(phi, y) if self.adaptive else y
        self.detector.add(err, t_ns)


def _raise_to(value: float) -> float:
    """A round limit above ``value`` (two significant digits up)."""
    if value <= 0 or not math.isfinite(value):
        return value
    scale = 10.0 ** (math.floor(math.log10(value)) - 1)
    return math.ceil(value / scale * 1.0000001) * scale
