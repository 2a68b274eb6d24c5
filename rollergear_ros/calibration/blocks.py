"""Block means of the residual and of every candidate effect's column (steps 2-3 of :mod:`.calibrate`).

Samples are averaged over short blocks (never across a bag, a sign change of ω or T, or a gap);
blocks are weighted by the inverse variance of their mean and grouped into dwells, which the
cross-validation folds never split (:mod:`.grouping`).  The candidate columns come from the effect registry
(:mod:`core.effects`).  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..core.effects import EFFECTS, EffectInputs, state_speed
from ..core.floatops import shared_powers
from ..core.modelparams import MODEL_PARAMETERS, fitted_parameters
from ..core.model import rotation_sign
from .noise import Repeatability, difference_variance, reading_noise, repeatability
from .nuisance import nuisance_columns
from .grouping import OperatingGroups, cells, dwells, operating_groups
from .samples import SampleData

#: an effect that needs the oil temperature is testable when it varies by at least this much
MIN_TEMPERATURE_SPAN_C = 3.0
#: an effect of speeds near standstill (:attr:`~core.effects.Effect.needs_speeds_below`) is testable when
#: at least this share of the samples run that slow
MIN_SLOW_SHARE = 0.01
#: one load: the output torque's 5-95 % spread within this share of its median magnitude
ONE_LOAD_SPREAD = 0.1


def _reverses(speed: np.ndarray, bag_id: np.ndarray, clear_rad_s: float) -> bool:
    """Whether the drive turns round within a recording: two samples in a row among those clearly
    moving (``|ω| >= clear_rad_s``, beyond the reading's noise) in opposite directions."""
    moving = np.abs(speed) >= max(clear_rad_s, 1e-12)
    s, b = np.sign(speed[moving]), bag_id[moving]
    return bool(np.any((s[1:] != s[:-1]) & (b[1:] == b[:-1])))


def _rows(x: EffectInputs, pick: np.ndarray) -> EffectInputs:
    """The effects' inputs ``x`` at the samples ``pick`` (an index array): each per-sample array indexed,
    a value shared by all samples kept, no state."""
    n = x.abs_speed.shape
    return EffectInputs(*(v[pick] if isinstance(v, np.ndarray) and v.shape == n else v
                          for v in x._replace(state={})))


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
    columns: dict[str, np.ndarray]  # effects without a member and model parameters, by name
    grids: dict[str, np.ndarray]  # effect with a member -> (len(member_grid), n_blocks) columns
    inflation: float
    block_s: float
    x: EffectInputs | None = None  # per-sample inputs of the effects' terms
    testable: tuple[str, ...] = ()  # effects this data can test (a varying temperature where needed)
    steady_state: bool = False  # rows of steady-state tables: a block and a dwell each, equal weights
    t_s: np.ndarray | None = None  # per-sample time [s], recording and signed speed: effects with memory
    bag_id: np.ndarray | None = None
    sample_speed: np.ndarray | None = None
    #: each recording's every estimated sample (time [ns], speed) and each analysed sample's index in
    #: it: what an effect's memory steps over, as the estimator steps it (None: the analysed ones only)
    streams: list[tuple[np.ndarray, np.ndarray]] | None = None
    source_index: np.ndarray | None = None
    sign_width_rad_s: float = 0.0  # the smooth sign's width: 3 of it beyond standstill the direction is known
    repeat: Repeatability | None = None  # the scatter of a block mean at one operating point (δ)
    #: each block's operating point across recordings (:func:`~.grouping.operating_groups`): where two
    #: stretches can be compared
    place: np.ndarray | None = None
    #: the operating points held out together, the folds, the runs' steadiness (:mod:`.grouping`)
    groups: OperatingGroups | None = None
    full_count: float = 1.0  # samples in a whole block (a transient's parts hold fewer)
    load: np.ndarray | None = None  # mean output-side load referred to the input [N·m] (what laws in the load take)
    untestable: dict[str, str] = field(default_factory=dict)  # candidate -> why this data cannot test it
    load_rule: str = ""  # why a law in the load cannot be tested here ('' where it can: :func:`load_rule`)
    #: the rig's nuisances' columns (:mod:`.nuisance`: a channel's lag, the inertia), always in the fit --
    #: where a run holds a transient (:attr:`~.grouping.OperatingGroups.transients`), else none
    nuisance: dict[str, np.ndarray] = field(default_factory=dict)
    _distinct: tuple | None = field(default=None, repr=False)  # distinct temperatures, inverse index
    _runs: _DirectionRuns | None = field(default=None, repr=False)  # runs of one direction (memory), once
    _speed_order: tuple | None = field(default=None, repr=False)  # samples by |ω| (laws that fade with speed)
    _columns: dict = field(default_factory=dict, repr=False)  # (effect, member, second) -> block means, computed once
    _thin: tuple | None = field(default=None, repr=False)  # the search's samples (:meth:`search_column`)

    def mean(self, values: np.ndarray) -> np.ndarray:
        return np.add.reduceat(np.broadcast_to(values, self.x.abs_speed.shape), self.start) / self.count

    def search_column(self, name: str, member: float | None = None, second: float | None = None,
                      law: tuple[float, float, float] | None = None) -> np.ndarray:
        """:meth:`column` as a search for the best exponent evaluates it, member after member: block
        means over at most :data:`SEARCH_SAMPLES` samples of each block, evenly spread (within a block
        the operating point barely moves: its mean of a law differs from the whole block's by far less
        than the noise); the exact column where the law needs all samples (a memory, a law of the
        slowest samples, the oil's) or a block holds few."""
        effect = EFFECTS.get(name)
        if effect is None or effect.scales_fr or effect.relaxes_over is not None or effect.state_step is not None \
                or effect.vanishes_above is not None or self.x is None:
            return self.column(name, member, second, law)
        if self._thin is None:
            self._thin = _thinned(self)
        idx, block, count = self._thin
        if idx is None:  # every block holds few samples already
            return self.column(name, member, second, law)
        key = ("search", name, member, second, law)
        cached = self._columns.get(key)
        if cached is not None:
            return cached
        params = effect.defaults() | (dict(zip(("B", "C", "theta_ref"), law)) if law is not None else {})
        x = _rows(self.x, idx)
        values = effect.column(x, params, member, second)
        if effect.needs_temperature:
            values = np.where(np.isnan(values), 0.0, values)
        cached = self._columns[key] = np.bincount(block, weights=values, minlength=len(self.count)) / count
        cached.flags.writeable = False
        return cached

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
        """Per recording: its analysed samples' indices ``idx``, and the stream the memory steps over:
        speeds (:func:`~core.effects.state_speed`: none at rest), time steps [s] and the position of
        each of ``idx`` in it.  The stream is the recording's every estimated sample (:attr:`streams`):
        those near standstill that the analysis leaves out turn the drive too, and the estimator steps
        its state over each one.  Without it (rows of
        tables, samples of another source) the analysed samples themselves: across the others a step
        counts one sample period, not the gap (the motion there is next to none, and the gap at the
        next sample's speed would turn the drive by far too much)."""
        for b in np.unique(self.bag_id):
            idx = np.flatnonzero(self.bag_id == b)
            if self.streams is not None and self.source_index is not None:
                t_ns, w = self.streams[int(b)]
                t_ns = np.asarray(t_ns, dtype=np.int64)
                # the estimator's steps: the gaps in integer ns, then seconds (core.estimator._advance_many)
                dt = np.diff(t_ns, prepend=t_ns[:1]).astype(float) * 1e-9
                yield idx, state_speed(w, self.sign_width_rad_s), dt, self.source_index[idx]
                continue
            dt = np.diff(self.t_s[idx], prepend=self.t_s[idx][:1])
            period = float(np.median(dt[1:])) if len(dt) > 1 else 0.0
            yield idx, state_speed(self.sample_speed[idx], self.sign_width_rad_s), np.minimum(dt, 2.0 * period), \
                np.arange(len(idx))

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
        for idx, w, dt, at in self._steps():
            z[idx] = effect.state_steps(0.0, w, dt, params)[at]
        return z

    def _by_speed(self) -> tuple[EffectInputs, np.ndarray]:
        """The effects' inputs with the samples in the order of their |ω|, and each one's block
        (computed once)."""
        if self._speed_order is None:
            order = np.argsort(self.x.abs_speed, kind="stable")
            x = _rows(self.x, order)
            self._speed_order = (x, np.repeat(np.arange(len(self.count)), self.count)[order])
        return self._speed_order

    def _direction_runs(self) -> _DirectionRuns:
        """The recordings cut into runs of one direction (computed once, see :class:`_DirectionRuns`)."""
        if self._runs is None:
            n = len(self.t_s)
            run, since, settled = np.empty(n, dtype=np.int64), np.empty(n), np.empty(n)
            sign, whole, opens = [], [], []
            for idx, w, dt, at in self._steps():
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
                run[idx] = len(sign) + local[at]
                since[idx] = (turned - before[local])[at]
                settled[idx] = held[at]
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
        x = _rows(self.x, moving)
        settled = runs.settled[moving]
        z = settled + (z_start - runs.sign)[runs.run[moving]] * decay
        change = (effect.column(x._replace(state={name: z}), params, member, second)
                  - effect.column(x._replace(state={name: settled}), params, member, second))
        return base + np.bincount(runs.block[moving], weights=change, minlength=len(self.count)) / self.count

    def angle_since_reversal(self, clear_rad_s: float) -> np.ndarray:
        """The angle [rad] turned since the drive last turned round, at every sample (NaN before a
        recording's first reversal); a reversal as :func:`_reverses` counts one (beyond the noise)."""
        phi = np.full(len(self.t_s), np.nan)
        for idx, w, dt, at in self._steps():
            turned = np.cumsum(np.abs(w) * dt)
            moving = np.flatnonzero(np.abs(w) >= max(clear_rad_s, 1e-12))
            flips = moving[1:][np.sign(w[moving[1:]]) != np.sign(w[moving[:-1]])]
            if not len(flips):
                continue
            # the last reversal at or before each sample: the angle turned since the sample before it
            last = np.searchsorted(flips, at, side="right") - 1
            since = last >= 0
            base = turned[np.maximum(flips[np.maximum(last, 0)] - 1, 0)]
            phi[idx[since]] = (turned[at] - base)[since]
        return phi


def make_blocks(d: SampleData, block_s: float = 0.25, folds: int = 5, like: Blocks | None = None) -> Blocks:
    """Average samples into blocks (see the module docstring) and compute every candidate column.

    ``like``: reuse another block set's boundaries, dwells and folds (same samples, corrected values).
    Steady-state rows (``d.steady_state``) are dwell means already: each is a block and a dwell of
    its own, weighted equally (a table says nothing about its noise), folds every ``folds``-th row;
    sensor errors are not candidates there (a table holds losses, not a torque sensor's readings).
    """
    t = d.t_ns.astype(np.float64) * 1e-9
    sg = d.sign if d.sign is not None else rotation_sign(d.speed, d.torque, d.sign_width_rad_s)
    start, count, brk = _block_starts(d, t, block_s, like)

    def mean(x: np.ndarray) -> np.ndarray:
        return np.add.reduceat(x, start) / count

    ym = mean(d.residual)
    aw, at = np.abs(d.speed), np.abs(d.torque)
    spd, trq = mean(d.speed), mean(d.torque)
    temp = mean(np.nan_to_num(d.temperature, nan=np.nan))
    if like is not None:
        dwell, groups = like.dwell, like.groups
    else:
        dwell, _fold = dwells(d, spd, trq, start, block_s, folds, t)
        groups = operating_groups(d, start, count, dwell, folds)
    fold = groups.fold
    weight, inflation, repeat = _block_weights(d, start, count, brk, dwell, mean(d.measured_loss),
                                               _full_block(t, block_s))
    theta = d.temperature
    untestable = {n: r for n, r in testability(d).items() if r}
    testable = tuple(n for n in EFFECTS if n not in untestable)
    columns: dict[str, np.ndarray] = {}
    # a lag or an inertia shows only where a run's operating point moves: steady runs, and the pauses
    # between them, carry none (their readings' noise would be fitted as one)
    nuisance = {name: mean(col) for name, col in nuisance_columns(d, sg).items()} if groups.transients else {}
    # the laws in the load take the output-side load the power balance measured (core.effectsum.output_load)
    load = d.torque - sg * d.measured_loss
    x = EffectInputs(at, aw, d.torque, sg, theta, d.fr_part, abs_load=np.abs(load))
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
        streams=None if d.recordings is None or d.source_index is None or d.steady_state
        else [(r.t_ns, r.speed_rad_s) for r in d.recordings],
        source_index=d.source_index,
        sign_width_rad_s=d.sign_width_rad_s,
    )
    blocks.repeat = repeat
    blocks.place = groups.place
    blocks.groups = groups
    blocks.full_count = _full_block(t, block_s)
    blocks.load = mean(load)
    blocks.untestable = untestable
    blocks.load_rule = load_rule(d)
    blocks.nuisance = nuisance
    _add_columns(blocks, d, mean)
    return blocks


