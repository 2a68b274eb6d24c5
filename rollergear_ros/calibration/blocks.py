"""Block means of the residual and of every candidate effect's column (steps 2-3 of :mod:`.calibrate`).

Samples are averaged over short blocks (never across a bag, a sign change of ω or T, or a gap);
blocks are weighted by the inverse variance of their mean and grouped into dwells, which the
cross-validation folds never split.  The candidate columns come from the effect registry
(:mod:`core.effects`).  No rclpy import.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..core.effects import EFFECTS, EffectInputs
from ..core.modelparams import MODEL_PARAMETERS, fitted_parameters
from ..core.model import rotation_sign
from .samples import SampleData

#: an effect that needs the oil temperature is testable when it varies by at least this much
MIN_TEMPERATURE_SPAN_C = 3.0
#: an effect of speeds near standstill (:attr:`~core.effects.Effect.needs_speeds_below`) is testable when
#: at least this share of the samples run that slow
MIN_SLOW_SHARE = 0.01


def _reverses(speed: np.ndarray, bag_id: np.ndarray, clear_rad_s: float) -> bool:
    """Whether the drive turns round within a recording: two samples in a row among those clearly
    moving (``|ω| >= clear_rad_s``, beyond the reading's noise) in opposite directions."""
    moving = np.abs(speed) >= max(clear_rad_s, 1e-12)
    s, b = np.sign(speed[moving]), bag_id[moving]
    return bool(np.any((s[1:] != s[:-1]) & (b[1:] == b[:-1])))


def groups() -> tuple[str, ...]:
    """The candidate groups: every effect of the registry, in its order, then the model's own
    parameters (:mod:`core.modelparams`, one per part of the model)."""
    return tuple(EFFECTS) + fitted_parameters()


class _DirectionRuns(NamedTuple):
    """The samples cut into runs of one direction of motion, per recording: what a state that relaxes
    over the angle turned needs, whatever its relaxation angle."""

    run: np.ndarray  #: per sample: its run
    since: np.ndarray  #: per sample: the angle turned since its run began, its own step included [rad]
    settled: np.ndarray  #: per sample: its run's direction (±1; 0 before any motion): the settled state
    sign: np.ndarray  #: per run: its direction
    whole: np.ndarray  #: per run: the angle turned in it [rad]
    opens: np.ndarray  #: per run: whether it opens a recording (its state starts at 0)
    block: np.ndarray  #: per sample: its block


@dataclass
class Blocks:
    """Block means of the residual and of every candidate column, with weights and dwell groups."""

    start: np.ndarray  # first sample index of each block
    count: np.ndarray
    y: np.ndarray  # mean residual
    measured: np.ndarray  # mean measured loss
    speed: np.ndarray
    torque: np.ndarray
    temperature: np.ndarray
    weight: np.ndarray  # inverse variance of the block mean
    dwell: np.ndarray
    fold: np.ndarray
    columns: dict[str, np.ndarray]  # nuisance columns dtdt, dwdt; effects without a member, by name
    grids: dict[str, np.ndarray]  # effect with a member -> (len(member_grid), n_blocks) columns
    inflation: float
    block_s: float
    x: EffectInputs | None = None  # per-sample inputs of the effects' terms
    testable: tuple[str, ...] = ()  # effects this data can test (a varying temperature where needed)
    steady_state: bool = False  # rows of steady-state tables: a block and a dwell each, equal weights
    t_s: np.ndarray | None = None  # per-sample time [s], recording and signed speed: effects with memory
    bag_id: np.ndarray | None = None
    sample_speed: np.ndarray | None = None
    sign_width_rad_s: float = 0.0  # the smooth sign's width: 3 of it beyond standstill the direction is known
    _distinct: tuple | None = field(default=None, repr=False)  # distinct temperatures, inverse index
    _runs: _DirectionRuns | None = field(default=None, repr=False)  # runs of one direction (memory), once
    _speed_order: tuple | None = field(default=None, repr=False)  # samples by |ω| (laws that fade with speed)
    _columns: dict = field(default_factory=dict, repr=False)  # (effect, member, second) -> block means, computed once

    def mean(self, values: np.ndarray) -> np.ndarray:
        return np.add.reduceat(np.broadcast_to(values, self.x.abs_speed.shape), self.start) / self.count

    def column(self, name: str, member: float | None = None, second: float | None = None,
               law: tuple[float, float, float] | None = None) -> np.ndarray:
        """Block means of an effect's regressor (coefficient 1), at any member (not only the grid's),
        with ``law`` (Vogel B, C, θ_ref) for an effect that follows the oil; a sample without an
        input the effect needs (a missing temperature) contributes 0.  Each (effect, member, law) is
        computed once: the selection asks for the same ones at every step."""
        key = (name, member, second, law)
        cached = self._columns.get(key)
        if cached is not None:
            return cached
        if name in MODEL_PARAMETERS:  # a part of the model (its relative change is the coefficient)
            return self.columns[name]
        effect = EFFECTS[name]
        params = effect.defaults() | (dict(zip(("B", "C", "theta_ref"), law)) if law is not None else {})
        if effect.scales_fr:
            # a relative change of Fr that depends on the oil temperature alone: evaluated once per
            # distinct temperature (held between its messages: ~1 in 20 samples), then times T_Fr
            if self._distinct is None:
                self._distinct = np.unique(self.x.temperature_c, return_inverse=True)
            theta, inverse = self._distinct
            relative = effect.column(self.x._replace(temperature_c=theta, fr_part_nm=1.0), params, member, second)
            values = self.x.fr_part_nm * relative[inverse]
        elif effect.relaxes_over is not None:  # memory, in closed form where it has not settled
            at = params | ({effect.member: member} if effect.member and member is not None else {})
            cached = self._columns[key] = self._relaxing_means(name, at, member, second)
            cached.flags.writeable = False
            return cached
        elif effect.vanishes_above is not None:  # a law that fades with speed: only the slower samples
            at = params | ({effect.member: member} if effect.member and member is not None else {}) \
                | ({effect.second_member: second} if effect.second_member and second is not None else {})
            by_speed, block = self._by_speed()
            k = int(np.searchsorted(by_speed.abs_speed, effect.vanishes_above(at), side="right"))
            x = EffectInputs(*(v[:k] if isinstance(v, np.ndarray) and v.shape == block.shape else v
                               for v in by_speed))  # views: the slower samples come first
            values = effect.column(x, params, member, second)
            if effect.needs_temperature:
                values = np.where(np.isnan(values), 0.0, values)
            cached = self._columns[key] = np.bincount(block[:k], weights=values,
                                                      minlength=len(self.count)) / self.count
            cached.flags.writeable = False
            return cached
        elif effect.state_step is not None:  # memory: its state replayed over each recording in time order
            values = effect.column(self.x._replace(state={name: self.states(name, params | (
                {effect.member: member} if effect.member and member is not None else {}))}), params, member, second)
        else:
            values = effect.column(self.x, params, member, second)
        if effect.needs_temperature:
            values = np.where(np.isnan(values), 0.0, values)
        cached = self._columns[key] = self.mean(values)
        cached.flags.writeable = False  # shared by every caller
        return cached

    def _steps(self):
        """Per recording: its samples' indices and time steps.  The analysis has only the samples with
        a measured loss: across the others (near standstill, a dwell at rest) a step counts one sample
        period, not the gap -- the motion there is next to none, and the gap at the next sample's
        speed would turn the drive by far too much."""
        for b in np.unique(self.bag_id):
            idx = np.flatnonzero(self.bag_id == b)
            dt = np.diff(self.t_s[idx], prepend=self.t_s[idx][:1])
            period = float(np.median(dt[1:])) if len(dt) > 1 else 0.0
            yield idx, np.minimum(dt, 2.0 * period)

    def states(self, name: str, params: dict) -> np.ndarray:
        """The state of an effect with memory at every sample, each recording from a state of 0."""
        effect = EFFECTS[name]
        if effect.relaxes_over is not None:
            runs = self._direction_runs()
            z = runs.settled.copy()
            moving, decay, z_start = self._transients(runs, params[effect.relaxes_over])
            z[moving] += (z_start - runs.sign)[runs.run[moving]] * decay
            return z
        z = np.empty(len(self.t_s))
        for idx, dt in self._steps():
            z[idx] = effect.state_steps(0.0, self.sample_speed[idx], dt, params)
        return z

    def _by_speed(self) -> tuple[EffectInputs, np.ndarray]:
        """The effects' inputs with the samples in the order of their |ω|, and each one's block
        (computed once)."""
        if self._speed_order is None:
            order = np.argsort(self.x.abs_speed, kind="stable")
            n = len(order)
            x = EffectInputs(*(v[order] if isinstance(v, np.ndarray) and v.shape == (n,) else v for v in self.x[:6]))
            self._speed_order = (x, np.repeat(np.arange(len(self.count)), self.count)[order])
        return self._speed_order

    def _direction_runs(self) -> _DirectionRuns:
        """The recordings cut into runs of one direction (computed once, see :class:`_DirectionRuns`)."""
        if self._runs is None:
            n = len(self.t_s)
            run, since, settled = np.empty(n, dtype=np.int64), np.empty(n), np.empty(n)
            sign, whole, opens = [], [], []
            for idx, dt in self._steps():
                w = self.sample_speed[idx]
                s = np.sign(w)
                # standstill continues a run; before any motion the direction is 0 (the state stays)
                last = np.maximum.accumulate(np.where(s != 0, np.arange(len(w)), -1))
                held = np.where(last >= 0, s[np.maximum(last, 0)], 0.0)
                opening = np.r_[True, held[1:] != held[:-1]]
                starts = np.flatnonzero(opening)
                local = np.cumsum(opening) - 1
                turned = np.cumsum(np.abs(w) * dt)  # the first sample's step is 0
                before = np.where(starts > 0, turned[np.maximum(starts - 1, 0)], 0.0)
                ends = np.r_[starts[1:], len(w)] - 1
                run[idx] = len(sign) + local
                since[idx] = turned - before[local]
                settled[idx] = held
                sign += held[starts].tolist()
                whole += (turned[ends] - before).tolist()
                opens += [True] + [False] * (len(starts) - 1)
            self._runs = _DirectionRuns(run, since, settled, np.array(sign), np.array(whole), np.array(opens),
                                        np.repeat(np.arange(len(self.count)), self.count))
        return self._runs

    @staticmethod
    def _transients(runs: _DirectionRuns, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where a state relaxing over ``scale`` radians has not settled (``exp(−Δφ/scale)`` ≥ e^-40,
        beyond that it is the direction to the last bit): those samples, their decay, and the state
        each run starts from (0 at a recording's start, else where the run before it ended)."""
        moving = np.flatnonzero((runs.since < 40.0 * scale) & (runs.settled != 0))
        decay = np.exp(-runs.since[moving] / scale)
        run_decay = np.exp(-runs.whole / scale).tolist()
        z_start, z = np.empty(len(runs.sign)), 0.0
        for r, (s, opens, d) in enumerate(zip(runs.sign.tolist(), runs.opens.tolist(), run_decay)):
            z = 0.0 if opens else z
            z_start[r] = z
            if s != 0:
                z = s + (z - s) * d
        return moving, decay, z_start

    def _relaxing_means(self, name: str, params: dict, member, second) -> np.ndarray:
        """Block means of the column of an effect whose state relaxes over the angle turned: its
        settled value's column (once), plus the difference where the state has not settled."""
        effect = EFFECTS[name]
        runs = self._direction_runs()
        base_key = (name, "settled")
        base = self._columns.get(base_key)
        if base is None:
            base = self._columns[base_key] = self.mean(
                effect.column(self.x._replace(state={name: runs.settled}), params, member, second))
        moving, decay, z_start = self._transients(runs, params[effect.relaxes_over])
        if not len(moving):
            return base.copy()
        x = EffectInputs(*(v[moving] if isinstance(v, np.ndarray) and v.shape == runs.since.shape else v
                           for v in self.x[:6]))
        settled = runs.settled[moving]
        z = settled + (z_start - runs.sign)[runs.run[moving]] * decay
        change = (effect.column(x._replace(state={name: z}), params, member, second)
                  - effect.column(x._replace(state={name: settled}), params, member, second))
        return base + np.bincount(runs.block[moving], weights=change, minlength=len(self.count)) / self.count

    def angle_since_reversal(self, clear_rad_s: float) -> np.ndarray:
        """The angle [rad] turned since the drive last turned round, at every sample (NaN before a
        recording's first reversal); a reversal as :func:`_reverses` counts one (beyond the noise)."""
        phi = np.full(len(self.t_s), np.nan)
        for idx, dt in self._steps():
            w = self.sample_speed[idx]
            turned = np.cumsum(np.abs(w) * dt)
            moving = np.flatnonzero(np.abs(w) >= max(clear_rad_s, 1e-12))
            flips = moving[1:][np.sign(w[moving[1:]]) != np.sign(w[moving[:-1]])]
            if not len(flips):
                continue
            # the last reversal at or before each sample: the angle turned since the sample before it
            last = np.searchsorted(flips, np.arange(len(w)), side="right") - 1
            since = last >= 0
            base = turned[np.maximum(flips[np.maximum(last, 0)] - 1, 0)]
            phi[idx[since]] = (turned - base)[since]
        return phi


def make_blocks(d: SampleData, block_s: float = 0.25, folds: int = 5, like: Blocks | None = None) -> Blocks:
    """Average samples into blocks (see the module docstring) and compute every candidate column.

    ``like``: reuse another block set's boundaries, dwells and folds (same samples, corrected values).
    Steady-state rows (``d.steady_state``) are dwell means already: each is a block and a dwell of
    its own, weighted equally (a table says nothing about its noise), folds every ``folds``-th row;
    sensor errors are not candidates there (a table holds losses, not a torque sensor's readings).
    """
    t = d.t_ns.astype(np.float64) * 1e-9
    sg = rotation_sign(d.speed, d.torque, d.sign_width_rad_s)
    start, count, brk = _block_starts(d, t, block_s, like)

    def mean(x: np.ndarray) -> np.ndarray:
        return np.add.reduceat(x, start) / count

    ym = mean(d.residual)
    dtdt, dwdt = _time_derivatives(d, t)
    weight, inflation = _block_weights(d, ym, start, count, brk)
    aw, at = np.abs(d.speed), np.abs(d.torque)
    spd, trq = mean(d.speed), mean(d.torque)
    temp = mean(np.nan_to_num(d.temperature, nan=np.nan))
    dwell, fold = _dwells(d, spd, trq, start, block_s, folds)
    if like is not None:
        dwell, fold = like.dwell, like.fold
    theta = d.temperature
    testable = _testable_effects(d)
    columns = {"dtdt": mean(dtdt * sg), "dwdt": mean(dwdt * sg)}
    x = EffectInputs(at, aw, d.torque, sg, theta, d.fr_part)
    blocks = Blocks(
        start,
        count,
        ym,
        mean(d.measured_loss),
        spd,
        trq,
        temp,
        weight,
        dwell,
        fold,
        columns,
        {},
        inflation,
        block_s,
        x,
        testable,
        d.steady_state,
        t_s=t,
        bag_id=d.bag_id,
        sample_speed=d.speed,
        sign_width_rad_s=d.sign_width_rad_s,
    )
    _add_columns(blocks, d, mean)
    return blocks


def _testable_effects(d: SampleData) -> tuple[str, ...]:
    """The effects this data can show: those needing a varying oil temperature only when it
    varies, sensor errors not in a table, low-speed ones with enough slow samples, load-dependent
    ones not in a spin test, effects with memory only where the speed reverses."""
    theta = d.temperature
    have_theta = np.isfinite(theta)
    varies = (
        bool(have_theta.mean() > 0.9 and np.nanmax(theta) - np.nanmin(theta) >= MIN_TEMPERATURE_SPAN_C)
        if have_theta.any()
        else False
    )
    # memory shows only at reversals within a recording, and not in a table's dwell means
    reverses = not d.steady_state and _reverses(d.speed, d.bag_id, 3.0 * d.sign_width_rad_s)
    return tuple(n for n, e in EFFECTS.items()
                 if (varies or not e.needs_temperature) and (e.physical or not d.steady_state)
                 and (e.needs_speeds_below is None
                      or np.mean(np.abs(d.speed) <= e.needs_speeds_below) >= MIN_SLOW_SHARE)
                 and not (d.spin_test and e.depends_on_load) and (e.state_step is None or reverses))


def _add_columns(blocks: Blocks, d: SampleData, mean) -> None:
    """Each testable effect's block column (or grid of columns over its member), and the model's
    own parameters' columns: the part each scales, where the model has it (not switched off, not 0
    as the ball friction without a ball force)."""
    for name in blocks.testable:
        effect = EFFECTS[name]
        if effect.oil_law:  # its columns need the oil's law: computed when the selection knows it
            continue
        if effect.member is None:
            blocks.columns[name] = blocks.column(name)
        else:
            blocks.grids[name] = np.stack([blocks.column(name, m) for m in effect.member_grid])
    for key in fitted_parameters():
        part = d.parts.get(MODEL_PARAMETERS[key].part)
        if part is not None and np.any(part != 0) and not d.spin_test:  # every part depends on the load
            blocks.columns[key] = mean(part)
            blocks.testable += (key,)


def _block_starts(d: SampleData, t: np.ndarray, block_s: float,
                  like: Blocks | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each block starts, its sample count, and the samples that start one (a new time slot,
    recording or sign of speed or torque, a gap; ``like``'s boundaries when given)."""
    n = len(t)
    dt = np.diff(t)
    typical = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1e-3
    brk = np.ones(n, bool)
    if n > 1:
        tb = np.floor((t - t[0]) / block_s)
        brk[1:] = (
            (tb[1:] != tb[:-1])
            | (d.bag_id[1:] != d.bag_id[:-1])
            | (np.sign(d.speed[1:]) != np.sign(d.speed[:-1]))
            | (np.sign(d.torque[1:]) != np.sign(d.torque[:-1]))
            | (dt > 5 * typical)
            | (dt < 0)
        )
    start = np.flatnonzero(brk) if like is None else like.start
    count = np.diff(np.append(start, n))
    if like is not None:
        brk = np.zeros(n, bool)
        brk[start] = True
    return start, count, brk


def _time_derivatives(d: SampleData, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """dT/dt and dω/dt within each recording (np.gradient over time; none for a table's rows)."""
    n = len(t)
    dtdt = np.zeros(n)
    dwdt = np.zeros(n)
    for b in np.unique(d.bag_id) if not d.steady_state else ():  # a table's rows have no time derivatives
        idx = np.flatnonzero(d.bag_id == b)
        if len(idx) > 2:
            tt = t[idx] + 1e-12 * np.arange(len(idx))
            dtdt[idx] = np.gradient(d.torque[idx], tt)
            dwdt[idx] = np.gradient(d.speed[idx], tt)
    return dtdt, dwdt


def _block_weights(d: SampleData, ym: np.ndarray, start: np.ndarray, count: np.ndarray,
                   brk: np.ndarray) -> tuple[np.ndarray, float]:
    """Each block mean's weight (1 / its noise variance: the within-block variance, inflated for the
    residual's autocorrelation) and the inflation; equal weights for a table's rows."""
    y = d.residual
    dev = y - np.repeat(ym, count)
    var_within = np.add.reduceat(dev * dev, start) / np.maximum(count - 1, 1)
    same_block = ~brk[1:]
    if same_block.sum() > 10:
        a, b_ = dev[:-1][same_block], dev[1:][same_block]
        rho = float(np.dot(a, b_) / max(np.sqrt(np.dot(a, a) * np.dot(b_, b_)), 1e-300))
    else:
        rho = 0.0
    rho = min(max(rho, 0.0), 0.98)
    inflation = (1 + rho) / (1 - rho)
    var_mean = var_within * inflation / count
    floor = max(float(np.median(var_mean[count > 1])) * 0.05 if np.any(count > 1) else 1e-12, 1e-16)
    var_mean = np.where(count > 1, np.maximum(var_mean, floor), float(np.max(var_mean)) if len(var_mean) else 1.0)
    if d.steady_state:
        return np.ones(len(start)), 1.0
    return 1.0 / var_mean, inflation


def _dwells(d: SampleData, spd: np.ndarray, trq: np.ndarray, start: np.ndarray, block_s: float,
            folds: int) -> tuple[np.ndarray, np.ndarray]:
    """Dwells (consecutive blocks at the same operating point, <= 5 s; each row of a table) and the
    folds, by dwell."""
    nb = len(start)
    dwell = np.zeros(nb, dtype=np.int64)
    max_blocks = max(int(round(5.0 / block_s)), 1)
    cur, run = 0, 0
    for i in range(1, nb):
        same = (
            abs(spd[i] - spd[i - 1]) <= 0.03 * abs(spd[i - 1]) + 1.0
            and abs(trq[i] - trq[i - 1]) <= 0.03 * abs(trq[i - 1]) + 0.5
            and d.bag_id[start[i]] == d.bag_id[start[i - 1]]
        )
        run += 1
        if not same or run >= max_blocks:
            cur += 1
            run = 0
        dwell[i] = cur
    if d.steady_state:
        dwell = np.arange(nb, dtype=np.int64)
    return dwell, dwell % folds
