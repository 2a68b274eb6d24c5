"""The estimator's batch path: whole arrays of paired samples estimated at once (:class:`BatchPath`).

Replay feeds it arrays (:meth:`BatchPath.push_many`, :meth:`BatchPath.flush`); the node reaches it where
its samples are aligned by a lag or resampled.  :meth:`BatchPath.process_batch` gives the numbers of the
per-sample :meth:`~.estimator.Estimator.process`, the order-dependent online adaptation included (tested).
:class:`~.estimator.Estimator` is the one class that carries both paths; this module holds the vectorised
half and the batch of estimates it returns (:class:`BatchEstimate`).  No rclpy import.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .adaptation import (
    regressors,
)
from .effects import (
    EFFECTS,
    EffectInputs,
    state_speed,
)
from .effectsum import additive_terms, fr_scale
from .equations import efficiency
from .measured import measured_efficiency
from .model import rotation_sign
from .pairing import CHANNELS, samples_to_arrays
from .lostmarks import lost_mask
from .resample import RESAMPLED_CHANNELS, Message, stale_mask


@dataclass
class BatchEstimate:
    """Estimator output for arrays of samples (replay)."""

    t_ns: np.ndarray
    torque_nm: np.ndarray
    speed_rad_s: np.ndarray
    loss_torque_nm: np.ndarray
    loss_power_w: np.ndarray
    efficiency: np.ndarray
    measured_loss_nm: np.ndarray
    residual_nm: np.ndarray
    temperature_c: np.ndarray | None = None  #: oil temperature (NaN where none)
    breakdown_nm: dict[str, np.ndarray] = field(default_factory=dict)
    effects_nm: np.ndarray | None = None  #: physical effects part of the loss magnitude
    coefficients: dict[str, np.ndarray] = field(default_factory=dict)  #: adapted, per sample
    alarms_t_ns: list[int] = field(default_factory=list)
    loss_magnitude_nm: np.ndarray | None = None  #: |loss| also at standstill, where the signed loss is 0
    out_torque_nm: np.ndarray | None = None  #: measured output torque (NaN where none)
    out_speed_rad_s: np.ndarray | None = None  #: measured output speed (NaN where none)
    efficiency_measured: np.ndarray | None = None  #: per sample (:attr:`Estimate.efficiency_measured`)
    #: the accepted sensor errors' part of the measured loss (the residual is measured − loss − this)
    sensor_nm: np.ndarray | None = None
    #: the measured efficiency over the window published at the start of each sample's second, and its
    #: uncertainty (:mod:`.measured`; filled in by replay's outputs, None from the estimator)
    efficiency_measured_window: np.ndarray | None = None
    efficiency_measured_uncertainty: np.ndarray | None = None
    #: the direction the loss opposes at each sample, as the estimate took it: ``tanh(ω/σ)`` near
    #: standstill, ±1 where a run of readings tells it (:class:`~.speednoise.DirectionRun`)
    sign: np.ndarray | None = None

    def select(self, keep: np.ndarray) -> BatchEstimate:
        """The estimates where ``keep`` (a boolean mask) is true."""
        def pick(a):
            return None if a is None else a[keep]

        t = self.t_ns[keep]
        lo, hi = (int(t[0]), int(t[-1])) if len(t) else (0, -1)
        return BatchEstimate(
            t, self.torque_nm[keep], self.speed_rad_s[keep], self.loss_torque_nm[keep], self.loss_power_w[keep],
            self.efficiency[keep], self.measured_loss_nm[keep], self.residual_nm[keep], pick(self.temperature_c),
            {k: v[keep] for k, v in self.breakdown_nm.items()}, pick(self.effects_nm),
            {k: v[keep] for k, v in self.coefficients.items()}, [a for a in self.alarms_t_ns if lo <= a <= hi],
            pick(self.loss_magnitude_nm), pick(self.out_torque_nm), pick(self.out_speed_rad_s),
            pick(self.efficiency_measured), sensor_nm=pick(self.sensor_nm), sign=pick(self.sign))

def concatenate_estimates(parts: Sequence[BatchEstimate]) -> BatchEstimate:
    """Consecutive batches of estimates as one (the alarms: the last one's list, which holds all)."""
    def cat(arrays):
        return None if any(a is None for a in arrays) else np.concatenate(arrays)

    def cat_dict(dicts):
        keys = dicts[0].keys()
        return {k: np.concatenate([d[k] for d in dicts]) for k in keys if all(k in d for d in dicts)}

    first = parts[0]
    return BatchEstimate(
        *(np.concatenate([getattr(p, f) for p in parts]) for f in ("t_ns", "torque_nm", "speed_rad_s",
                                                                   "loss_torque_nm", "loss_power_w", "efficiency",
                                                                   "measured_loss_nm", "residual_nm")),
        temperature_c=cat([p.temperature_c for p in parts]), breakdown_nm=cat_dict([p.breakdown_nm for p in parts]),
        effects_nm=cat([p.effects_nm for p in parts]), coefficients=cat_dict([p.coefficients for p in parts]),
        alarms_t_ns=list(parts[-1].alarms_t_ns), loss_magnitude_nm=cat([p.loss_magnitude_nm for p in parts]),
        out_torque_nm=cat([p.out_torque_nm for p in parts]), out_speed_rad_s=cat([p.out_speed_rad_s for p in parts]),
        efficiency_measured=cat([p.efficiency_measured for p in parts]), sensor_nm=cat([p.sensor_nm for p in parts]),
        sign=cat([p.sign for p in parts]),
    ) if len(parts) > 1 else first


class BatchPath:
    """The vectorised methods of :class:`~.estimator.Estimator` (its state is the estimator's)."""

    # ------------------------------------------------------------------ batches (replay)
    def push_many(self, codes: np.ndarray, t_ns: np.ndarray, values: np.ndarray,
                  source_ns: np.ndarray | None = None) -> BatchEstimate | None:
        """Feed a batch of messages in arrival (file) order (``codes`` index :data:`~.pairing.CHANNELS`;
        ``source_ns``: the publishers' timestamps, by arrival); returns the estimates of the samples
        they complete (None when they complete none)."""
        if self.resampler.needs(codes):
            codes, t_ns, values, source_ns = self._resample_many(codes, t_ns, values, source_ns)
            if not len(codes):
                return None
        return self._estimate(self._aligned(self.sync.push_many(codes, t_ns, values, source_ns)))

    def flush(self) -> BatchEstimate | None:
        """At the end of a log: estimate what can still be paired (the rest counts as unpaired)."""
        samples = self._push_resampled(self.resampler.flush())
        samples.extend(self.sync.flush())
        return self._estimate(self._aligned(samples_to_arrays(samples), final=True))

    def _resample_many(self, codes, t_ns, values, source_ns):
        """A batch of messages through the resampler (message by message, as the node pushes them):
        the messages for the pairing as arrays."""
        resampler = self.resampler
        sources = source_ns.tolist() if source_ns is not None else [None] * len(codes)
        out: list[Message] = []
        # where each channel the resampler has not seen yet comes first in the batch (its rate to be told)
        first = {c: int(np.argmax(codes == i)) for i, c in enumerate(CHANNELS)
                 if c in RESAMPLED_CHANNELS and resampler.mode[c] is None and np.any(codes == i)}
        k = 0
        for c, t, v, s in zip(codes.tolist(), t_ns.tolist(), values.tolist(), sources):
            out.extend(resampler.push(Message(CHANNELS[c], t, v, s)))
            k += 1
            if resampler.passthrough and not any(resampler.mode[ch] is None and at >= k for ch, at in first.items()):
                break  # told, nothing resampled or waiting: the rest of the batch as it is
        index = {c: i for i, c in enumerate(CHANNELS)}
        head = (np.fromiter((index[m.channel] for m in out), dtype=codes.dtype, count=len(out)),
                np.fromiter((m.t_ns for m in out), dtype=np.int64, count=len(out)),
                np.fromiter((m.value for m in out), dtype=float, count=len(out)))
        codes, t_ns, values = (np.concatenate([a, b[k:]]) for a, b in zip(head, (codes, t_ns, values)))
        if source_ns is not None:
            given = np.fromiter((m.t_ns if m.source_ns is None else m.source_ns for m in out), dtype=np.int64,
                                count=len(out))
            source_ns = np.concatenate([given, source_ns[k:]])
        return codes, t_ns, values, source_ns

    def estimate_paired(self, t_ns: np.ndarray, torque: np.ndarray, speed: np.ndarray, out_torque: np.ndarray,
                        out_speed: np.ndarray, temperature: np.ndarray) -> BatchEstimate | None:
        """The paired samples of a whole recording (in time order, as replay paired them) through the
        lag alignment and the estimate: what replay estimates of them (without the paper's breakdown)."""
        return self._estimate(self._aligned((t_ns, torque, speed, out_torque, out_speed, temperature), final=True),
                              breakdown=False)

    def _advance_many(self, t_ns: np.ndarray, speed: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`_advance` for a batch: the same steps in the same float arithmetic (bit for bit)."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        if not len(t_ns):
            return {name: np.empty(0) for name in self._stateful}
        gaps = np.diff(t_ns, prepend=t_ns[0] if self._state_t_ns is None else np.int64(self._state_t_ns))
        dt = gaps.astype(float) * 1e-9
        w = state_speed(speed, self.sign_width_rad_s)
        out = {}
        for name, params in self._stateful.items():
            out[name] = EFFECTS[name].state_steps(self._states[name], w, dt, params)
            self._states[name] = float(out[name][-1])
        self._state_t_ns = int(t_ns[-1])
        return out

    # ------------------------------------------------------------------ batch (replay)
    def process_batch(self, t_ns: np.ndarray, torque: np.ndarray, speed: np.ndarray,
                      out_torque: np.ndarray | None = None, out_speed: np.ndarray | None = None,
                      temperature: np.ndarray | None = None, *, breakdown: bool = True) -> BatchEstimate:
        """Vectorised :meth:`process` over paired samples (invalid ones are removed and counted).

        Gives the same numbers as calling :meth:`process` sample by sample, including the
        order-dependent online adaptation.
        """
        n = len(t_ns)
        nan = np.full(n, np.nan)
        arrays = self._plausible(
            np.asarray(t_ns), np.asarray(torque, float), np.asarray(speed, float),
            nan if out_torque is None else np.asarray(out_torque, float),
            nan if out_speed is None else np.asarray(out_speed, float),
            nan if temperature is None else np.asarray(temperature, float))
        noise = self.speed_noise
        if not noise.learning and not noise.schedule:
            return self._batch(*arrays, breakdown=breakdown)
        # while the speed noise is learned (or follows another estimator's checkpoints by time): the
        # samples up to each checkpoint with the σ before it, as the scalar path steps (bit for bit)
        parts, rest = [], arrays
        while len(rest[0]) and (noise.learning or noise.schedule):
            if noise.schedule:
                if noise.reach(int(rest[0][0])):
                    self._noise_changed()
                after = noise.next_change_ns()
                k = len(rest[0]) if after is None else int(np.searchsorted(rest[0], after, side="right"))
                k = max(k, 1)
            else:
                k = min(noise.until_checkpoint(), len(rest[0]))
            parts.append(self._batch(*(a[:k] for a in rest), breakdown=breakdown))
            if noise.learning and noise.add(rest[2][:k].tolist(), int(rest[0][k - 1])):
                self._noise_changed()
            rest = tuple(a[k:] for a in rest)
        if len(rest[0]) or not parts:
            parts.append(self._batch(*rest, breakdown=breakdown))
        return parts[0] if len(parts) == 1 else concatenate_estimates(parts)

    def _batch(self, t_ns: np.ndarray, torque_meas: np.ndarray, speed: np.ndarray, out_torque: np.ndarray,
               out_speed: np.ndarray, temperature: np.ndarray, *, breakdown: bool) -> BatchEstimate:
        """:meth:`process_batch` of plausible samples at the speed noise of now."""
        torque = self.corrected_torque(torque_meas)
        at, aw = np.abs(torque), np.abs(speed)
        run = np.zeros(len(speed), np.int64) if self.operating_points \
            else self._run.many(speed, self.sign_width_rad_s, self.speed_noise.known)
        sg = np.where((run != 0) & (aw < self.min_measured_speed_rad_s), run,
                      rotation_sign(speed, torque, self.sign_width_rad_s))
        res = self._model_result(torque, speed, sg, temperature, breakdown=breakdown, count=True)
        mag = res.loss_magnitude_nm
        bad_out = ~np.isnan(out_torque) & (~np.isfinite(out_torque) | (~np.isfinite(out_speed) & ~np.isnan(out_speed)))
        self.counts["output_non_finite"] += int(np.count_nonzero(bad_out))
        with np.errstate(invalid="ignore"):
            previous = np.concatenate([[self._previous_speed], speed[:-1]])
            meas = np.where(bad_out, np.nan, self.measured_loss(torque_meas, speed, out_torque, out_speed, previous,
                                                                run))
        if len(speed):
            self._previous_speed = float(speed[-1])
        state = self._advance_many(t_ns, speed) if self._stateful else {}
        x = EffectInputs(at, aw, torque, sg, temperature, state=state)
        phys, sens, coefficients = self._effects_batch(x, meas, mag, t_ns, torque_meas)
        loss = mag + phys
        if self._load_laws:
            self.counts["load_unbalanced"] += int(np.count_nonzero(np.isnan(loss) & ~np.isnan(mag)))
        residual = meas - (loss + sens)
        eff = efficiency(torque, speed, loss, self.model.min_torque_nm, self.model.min_speed_rad_s)
        eff_meas = np.where(np.isfinite(meas),
                            measured_efficiency(torque_meas, speed, out_torque, out_speed, self.ratio,
                                                                   self.model.min_torque_nm,
                                                                   self.model.min_speed_rad_s), np.nan)
        self.estimated += len(t_ns)
        return BatchEstimate(
            t_ns=t_ns,
            torque_nm=torque_meas,
            speed_rad_s=speed,
            loss_torque_nm=loss * sg,
            loss_power_w=loss * aw,
            efficiency=eff,
            measured_loss_nm=meas,
            residual_nm=residual,
            temperature_c=temperature,
            breakdown_nm=res.breakdown_nm,
            effects_nm=phys,
            coefficients=coefficients,
            alarms_t_ns=list(self.detector.alarm_times_ns),
            loss_magnitude_nm=loss,
            out_torque_nm=out_torque,
            out_speed_rad_s=out_speed,
            efficiency_measured=eff_meas,
            sensor_nm=sens,
            sign=sg,
        )

    def _model_result(self, torque: np.ndarray, speed: np.ndarray, sg: np.ndarray, temperature: np.ndarray, *,
                      breakdown: bool, count: bool = False):
        """The paper's model at (corrected) ``torque`` and ``speed``, its Fr part scaled by the
        Fr-scaling effects at ``temperature`` (``count``: samples without one counted as skipped
        ``temperature_missing``; they are evaluated unscaled)."""
        vscale = None
        if self._fr_scaling:
            have_t = np.isfinite(temperature) if self._needs_temperature else np.ones(len(torque), bool)
            if count:
                self.counts["temperature_missing"] += int(np.count_nonzero(~have_t))
            x = EffectInputs(np.abs(torque), np.abs(speed), torque, sg, np.where(have_t, temperature, 0.0))
            vscale = np.where(have_t, fr_scale(self._active, x), 1.0)
        return self.model.evaluate(torque, speed, vscale, breakdown=breakdown)

    def breakdown(self, torque_nm: np.ndarray, speed_rad_s: np.ndarray, temperature_c: np.ndarray,
                  loss_torque_nm: np.ndarray, sign: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The loss's parts at samples already estimated (the node's rerun view, off its input path):
        the paper's terms (as :meth:`process_batch` gives them) and the effects' share of the loss
        magnitude, from the measured torque, the speed, the oil temperature, the signed loss and the
        direction the estimate took (:attr:`Estimate.sign`)."""
        torque = self.corrected_torque(np.asarray(torque_nm, float))
        speed = np.asarray(speed_rad_s, float)
        sg = np.asarray(sign, float)
        res = self._model_result(torque, speed, sg, np.asarray(temperature_c, float), breakdown=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            effects = np.where(sg != 0, np.asarray(loss_torque_nm, float) / sg - res.loss_magnitude_nm, 0.0)
        return res.breakdown_nm, effects

    def _plausible(self, t_ns: np.ndarray, torque: np.ndarray, speed: np.ndarray,
                   *others: np.ndarray) -> tuple[np.ndarray, ...]:
        """The samples with finite, plausible drive torque and speed (the rest counted by reason):
        ``t_ns``, ``torque``, ``speed`` and each of ``others`` at those samples."""
        est = self.config.estimator
        finite = np.isfinite(torque) & np.isfinite(speed)
        with np.errstate(invalid="ignore"):
            plausible = est.plausible(torque, speed)
        if not finite.all():
            lost = lost_mask(torque) | lost_mask(speed)
            stale = stale_mask(speed) & ~lost
            self.counts["lost"] += int(np.count_nonzero(lost))
            self.counts["stale"] += int(np.count_nonzero(stale))
            self.counts["non_finite"] += int(np.count_nonzero(~finite & ~lost & ~stale))
        self.counts["implausible"] += int(np.count_nonzero(finite & ~plausible))
        if not plausible.all():
            for name, x, limit in (("speed", speed, est.max_abs_speed_rad_s),
                                   ("torque", torque, est.max_abs_torque_nm)):
                over = finite & (np.abs(x) > limit)
                if over.any():
                    seen = self.beyond[name]
                    seen[0] += int(np.count_nonzero(over))
                    seen[1] = max(seen[1], float(np.max(np.abs(x[over]))))
        keep = finite & plausible
        return tuple(a[keep] for a in (t_ns, torque, speed, *others))

    def _effects_batch(self, x: EffectInputs, meas: np.ndarray, mag: np.ndarray, t_ns: np.ndarray,
                       torque_meas: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """The effects' (physical, sensor) contributions of a batch and the adapted coefficients of
        each sample: the adaptive effects by RLS sample by sample, the rest as configured (their
        residual fed to the change detector).  With adaptation the laws in the load take the measured
        load where a loss is measured (what the RLS learns from), else the one solved at the a-priori
        coefficients (:meth:`~.estimator.Estimator.solved_load`), as :meth:`process` does."""
        coefficients: dict[str, np.ndarray] = {}
        if self.adaptive:
            if self._load_laws:
                with np.errstate(invalid="ignore"):
                    x = x._replace(abs_load=np.abs(torque_meas - x.rot_sign * meas))
            phys = np.zeros(len(mag))
            sens = np.zeros(len(mag))
            fixed = additive_terms(self._fixed, x, mag) if self._fixed_additive else None
            if fixed is not None:
                phys, sens = phys + fixed.physical_nm, sens + fixed.sensor_nm
            phis = regressors(self._regressor_plan, x)
            theta_hist = self._adapt_batch(phis, meas - mag - phys - sens, t_ns)
            unmeasured = ~np.isfinite(meas)
            if self._load_laws and unmeasured.any():
                solved = self.solved_load(x._replace(abs_load=None), mag,
                                          [theta_hist[:, i] for i in range(len(self.adaptive))])
                x = x._replace(abs_load=np.where(unmeasured, solved.abs_load, x.abs_load))
                phys, sens = np.zeros(len(mag)), np.zeros(len(mag))
                if self._fixed_additive:
                    fixed = additive_terms(self._fixed, x, mag)
                    phys, sens = phys + fixed.physical_nm, sens + fixed.sensor_nm
                phis = regressors(self._regressor_plan, x)
            for i, (name, phi) in enumerate(zip(self.adaptive, phis)):
                contrib = theta_hist[:, i] * phi
                if self._sensor[i]:
                    sens += contrib
                else:
                    phys += contrib
                coefficients[name] = theta_hist[:, i] / self._scales[i]
            return phys, sens, coefficients
        terms = additive_terms(self._active, x, mag)
        phys, sens = np.asarray(terms.physical_nm) + 0.0 * mag, np.asarray(terms.sensor_nm) + 0.0 * mag
        y = meas - mag - phys - sens
        ok = np.isfinite(y)
        self.detector.add_many(y[ok], t_ns[ok])
        self.residual_stats.add_many(y[ok])
        return phys, sens, coefficients

    def _adapt_batch(self, phis: list[np.ndarray], y: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
        """Run RLS sample by sample (it is order dependent); returns the a-priori θ of each sample."""
        n = len(y)
        hist = np.empty((n, len(phis)))
        rows = np.stack(phis, axis=1).tolist() if n else []
        ys = y.tolist()
        ts = t_ns.tolist()
        rls, det, stats = self.rls, self.detector, self.residual_stats
        for i in range(n):
            hist[i] = rls.theta
            yi = ys[i]
            if yi == yi:  # not NaN
                err = rls.update(rows[i], yi)
                det.add(err, ts[i])
                stats.add(err)
        return hist