def testability(d: SampleData) -> dict[str, str]:
    """Each effect of the registry -> why this data cannot show it ("" where it can): one that needs a
    varying oil temperature, speeds near standstill, regeneration or both directions of rotation
    where the data have them; sensor errors in a table only where its loss is the power balance of its
    torque readings and its rows turn both ways (else its rows are taken as losses);
    load-dependent ones not in a spin test nor under one load (:func:`_one_load`);
    effects with memory only where the speed reverses."""
    theta = d.temperature
    have_theta = np.isfinite(theta)
    span = float(np.nanmax(theta) - np.nanmin(theta)) if have_theta.any() else 0.0
    varies = bool(have_theta.mean() > 0.9 and span >= MIN_TEMPERATURE_SPAN_C)
    # memory shows only at reversals within a recording, and not in a table's dwell means
    reverses = not d.steady_state and _reverses(d.speed, d.bag_id, 3.0 * d.sign_width_rad_s)
    regenerating = float(np.mean(d.torque * d.speed < 0)) if len(d.speed) else 0.0
    directions = min(float(np.mean(d.speed > 0)), float(np.mean(d.speed < 0))) if len(d.speed) else 0.0
    one_load = load_rule(d)
    why = {}
    for n, e in EFFECTS.items():
        reason = ""
        if e.needs_temperature and not varies:
            reason = ("no oil temperature" if not have_theta.any() else
                      f"the oil temperature varies by {span:.2g} °C only (needs {MIN_TEMPERATURE_SPAN_C:g} °C over "
                      "90 % of the samples)")
        elif not e.physical and d.steady_state and not d.torque_readings:
            reason = "a table's rows are losses, not a sensor's readings"
        elif not e.physical and d.steady_state and directions < MIN_SLOW_SHARE:
            reason = ("a table's torque readings in one direction: its rows are taken as losses (a reading's zero "
                      "error is a constant drag there)")
        elif e.needs_speeds_below is not None and (
                not len(d.speed) or np.mean(np.abs(d.speed) <= e.needs_speeds_below) < MIN_SLOW_SHARE):
            reason = (f"too few samples at |speed| <= {e.needs_speeds_below:g} rad/s (needs "
                      f"{100 * MIN_SLOW_SHARE:g} % of them)")
        elif d.spin_test and e.depends_on_load:
            reason = "a spin test (nothing on the output): the drive torque is the loss, no load to depend on"
        elif one_load and e.depends_on_load:
            reason = one_load
        elif e.needs_regeneration and regenerating < MIN_SLOW_SHARE:
            reason = f"no regeneration (the output driving the input) in {100 * MIN_SLOW_SHARE:g} % of the samples"
        elif e.needs_both_directions and directions < MIN_SLOW_SHARE:
            reason = "the drive turns one way only"
        elif e.state_step is not None and not reverses:
            reason = "no reversal of the drive within a recording (beyond the speed reading's noise)"
        why[n] = reason
    return why


