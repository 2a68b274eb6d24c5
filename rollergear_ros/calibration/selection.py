"""The fits the selection of missing effects decides with, on block means (step 4 of :mod:`.calibrate`).

Weighted least squares with cluster-robust errors (:func:`~.leastsquares.wls`), one candidate :class:`Term` per
effect and member of its grid (:func:`members`), and the :class:`Calibrator`: a set's fit, its
held-out predictions, exponents profiled with their ranges, a candidate's screen (is it an
explanation at all?) and its acceptance test.  The procedure that uses them is :mod:`.forward`.
No rclpy import.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .blocks import Blocks
from .leastsquares import Fit, weighted_sse, wls, z_two_sided
from .noise import Repeatability, minimum_effect
from ..core.effects import EFFECTS
from ..core.modelparams import MODEL_PARAMETERS


@dataclass(frozen=True)
class ErrorStats:
    """Error of a prediction of the measured loss (weighted by samples per block)."""

    rmse_nm: float
    mae_nm: float
    max_abs_nm: float
    rel_rmse_pct: float  #: RMSE / RMS measured loss, %

    def to_json(self) -> dict[str, float]:
        return {"rmse_nm": self.rmse_nm, "mae_nm": self.mae_nm, "max_abs_nm": self.max_abs_nm,
                "rel_rmse_pct": self.rel_rmse_pct}


@dataclass(frozen=True)
class RejectedEffect:
    """An effect not accepted, with the upper 95 % bound of its RMS contribution."""

    name: str
    upper_rms_nm: float
    estimate_rms_nm: float
    ambiguous: bool = False  #: in a set the data cannot tell apart (bounds NaN)
    reason: str = ""  #: why, when it is not the bound (e.g. a fitted value out of range)

    def to_json(self) -> dict:
        out = {"name": self.name, "upper_rms_nm": self.upper_rms_nm, "estimate_rms_nm": self.estimate_rms_nm,
               "ambiguous": self.ambiguous}
        return out | ({"reason": self.reason} if self.reason else {})


@dataclass
class AmbiguousSet:
    """Effects whose columns are the same on this data, and the data that would separate them."""

    effects: list[str]
    needs: str
    rms_contribution_nm: list[float]  #: 95 % range of the RMS contribution of the set's best
    assumed: str | None = None  #: the member the user said it is (``calibrate --assume``): accepted and written
    #: two readings of one part of the loss (:mod:`.forward`): the one written ("a + b")
    taken: str | None = None
    #: each reading's effects, held-out RMSE, parameters and whether it is the one written
    readings: list[dict] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"effects": self.effects, "needs": self.needs,
                "rms_contribution_nm": [v if math.isfinite(v) else None for v in self.rms_contribution_nm],
                "assumed": self.assumed, "taken": self.taken, "readings": self.readings}


@dataclass
class Term:
    """One candidate group at one member (exponent / Vogel B): a column in the design."""

    name: str
    column: np.ndarray
    member: float | None = None  # p, q or B
    second: float | None = None  # Vogel C (None: the registry's default)
    law: tuple[float, float, float] | None = None  # the oil's Vogel B, C, θ_ref (an effect that follows the oil)
    fixed: bool = False  # the member held (the law's line, :attr:`~core.effects.Effect.linear`), not profiled

    def params(self, coef: float) -> dict[str, float]:
        """The effect's parameters (short names, registry order): the fitted coefficient, the
        profiled member, the defaults for the rest."""
        effect = EFFECTS[self.name]
        values = effect.defaults()
        values[effect.coefficient] = coef
        if effect.member is not None:
            values[effect.member] = float(self.member)
        if effect.second_member is not None and self.second is not None:
            values[effect.second_member] = float(self.second)
        if self.law is not None:
            values.update(zip(("B", "C", "theta_ref"), self.law))
        return values


def members(blocks: Blocks, name: str, law: tuple[float, float, float] | None = None) -> list[Term]:
    """The candidate terms of one group: one column, or one per member of its grid ([] when the
    data cannot test it, or when it follows the oil and no ``law`` is known)."""
    if name not in blocks.testable:
        return []
    if name in MODEL_PARAMETERS:
        return [Term(name, blocks.columns[name])]
    effect = EFFECTS[name]
    if effect.oil_law:
        if law is None:
            return []
        return [Term(name, blocks.column(name, float(m), None, law), float(m), None, law) for m in effect.member_grid]
    if effect.member is None:
        return [Term(name, blocks.columns[name])]
    return [Term(name, blocks.grids[name][i], float(m)) for i, m in enumerate(effect.member_grid)]


def viscosity_level() -> str | None:
    """The model's parameter that is a viscosity law's level: the rolling part's (η at θ_ref)."""
    return next((k for k, p in MODEL_PARAMETERS.items() if p.part == "fr" and p.same_part_as is None), None)