def load_rule(d: SampleData) -> str:
    """Why this data cannot test a law in the load ('' where it can; a spin test says so apart): one load
    (:func:`_one_load`), or a load that varies with the speed only (:func:`_load_follows_speed`)."""
    if d.spin_test:
        return ""
    return _one_load(d.load_torque, d.steady_state) or _load_follows_speed(d)


def _one_load(load_torque: np.ndarray | None, rows: bool = False) -> str:
    """Why the data hold one load only ('' where the output torque varies; ``load_torque``:
    :attr:`~.samples.SampleData.load_torque`): then a law in the load cannot be told from a constant
    drag, and one in the drive torque -- the load plus the very loss measured -- reproduces the torque
    balance whatever the friction (an identity, not a loss).  ``rows``: a table's (its load referred to
    the input)."""
    if load_torque is None or not len(load_torque):
        return ""
    load = np.abs(load_torque[np.isfinite(load_torque)])
    if len(load) < 0.9 * len(load_torque) or not len(load):
        return ""
    median = float(np.median(load))
    low, high = np.percentile(load, [5.0, 95.0])
    if median <= 0 or high - low > ONE_LOAD_SPREAD * median:
        return ""
    what = "the rows' output torque referred to the input" if rows else "the output torque"
    unit = "rows" if rows else "samples"
    return (f"one load ({what} stays at {median:.4g} N·m, 90 % of the {unit} within "
            f"{high - low:.2g} N·m): a load-dependent law cannot be told from a constant drag")


#: the load varies at a fixed speed where, in a speed bin (10 %), its 10-90 % spread reaches this share of the
#: drive torque there ...
LOAD_SPREAD_AT_SPEED = 0.1
#: ... in at least this share of the samples (else a law in the load is a law in the speed)
LOAD_VARIES_SHARE = 0.2


def _load_follows_speed(d: SampleData) -> str:
    """Why a law in the load cannot be told from one in the speed ('' where it can): the load (the output
    torque referred to the input; a table row's ``T_in − L·sgn ω``) must vary at a fixed speed -- by
    :data:`LOAD_SPREAD_AT_SPEED` of the drive torque within a 10 % speed bin, in
    :data:`LOAD_VARIES_SHARE` of the samples.  A test plan whose every speed has one load (a payload, a
    torque sensor's small constant reading while the drive torque rises with the friction) cannot: the drive
    torque's rise there is the loss itself, and a load law in it explains the loss by the loss."""
    load = d.load_torque
    if load is None or not len(load):
        return ""
    if d.steady_state:
        load_in = np.abs(load)
    else:
        ratio = d.speed_ratio if d.speed_ratio and d.speed_ratio > 0 else 1.0
        w_out = d.speed / ratio if d.out_speed is None else np.where(np.isnan(d.out_speed), d.speed / ratio,
                                                                         d.out_speed)
        load_in = np.abs(np.nan_to_num(load) * w_out / np.maximum(np.abs(d.speed), 1e-300))
    drive = np.abs(d.torque)
    speed_bin = np.floor(np.log(np.maximum(np.abs(d.speed), 1e-12)) / np.log1p(0.1))
    _u, inv = np.unique(speed_bin, return_inverse=True)
    varies = np.zeros(len(load_in), bool)
    for k in range(len(_u)):
        mine = inv == k
        if np.count_nonzero(mine) < 2:
            continue
        lo, hi = np.percentile(load_in[mine], [10.0, 90.0])
        varies[mine] = hi - lo >= LOAD_SPREAD_AT_SPEED * float(np.median(drive[mine]))
    if float(np.mean(varies)) >= LOAD_VARIES_SHARE:
        return ""
    unit = "rows" if d.steady_state else "samples"
    return (f"the load varies with the speed only (at a fixed speed it stays within {100 * LOAD_SPREAD_AT_SPEED:g} % "
            f"of the drive torque in {100 * (1 - float(np.mean(varies))):.0f} % of the {unit}): a law in the load "
            "cannot be told from one in the speed -- it needs two or more loads at one speed")