class Calibrator:
    """The fits on block means that the selection (:mod:`.forward`) decides with: a set of terms'
    weighted fit, held-out predictions, exponents profiled, a candidate's screen and test."""

    def __init__(
        self, blocks: Blocks, delta_nm: float | None = None, alpha: float = 0.01, min_improvement: float = 0.02,
        sensors_nm: float | None = None,
    ) -> None:
        self.b = blocks
        self.alpha = alpha
        self.min_improvement = min_improvement
        # the rig's nuisances (a channel's lag, the inertia), without those that do not vary (steady
        # data: they would be singular)
        kept = {k: c for k, c in blocks.nuisance.items() if np.sqrt(np.average(c * c, weights=blocks.count)) > 1e-12}
        self.nuisance_names = list(kept)
        self.nuisance = list(kept.values())
        rms_meas = float(np.sqrt(np.average(blocks.measured**2, weights=blocks.count)))
        noise_se = float(np.sqrt(np.median(1.0 / blocks.weight))) if len(blocks.weight) else math.nan
        self.minimum = minimum_effect(delta_nm, blocks.repeat or Repeatability(math.nan, 0, 0), sensors_nm, noise_se,
                                      rms_meas, blocks.steady_state, blocks.block_s)
        self.delta = self.minimum.delta_nm
        self.rms_measured = rms_meas
        self.log: list[str] = []
        self.stage: Callable[[str], None] = lambda text: None  #: told what the selection is doing
        #: effect -> (member, second member) to start its search from, and -> their search bounds,
        #: instead of the registry's grids and bounds (a data sheet's viscosity law: ``calibrate``)
        self.starts: dict[str, tuple[float, float | None]] = {}
        self.bounds: dict[str, dict[str, tuple[float, float]]] = {}
        self.datasheet_law: tuple[float, float, float] | None = None  #: the oil's data sheet's Vogel B, C, θ_ref
        #: effect -> why it was last taken as its line (:meth:`_line_unless_curve_predicts`)
        self.line_notes: dict[str, str] = {}
        #: fits on the operating points' means, not the blocks' (:meth:`at_operating_points`)
        self.point_means = False

    def at_operating_points(self) -> Calibrator:
        """This calibrator fitting the operating points' means (:mod:`.grouping`), each weighing by its samples,
        instead of the blocks: a line through a test plan's runs as an engineer fits it by hand, which how torque
        and speed ripple together inside a run does not tilt.  Its held-out predictions and
        every fit of it go the same way; without operating-point groups, this calibrator itself."""
        if self.b.groups is None or self.point_means:
            return self
        out = copy.copy(self)
        out.point_means = True
        return out

    def solve(self, x: np.ndarray, y: np.ndarray, rows: np.ndarray | None = None, robust: bool = True) -> Fit:
        """The weighted fit of ``y`` by ``x``'s columns over the blocks (or ``rows`` of them), its covariance
        cluster-robust by dwell (``robust``; else the plain one, for a fit whose coefficients alone are used);
        at the operating points (:meth:`at_operating_points`): of their means, robust point by point.  The
        prediction is per block."""
        b = self.b
        if rows is not None:
            x, y = x[rows], y[rows]
        if not self.point_means:
            w = b.weight if rows is None else b.weight[rows]
            return wls(x, y, w, (b.dwell if rows is None else b.dwell[rows]) if robust else None)
        group = b.groups.group if rows is None else b.groups.group[rows]
        count = b.count if rows is None else b.count[rows]
        points, index = np.unique(group, return_inverse=True)
        n = np.bincount(index, weights=count)
        yg = np.bincount(index, weights=count * y) / n
        if x.shape[1] == 0:
            return Fit(np.zeros(0), np.zeros((0, 0)), float(np.sum(n * yg**2)), np.zeros(len(y)))
        xg = np.column_stack([np.bincount(index, weights=count * c) / n for c in x.T])
        f = wls(xg, yg, n, np.arange(len(points)))
        return Fit(f.coef, f.cov, f.wsse, x @ f.coef)

    def _residual_sse(self, x: np.ndarray, y: np.ndarray) -> float:
        """The weighted residual sum of squares of the fit of ``y`` by ``x`` (the profiles': the normal
        equations where well conditioned; the operating points' means where they are fitted)."""
        if self.point_means:
            return self.solve(x, y).wsse
        if x.shape[1] == 0:
            return float(np.sum(self.b.weight * y**2))
        return weighted_sse(x, y, self.b.weight)

    def search_ranges(self, name: str) -> dict[str, tuple[float, float]]:
        """Short name -> search bounds of an effect's profiled members (a start's, else the registry's)."""
        return self.bounds.get(name) or EFFECTS[name].profiled_ranges()

    # -------------------------------------------------------------- helpers
    def design(self, terms: Sequence[Term], nuisance: bool = True, skip: Sequence[int] = ()) -> np.ndarray:
        """The columns of a set (nuisance first), without the terms at ``skip`` (held coefficients)."""
        cols = (self.nuisance if nuisance else []) + [self.effective_column(t, terms) for i, t in enumerate(terms)
                                                      if i not in skip]
        return np.column_stack(cols) if cols else np.zeros((len(self.b.y), 0))

    def effective_column(self, t: Term, terms: Sequence[Term]) -> np.ndarray:
        """A term's column in a set: the rolling part's parameter (η0) scales the Fr part *at the
        viscosity law's η(θ)* when a Fr-scaling effect is in the set (its column is ``T_Fr·(s − 1)``
        at coefficient 1, so the part at η(θ) is ``T_Fr + T_Fr·(s − 1)``); an effect that follows the
        oil follows the set's viscosity law (one oil: its B and C are fitted once, for both)."""
        if t.law is not None:
            law = self.oil_law(terms)
            if law is not None and law != t.law:
                return self.b.column(t.name, t.member, t.second, law)
            return t.column
        parameter = MODEL_PARAMETERS.get(t.name)
        if parameter is None or parameter.part != "fr":
            return t.column
        coupled = [u.column for u in terms if u.name in EFFECTS and EFFECTS[u.name].scales_fr]
        return t.column + sum(coupled) if coupled else t.column

    @staticmethod
    def held(terms: Sequence[Term]) -> dict[int, float]:
        """Terms whose coefficient is held, not fitted: with the rolling part's parameter (η0) in a
        set, a Fr-scaling effect (the viscosity law) is held at its profile coefficient -- η0 is the
        law's level, and the file (η0, the law at scale 1) then predicts exactly what was fitted."""
        if not any(t.name in MODEL_PARAMETERS and MODEL_PARAMETERS[t.name].part == "fr" for t in terms):
            return {}
        return {i: float(EFFECTS[t.name].profile_coefficient) for i, t in enumerate(terms)
                if t.name in EFFECTS and EFFECTS[t.name].scales_fr and EFFECTS[t.name].profile_coefficient is not None}

    def _offset(self, terms: Sequence[Term], held: dict[int, float]) -> np.ndarray:
        """What the held terms predict."""
        out = np.zeros(len(self.b.y))
        for i, coef in held.items():
            out = out + coef * self.effective_column(terms[i], terms)
        return out

    def fit(self, terms: Sequence[Term]) -> Fit:
        """The weighted fit of a set; a held term's coefficient is its held value (variance 0)."""
        held = self.held(terms)
        x = self.design(terms, skip=held)
        offset = self._offset(terms, held)
        k0 = len(self.nuisance)
        if x.shape[1] == 0:
            f = Fit(np.zeros(0), np.zeros((0, 0)), self._residual_sse(x, self.b.y - offset), offset)
        else:
            f = self.solve(x, self.b.y - offset)
            f.pred = f.pred + offset
        if not held:
            return f
        n = k0 + len(terms)
        free = [k for k in range(n) if k < k0 or k - k0 not in held]
        coef, cov = np.zeros(n), np.zeros((n, n))
        coef[free] = f.coef
        cov[np.ix_(free, free)] = f.cov
        for i, c in held.items():
            coef[k0 + i] = c
        return Fit(coef, cov, f.wsse, f.pred)

    def wsse(self, terms: Sequence[Term]) -> float:
        """The weighted residual sum of squares of a set's fit (what the exponents' profiles minimise)."""
        held = self.held(terms)
        x = self.design(terms, skip=held)
        return self._residual_sse(x, self.b.y - self._offset(terms, held))

    def cv_predictions(self, terms: Sequence[Term], only_terms: int | None = None) -> np.ndarray:
        """Prediction of every block from a fit that did not see its fold.

        ``only_terms=n``: the part predicted by the first ``n`` terms alone (what a calibrated
        parameter file adds), without the nuisance columns and later terms fitted alongside them.
        """
        held = self.held(terms)
        x = self.design(terms, skip=held)
        offset = self._offset(terms, {i: c for i, c in held.items() if only_terms is None or i < only_terms})
        fit_offset = self._offset(terms, held)
        pred = offset.copy()
        if x.shape[1] == 0:
            return pred
        k0 = len(self.nuisance)
        kept = [i for i in range(len(terms)) if i not in held]  # the free terms, in order
        n_free = sum(1 for i in kept if only_terms is None or i < only_terms)
        cols = slice(None) if only_terms is None else slice(k0, k0 + n_free)
        for k in np.unique(self.b.fold):
            test = self.b.fold == k
            f = self.solve(x, self.b.y - fit_offset, rows=~test, robust=False)
            pred[test] += x[test][:, cols] @ f.coef[cols]
        return pred

    def cv_rmse(self, terms: Sequence[Term]) -> float:
        e = self.b.y - self.cv_predictions(terms)
        return float(np.sqrt(np.average(e * e, weights=self.b.count)))

    def cv_rmse_points(self, terms: Sequence[Term], written: int | None = None) -> float:
        """The held-out error at each operating point (:func:`operating_point_rmse`) of a set's fit, or of
        its first ``written`` terms alone (what a file of them predicts)."""
        return operating_point_rmse(self.b, self.b.y - self.cv_predictions(terms, only_terms=written))

    def noise_rms(self) -> float:
        """The RMS noise of the block means (:func:`.structure.block_noise`)."""
        from .structure import block_noise

        return block_noise(self.b)

    def measured_noise_rms(self) -> float:
        """The noise of a block mean as the data measure it -- the scatter of consecutive whole blocks at
        one held operating point (:mod:`.noise`) -- or NaN where no dwell tells it (operating points
        that only recur, noise-free data: their scatter may be the loss's own variation)."""
        rep = self.b.repeat
        if rep is None or rep.cells or not math.isfinite(rep.se_block_nm) or rep.se_block_nm <= 0:
            return math.nan
        return self.noise_rms()

    def rms_of(self, column: np.ndarray) -> float:
        return float(np.sqrt(np.average(column * column, weights=self.b.count)))

    def contribution_rms(self, terms: Sequence[Term], i: int) -> float:
        """RMS of term ``i``'s column as the set uses it (per unit coefficient)."""
        return self.rms_of(self.effective_column(terms[i], terms))

    def _with_member(self, term: Term, member: float, second: float | None = None, search: bool = False) -> Term:
        """``term`` at another member (and second member); ``search``: its column as a search evaluates it."""
        second = term.second if second is None else second
        column = (self.b.search_column if search else self.b.column)(term.name, member, second, term.law)
        return Term(term.name, column, member, second, term.law)

    def oil_law(self, terms: Sequence[Term]) -> tuple[float, float, float] | None:
        """The calibrated oil's Vogel law: the set's viscosity_temperature, else the data sheet's."""
        for t in terms:
            if t.name in EFFECTS and EFFECTS[t.name].scales_fr and t.member is not None:
                return (float(t.member), float(t.second if t.second is not None
                                                else EFFECTS[t.name].defaults()["C"]),
                        float(EFFECTS[t.name].defaults()["theta_ref"]))
        return self.datasheet_law

    def wsse_held(self, terms: Sequence[Term], i: int) -> float:
        """:meth:`wsse` with term ``i``'s coefficient held at its effect's ``profile_coefficient``."""
        held = self.held(terms) | {i: float(EFFECTS[terms[i].name].profile_coefficient)}
        x = self.design(terms, skip=held)
        return self._residual_sse(x, self.b.y - self._offset(terms, held))

    def _score(self, terms: list[Term], i: int) -> Callable[[Term], float]:
        """What term ``i``'s members minimise: the fit's wsse, with the coefficient held where the
        effect profiles at a fixed one."""
        held = terms[i].name in EFFECTS and EFFECTS[terms[i].name].profile_coefficient is not None
        if held:
            return lambda t: self.wsse_held(terms[:i] + [t] + terms[i + 1 :], i)
        return lambda t: self.wsse(terms[:i] + [t] + terms[i + 1 :])

    def _best_member(self, terms: list[Term], i: int, second: float | None = None) -> tuple[float, Term]:
        """Term ``i`` at its best member (grid, then a bounded refinement), at ``second`` if given."""
        from scipy.optimize import minimize_scalar

        t = terms[i]
        effect = EFFECTS[t.name]
        score = self._score(terms, i)
        grid = [self._with_member(t, m, second) for m in effect.member_grid]
        scores = [score(g) for g in grid]
        j = int(np.argmin(scores))
        lo_b, hi_b = self.search_ranges(t.name)[effect.member]
        step = (grid[1].member - grid[0].member) if len(grid) > 1 else 0.1
        # around the grid's best; from the grid's first or last member on to the member's bound (else
        # an optimum beyond the grid would stop one step outside it and pass for an estimate)
        lo = lo_b if j == 0 else max(lo_b, grid[j].member - step)
        hi = hi_b if j == len(grid) - 1 else min(hi_b, grid[j].member + step)
        # the search over thinned block means (:meth:`~.blocks.Blocks.search_column`), the best refined
        # member's exact column against the grid's
        res = minimize_scalar(lambda m: score(self._with_member(t, m, second, search=True)), bounds=(lo, hi),
                              method="bounded", options={"xatol": step * 1e-2})
        found = self._with_member(t, float(res.x), second)
        exact = score(found)
        if exact <= scores[j]:
            return exact, found
        return scores[j], grid[j]

    def _best_pair(self, terms: list[Term], i: int) -> Term:
        """Term ``i`` at its best member and second member (Vogel B and C): the first time B profiled
        at each C of the grid, then both refined together (Nelder-Mead) from the best."""
        from scipy.optimize import minimize

        t = terms[i]
        effect = EFFECTS[t.name]
        score = self._score(terms, i)
        if t.second is None:
            profile = [self._best_member(terms, i, c) for c in effect.second_grid]
            t = profile[int(np.argmin([p[0] for p in profile]))][1]
        start = score(t)
        ranges = self.search_ranges(t.name)
        (lo_m, hi_m), (lo_s, hi_s) = ranges[effect.member], ranges[effect.second_member]
        res = minimize(lambda v: score(self._with_member(t, float(v[0]), float(v[1]))), [t.member, t.second],
                       method="Nelder-Mead", bounds=[(lo_m, hi_m), (lo_s, hi_s)],
                       options={"initial_simplex": [[t.member, t.second], [t.member * 1.1, t.second],
                                                    [t.member, t.second + 10.0]],
                                "xatol": 0.05, "fatol": 1e-9 * max(start, 1e-12), "maxfev": 200})
        return self._with_member(t, float(res.x[0]), float(res.x[1])) if res.fun < start else t

    def optimise(self, terms: list[Term], passes: int = 3) -> list[Term]:
        """Coordinate descent over the exponents / Vogel B and C of the terms (grid, then a bounded
        refinement)."""
        terms = list(terms)
        for _ in range(passes):
            changed = False
            for i, t in enumerate(terms):
                if t.member is None or t.fixed:
                    continue
                effect = EFFECTS[t.name]
                best = self._best_pair(terms, i) if effect.second_member else self._best_member(terms, i)[1]
                step = effect.member_grid[1] - effect.member_grid[0] if len(effect.member_grid) > 1 else 0.1
                if abs(best.member - t.member) > step * 1e-2 or (best.second or 0.0) != (t.second or 0.0):
                    changed = True
                terms[i] = best
            if not changed:
                break
        return terms

    def best_candidate(self, name: str, base: list[Term]) -> list[Term] | None:
        """``base`` plus the group's best member, with every exponent re-optimised jointly.  A
        Fr-scaling effect (the viscosity law) comes with the rolling part's parameter (its level,
        η(θ_ref)) when that fits better: neither explains an oil of another viscosity alone."""
        single = self._best_single(name, base)
        if single is None or name not in EFFECTS or not EFFECTS[name].scales_fr:
            return single
        level = viscosity_level()
        if level is None or any(t.name == level for t in base) or not members(self.b, level, None):
            return single
        paired = self._best_single(name, base + members(self.b, level))
        if paired is not None and self.cv_rmse(paired) < (1.0 - self.min_improvement) * self.cv_rmse(single):
            return paired  # the level too, when it clearly helps (else it would pass untested)
        return single

    def _best_single(self, name: str, base: list[Term]) -> list[Term] | None:
        cands = members(self.b, name, self.oil_law(base))
        if not cands:
            return None
        if cands[0].member is None:
            return self.optimise(base + cands)
        if name in self.starts:  # a known start (a data sheet): refined from there within its bounds
            return self.optimise(base + [self._with_member(cands[0], *self.starts[name])])
        scores = [self.wsse(base + [c]) for c in cands]
        curved = self.optimise(base + [cands[int(np.argmin(scores))]])
        return self._line_unless_curve_predicts(name, base, curved)

    def line_of(self, term: Term) -> Term:
        """``term``'s law as its line (:attr:`~core.effects.Effect.linear`), the member held."""
        t = self._with_member(term, EFFECTS[term.name].linear)
        return Term(t.name, t.column, t.member, t.second, t.law, fixed=True)

    def _line_unless_curve_predicts(self, name: str, base: list[Term], curved: list[Term]) -> list[Term]:
        """The law as a line (its :attr:`~core.effects.Effect.linear` member, held) unless the curve found
        predicts held-out operating points better by more than :attr:`min_improvement` and is a law within
        the vocabulary (its member not stopped at its search's bound): curvature enters only where the
        data between the operating points fitted ask for it."""
        if EFFECTS[name].linear is None:
            return curved
        line = base + [self.line_of(members(self.b, name)[0])]  # the others as the step found them
        short = EFFECTS[name].member
        lo, hi = self.search_ranges(name)[short]
        member = curved[-1].member
        at_bound = min(abs(member - lo), abs(member - hi)) <= 1e-3 * (hi - lo)
        if at_bound:
            self.line_notes[name] = (f"its line ({short} = {line[-1].member:g}): its curve's {short} = {member:.4g} "
                                     f"stopped at the bound of its search [{lo:g}, {hi:g}] (a law outside the "
                                     "vocabulary)")
            return line
        if self.cv_rmse_points(curved) >= (1.0 - self.min_improvement) * self.cv_rmse_points(line):
            self.line_notes[name] = (f"its line ({short} = {line[-1].member:g}): its curve ({short} = {member:.3g}) "
                                     "predicts held-out operating points no better")
            return line
        self.line_notes.pop(name, None)
        return curved

    def member_range(self, terms: list[Term], i: int, second: bool = False) -> list[float]:
        """Profile-likelihood 95 % range of term i's exponent (the others held at their optimum); of
        a pair (Vogel B and C), of either one with the other profiled, at the held coefficient.
        ``second``: the range of the second member.  A law held at its line has the range its exponent
        would have free: what the data allow, which the other terms' intervals cover."""
        from scipy.optimize import brentq, minimize_scalar

        t = terms[i]  # a line held at its member still has the range the data allow it (its curve's)
        effect = EFFECTS[t.name]
        pair = effect.second_member is not None
        w0 = self.wsse_held(terms, i) if effect.profile_coefficient is not None else self.wsse(terms)
        dof = max(len(self.b.y) - len(terms) - len(self.nuisance), 1)
        # blocks weighted by their inverse variance: chi-square with sigma 1, at least (the model may
        # fit better than the noise says); a table's rows weigh 1 each: sigma^2 is the residual's
        sigma2 = w0 / dof if self.b.steady_state else max(w0 / dof, 1.0)
        limit = w0 + 3.84 * sigma2
        score = self._score(terms, i)

        def other_profiled(m: float) -> float:
            """The pair's score at member m (or second m), the other one at its best near t's."""
            ranges = self.search_ranges(t.name)
            name, bounds, at = ((effect.member, ranges[effect.member], t.member) if second
                                else (effect.second_member, ranges[effect.second_member], t.second))
            width = 0.5 * abs(at) + 1.0
            res = minimize_scalar(
                lambda o: score(self._with_member(t, m, o) if not second else self._with_member(t, o, m)),
                bounds=(max(bounds[0], at - width), min(bounds[1], at + width)), method="bounded",
                options={"xatol": 1e-3 * width})
            return float(res.fun)

        def excess(m: float) -> float:
            if pair:
                return other_profiled(m) - limit
            return self.wsse(terms[:i] + [self._with_member(t, m)] + terms[i + 1 :]) - limit

        lo_b, hi_b = self.search_ranges(t.name)[effect.second_member if second else effect.member]
        at = t.second if second else t.member
        tol = max(1e-4 * abs(at), 1e-9 * (hi_b - lo_b))  # relative: a presliding angle of 0.01 rad as a B of 1000 K
        lo = brentq(excess, lo_b, at, xtol=tol) if excess(lo_b) > 0 and excess(at) <= 0 else lo_b
        hi = brentq(excess, at, hi_b, xtol=tol) if excess(hi_b) > 0 and excess(at) <= 0 else hi_b
        return [float(lo), float(hi)]

    def coefficient(self, terms: list[Term], i: int) -> tuple[float, float]:
        f = self.fit(terms)
        k = len(self.nuisance) + i
        return float(f.coef[k]), float(math.sqrt(max(f.cov[k, k], 0.0)))

    # -------------------------------------------------------------- selection
    def screen(self, terms: list[Term], check: Callable[[Term, float], str | None] | None = None) -> str | None:
        """Why a candidate set (its newest term last) is no explanation, whatever its significance
        (None: it may be): a physical friction fitted negative, an exponent stopped at the bound of
        its search, a model parameter driven outside its physical range, or ``check``'s reason (a
        value the parameter file refuses) -- of the new term, or of an earlier one the new term moves."""
        fit = self.fit(terms)
        k0 = len(self.nuisance)
        for i, t in enumerate(terms):
            c = float(fit.coef[k0 + i])
            who = "" if i == len(terms) - 1 else f" (with {terms[-1].name}, {t.name} becomes so)"
            if t.name in EFFECTS:
                effect = EFFECTS[t.name]
                if effect.signed:
                    why = self._direction_loss(terms, fit)
                    if why is not None:
                        return why + who
                elif effect.physical and not effect.scales_fr and c < 0:
                    return f"needs a negative friction (fits only with c = {c:.4g}){who}: not a loss the gearbox has"
                for short, v in ((effect.member, t.member), (effect.second_member, t.second)):
                    if short is None or v is None:
                        continue
                    lo, hi = self.search_ranges(t.name)[short]
                    if min(abs(v - lo), abs(v - hi)) <= 1e-3 * (hi - lo):
                        return (f"{t.name}'s {short} = {v:.4g} stopped at the bound of its search [{lo:g}, {hi:g}]"
                                f"{who}: the data want a law outside the vocabulary")
            if check is not None:
                why = check(t, c)
                if why is not None:
                    return why + who
        return None

    def _direction_loss(self, terms: list[Term], fit: Fit) -> str | None:
        """Why a set with a difference between directions is no explanation: the loss it predicts (the
        model's and the physical terms') would be negative in some block, beyond δ."""
        k0 = len(self.nuisance)
        loss = self.b.measured - self.b.y  # the model's loss, per block
        for i, t in enumerate(terms):
            effect = EFFECTS.get(t.name)
            if effect is not None and effect.physical and not effect.scales_fr:
                loss = loss + float(fit.coef[k0 + i]) * self.effective_column(t, terms)
        worst = float(np.min(loss)) if len(loss) else 0.0
        if worst < -self.delta:
            return (f"the loss it predicts would be negative in one direction (down to {worst:.4g} N·m): not a loss "
                    "the gearbox has")
        return None

    def clear(self, terms: list[Term], cv_now: float, cv_new: float, z_crit: float) -> bool:
        """Whether the newest term of ``terms`` passes the acceptance tests but for its sign."""
        c, se = self.coefficient(terms, len(terms) - 1)
        lower = max(0.0, abs(c) - 1.96 * se) * self.contribution_rms(terms, len(terms) - 1)
        improvement = (cv_now - cv_new) / cv_now if cv_now > 0 else 0.0
        return (abs(c) / se if se > 0 else math.inf) >= z_crit and lower > self.delta \
            and improvement > self.min_improvement

    def coefficient_interval(self, terms: list[Term], i: int, member_range: list[float] | None) -> list[float]:
        """95 % interval of term ``i``'s coefficient, covering its exponent's range (c and p are correlated)."""
        c, se = self.coefficient(terms, i)
        lo, hi = c - 1.96 * se, c + 1.96 * se
        for m in member_range or ():
            alt = list(terms)
            alt[i] = self._with_member(terms[i], m)
            ca, sa = self.coefficient(alt, i)
            lo, hi = min(lo, ca - 1.96 * sa), max(hi, ca + 1.96 * sa)
        return [float(lo), float(hi)]

    def test(self, terms: list[Term], g: str, cv_now: float, cv_new: float, candidates: int,
             check=None, full: bool = True) -> tuple[float, float, float, list[str]]:
        """The acceptance test of the newest term of ``terms`` (``g``): its RMS contribution's 95 %
        bounds, its |z|, and the reasons it is not accepted (none: accepted) -- significance at α
        Bonferroni-corrected over ``candidates``, the lower bound above δ, a held-out improvement from
        ``cv_now`` to ``cv_new`` above :attr:`min_improvement`; with ``full``, a model parameter's
        interval within its physical range and an exponent's coefficient interval clear of 0."""
        c, se = self.coefficient(terms, len(terms) - 1)
        new = terms[-1]
        rms_col = self.contribution_rms(terms, len(terms) - 1)
        z = abs(c) / se if se > 0 else math.inf
        z_crit = z_two_sided(self.alpha / max(candidates, 1))
        lower = max(0.0, abs(c) - 1.96 * se) * rms_col
        upper = (abs(c) + 1.96 * se) * rms_col
        improvement = (cv_now - cv_new) / cv_now if cv_now > 0 else 0.0
        reasons = []
        if z < z_crit:
            reasons.append(f"not significant (|z| = {z:.1f} < {z_crit:.1f})")
        if lower <= self.delta:
            reasons.append(
                f"lower 95 % bound of its RMS contribution {lower:.4g} N·m <= delta {self.delta:.4g} N·m"
            )
        if improvement <= self.min_improvement:
            reasons.append(f"held-out RMSE improves by only {100 * improvement:.1f} %")
        noise = self.measured_noise_rms()
        if math.isfinite(noise) and cv_new < IDENTITY_SHARE * noise:
            reasons.append(f"an identity, not a loss: the set leaves {cv_new:.2g} N·m held out, far below the "
                           f"data's own noise ({noise:.2g} N·m) -- its regressor carries the measured loss itself")
        # a model parameter's interval within the physical range
        if full and not reasons and g in MODEL_PARAMETERS and check is not None:
            for end in (c - 1.96 * se, c + 1.96 * se):
                why = check(new, end)
                if why is not None:
                    reasons.append(f"its 95 % interval reaches the bound of the physical range ({why})")
                    break
        if full and not reasons and new.member is not None:  # its interval, over the exponent's range, must not reach 0
            ci = self.coefficient_interval(terms, len(terms) - 1, self.member_range(terms, len(terms) - 1))
            if ci[0] <= 0 <= ci[1]:
                reasons.append(f"its coefficient's 95 % interval [{ci[0]:.3g}, {ci[1]:.3g}] reaches 0")
        return lower, upper, z, reasons

    def level_unfixed(self, terms: list[Term], i: int) -> str | None:
        """Why term ``i``, a law that fades with speed (its coefficient its level near standstill), is no
        measurement beside the others (None: it may be): its level's 95 % interval, over its Stribeck
        speed's range, spans more than :data:`LEVEL_SPAN` -- the data hold its tail, not its level."""
        t = terms[i]
        if t.name not in EFFECTS or EFFECTS[t.name].vanishes_above is None or t.member is None:
            return None
        lo, hi = self.coefficient_interval(terms, i, self.member_range(terms, i))
        if lo <= 0 <= hi or max(abs(lo), abs(hi)) <= LEVEL_SPAN * min(abs(lo), abs(hi)):
            return None  # an interval that reaches 0 is the significance test's
        return (f"its level's 95 % interval [{lo:.3g}, {hi:.3g}] spans more than a factor of {LEVEL_SPAN:g}: the "
                f"data (the slowest at {float(np.abs(self.b.speed).min()):.3g} rad/s) hold its tail, not its level "
                "near standstill")

    def partial_corr(self, a: Term, b: Term, base: Sequence[Term]) -> float:
        """|correlation| of two columns after removing the nuisance and base columns (weighted)."""
        w = self.b.weight
        x = self.design(base)

        def resid(v: np.ndarray) -> np.ndarray:
            if x.shape[1] == 0:
                return v
            return v - x @ wls(x, v, w).coef

        ra, rb = resid(a.column), resid(b.column)
        den = math.sqrt(float(np.sum(w * ra * ra)) * float(np.sum(w * rb * rb)))
        return abs(float(np.sum(w * ra * rb))) / den if den > 0 else 1.0