def _add_columns(blocks: Blocks, d: SampleData, mean) -> None:
    """Each testable effect's block column (or grid of columns over its member), and the model's
    own parameters' columns: the part each scales, where the model has it (not switched off, not 0
    as the ball friction without a ball force)."""
    laws = [n for n in blocks.testable if not EFFECTS[n].oil_law]  # the oil's: once the selection knows it
    for name in laws:
        if EFFECTS[name].member is None:
            blocks.columns[name] = blocks.column(name)
    gridded = [n for n in laws if EFFECTS[n].member is not None]
    columns: dict[str, dict[float, np.ndarray]] = {n: {} for n in gridded}
    for m in sorted({m for n in gridded for m in EFFECTS[n].member_grid}):
        with shared_powers():  # laws of one input at one exponent share its powers
            for name in gridded:
                if m in EFFECTS[name].member_grid:
                    columns[name][m] = blocks.column(name, m)
    for name in gridded:
        blocks.grids[name] = np.stack([columns[name][m] for m in EFFECTS[name].member_grid])
    for key in fitted_parameters():
        part = d.parts.get(MODEL_PARAMETERS[key].part)
        if d.spin_test:
            blocks.untestable[key] = "a spin test (nothing on the output): every part of the model depends on the load"
        elif part is None:
            blocks.untestable[key] = "the paper's model is switched off (estimator.paper_model: false)"
        elif not np.any(part != 0):
            blocks.untestable[key] = f"the model's {MODEL_PARAMETERS[key].part} part is 0 on this data"
        elif MODEL_PARAMETERS[key].depends_on_load and blocks.load_rule:
            blocks.untestable[key] = (f"its part ({MODEL_PARAMETERS[key].part}) scales with the load, and "
                                      f"{blocks.load_rule}")
        else:
            blocks.columns[key] = mean(part)
            blocks.testable += (key,)


def _block_starts(d: SampleData, t: np.ndarray, block_s: float,
                  like: Blocks | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each block starts, its sample count, and the samples that start one (a new time slot,
    recording or sign of speed or torque, a gap; ``like``'s boundaries when given).  A slot through
    which the operating point moves (a ramp, a reversal) is cut into equal parts short enough that
    the speed and the torque each move less than :data:`OPERATING_POINT_TOLERANCE` of their level
    (and beyond six times their reading's noise) within one: the block means keep the shape of a
    transient instead of averaging across it."""
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
    if like is not None:
        start = like.start
        brk = np.zeros(n, bool)
        brk[start] = True
        return start, np.diff(np.append(start, n)), brk
    if n > 1 and not d.steady_state:
        brk = _cut_transients(d, brk)
    start = np.flatnonzero(brk)
    return start, np.diff(np.append(start, n)), brk


#: within a block the speed and the torque each move less than this share of their level
OPERATING_POINT_TOLERANCE = 0.05
#: a transient's parts hold at least this many samples
MIN_PART_SAMPLES = 4


def _cut_transients(d: SampleData, brk: np.ndarray) -> np.ndarray:
    """``brk`` with the blocks through which the speed moves cut into equal parts: a block's drift is
    1.5 × the difference of the means of its last and first thirds (a ramp's whole rise; noise
    averages out of the thirds), its tolerance :data:`OPERATING_POINT_TOLERANCE` of the block's
    speed or four standard errors of that difference, whichever is larger."""
    n = len(brk)
    start = np.flatnonzero(brk)
    count = np.diff(np.append(start, n))
    within = np.arange(n) - np.repeat(start, count)
    third = np.repeat(np.maximum(count // 3, 1), count)
    first, last = within < third, within >= np.repeat(count, count) - third
    x = d.speed
    k = np.maximum(count // 3, 1).astype(float)
    drift = 1.5 * np.abs(np.add.reduceat(np.where(last, x, 0.0), start) - np.add.reduceat(np.where(first, x, 0.0),
                                                                                           start)) / k
    level = np.abs(np.add.reduceat(x, start)) / count
    noise = noise_of(x, d.bag_id)
    tol = np.maximum(OPERATING_POINT_TOLERANCE * level, 4.0 * (noise if np.isfinite(noise) else 0.0) * np.sqrt(2.0 / k))
    with np.errstate(divide="ignore", invalid="ignore"):
        parts = np.where(tol > 0, np.ceil(drift / tol), 1.0)
    parts = np.clip(np.nan_to_num(parts, nan=1.0, posinf=1.0), 1, np.maximum(count // MIN_PART_SAMPLES, 1))
    parts = parts.astype(np.int64)
    if np.all(parts == 1):
        return brk
    piece = within * np.repeat(parts, count) // np.repeat(count, count)
    out = brk.copy()
    out[1:] |= piece[1:] != piece[:-1]
    return out


#: a search for an exponent evaluates a law on at most this many samples of each block
SEARCH_SAMPLES = 16


def _thinned(b: Blocks) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The samples :meth:`Blocks.search_column` evaluates: at most :data:`SEARCH_SAMPLES` of each block,
    evenly spread; their blocks and counts (``None`` where no block holds more)."""
    if not np.any(b.count > SEARCH_SAMPLES):
        return None, None, None
    take = np.minimum(b.count, SEARCH_SAMPLES)
    block = np.repeat(np.arange(len(b.count)), take)
    k = np.arange(len(block)) - np.repeat(np.cumsum(take) - take, take)
    idx = np.repeat(b.start, take) + (k * np.repeat(b.count, take)) // np.repeat(take, take)
    return idx, block, take.astype(float)


def _full_block(t: np.ndarray, block_s: float) -> float:
    """Samples in a whole block: the block length over the median sample period."""
    dt = np.diff(t)
    dt = dt[dt > 0]
    return max(block_s / float(np.median(dt)), 1.0) if len(dt) else 1.0


def noise_of(x: np.ndarray, bag_id: np.ndarray) -> float:
    """A reading's noise (:func:`.noise.reading_noise`) over the recordings."""
    return reading_noise(x, bag_id)


def _block_weights(d: SampleData, start: np.ndarray, count: np.ndarray, brk: np.ndarray, dwell: np.ndarray,
                   measured: np.ndarray, full: float) -> tuple[np.ndarray, float, Repeatability | None]:
    """Each block mean's weight (1 / its noise variance), the factor from a sample's noise variance to
    a block mean's (times ``1/count``), and the repeatability of a whole block's mean.

    Blocks weigh by their samples; one whose residual is clearly noisier than the typical block's (a
    spike, a rough patch: its samples' differences, which the model's slow misfit through a ramp
    barely inflates; :func:`.noise.difference_variance`) weighs less in proportion.  The factor is what
    the scatter of consecutive whole blocks of a dwell says (:func:`.noise.repeatability`: whatever the
    noise's colour), else the AR(1) inflation of the differences.  A table's rows weigh 1 each."""
    if d.steady_state:
        return np.ones(len(start)), 1.0, None
    var_sample, inflation = difference_variance(d.residual, start, count, brk)
    repeat = repeatability(measured, dwell, count, full, cells(d, start, count))
    whole = count >= 0.8 * full
    if math.isfinite(repeat.se_block_nm) and repeat.se_block_nm > 0 and whole.any():
        inflation = repeat.se_block_nm ** 2 * full / float(np.median(var_sample[whole]))
    return count / (var_sample * inflation), inflation, repeat