#: a set whose held-out error is below this share of the block means' noise explains the noise too: its
#: regressors carry the measured loss (a torque balance reproduced), it describes no loss
IDENTITY_SHARE = 0.1
#: a law that fades with speed whose level's 95 % interval spans more than this factor beside the final
#: set is not fixed by the data (:meth:`Calibrator.level_unfixed`): not known within two orders of
#: magnitude, the data hold its tail
LEVEL_SPAN = 100.0


def operating_point_rmse(blocks: Blocks, err: np.ndarray) -> float:
    """The RMS over operating-point groups (:mod:`.grouping`) of ``err``'s mean in each (block errors weighed by
    samples; each group by its samples): the map's error at each operating point, a block's noise averaged
    out as over a steady run."""
    groups = blocks.groups
    if groups is None:
        return float(np.sqrt(np.average(err * err, weights=blocks.count)))
    n = np.bincount(groups.group, weights=blocks.count)
    mean = np.bincount(groups.group, weights=blocks.count * err) / np.where(n > 0, n, 1.0)
    return float(np.sqrt(np.average(mean * mean, weights=n)))


def error_stats(err: np.ndarray, measured: np.ndarray, count: np.ndarray) -> ErrorStats:
    """Errors ``err`` of block means (or samples) weighted by ``count``, relative to the measured loss."""
    rmse = float(np.sqrt(np.average(err * err, weights=count)))
    rms_meas = float(np.sqrt(np.average(measured * measured, weights=count)))
    return ErrorStats(rmse, float(np.average(np.abs(err), weights=count)),
                      float(np.max(np.abs(err))) if len(err) else 0.0,
                      100.0 * rmse / rms_meas if rms_meas > 0 else math.nan)
