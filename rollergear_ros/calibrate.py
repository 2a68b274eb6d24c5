"""Close the loop: trace the residual to effects the model lacks, fit them, report before/after.

Procedure (after ``shared/closing-the-loop.md``):

1. **Measured loss** ``T_loss,meas = (T_in·ω_in − T_out·ω_out)/|ω_in|`` (any quadrant) and the
   residual ``y = T_loss,meas − T_loss,model`` per sample (never the efficiency).
2. **Block averages.** Samples are averaged over short blocks (default 0.25 s, never across a bag,
   a sign change of ω or T, or a gap).  Every candidate term is linear in its coefficient, so block
   means of the regressors keep the relation exact while coloured noise averages out.  Each block
   is weighted by the inverse variance of its mean (within-block variance × the AR(1) inflation
   ``(1+ρ)/(1−ρ)`` measured on the data).
3. **Dwells and folds.** Consecutive blocks at the same operating point form a dwell (≤ 5 s);
   5-fold grouped cross-validation assigns whole dwells to folds (never random rows).
4. **Candidate groups** are the physical laws of the vocabulary, one column each; a law's exponent
   (``p``, ``q``) or Vogel ``B`` is chosen by profiling the weighted fit over a grid and reported
   with its profile-likelihood 95 % range.  Two nuisance columns are always in the fit and never
   reported: ``dT/dt·sgn ω`` (time misalignment of the torque channels) and ``dω/dt·sgn ω``
   (inertia).
5. **Forward selection**, one group per step: the group with the lowest cross-validated error is
   accepted only if (a) its coefficient passes a Wald test with cluster-robust (by dwell) standard
   errors at α = 0.01, Bonferroni-corrected over the groups left, (b) the lower 95 % bound of its
   RMS contribution exceeds δ, and (c) held-out RMSE improves by more than 2 %.  A group whose
   column the data cannot tell apart from another's (partial correlation > 0.995, similar error)
   makes the verdict *inconclusive*, naming both and the data that would separate them.
6. **Verdict**: ``effects_found``; ``no_missing_effect`` (every group's upper 95 % bound < δ); or
   ``inconclusive``.  Errors before/after are cross-validated predictions on held-out dwells.

δ, the practical minimum effect size, defaults to ``max(0.005 N·m, 2 % of the RMS measured loss,
3 × the standard error of a block-mean loss)`` and is stated in the report.  No rclpy import.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable, Sequence

import numpy as np

from .bag import TopicMap
from .effects import EFFECTS, EffectInputs, separating_data
from .errors import BagError
from .model import LossModel, rotation_sign
from .params import Config, ParameterError, config_to_yaml, validate

#: an effect that needs the oil temperature is testable when it varies by at least this much
MIN_TEMPERATURE_SPAN_C = 3.0


def groups() -> tuple[str, ...]:
    """The candidate groups: every effect of the registry, in its order."""
    return tuple(EFFECTS)


# ------------------------------------------------------------------------------------ data
@dataclass
class SampleData:
    """Per-sample inputs and measured loss of one or more bags (valid samples only)."""

    t_ns: np.ndarray
    bag_id: np.ndarray
    torque: np.ndarray
    speed: np.ndarray
    temperature: np.ndarray
    measured_loss: np.ndarray
    model_loss: np.ndarray
    fr_part: np.ndarray
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def residual(self) -> np.ndarray:
        return self.measured_loss - self.model_loss


def load_samples(bags: Sequence[str | Path], config: Config, topics: TopicMap = TopicMap(),
                 warn: Callable[[str], None] | None = None, min_speed_rad_s: float = 2.0,
                 progress: bool = False) -> SampleData:
    """Replay bags through the bare model (no effects, no adaptation) and keep samples with a measured loss."""
    from .replay import replay

    base = validate({k: v for k, v in config.to_flat().items() if not k.startswith("effects.")}
                    | {"estimator.adapt": False})
    model = LossModel(base.gearbox)
    parts = []
    skipped: dict[str, int] = {}
    for i, bag in enumerate(bags):
        summary, batches = replay(bag, base, topics, show_progress=progress, warn=warn, collect=True)
        for k, v in summary.skipped.items():
            skipped[k] = skipped.get(k, 0) + v
        for b in batches:
            ok = np.isfinite(b.measured_loss_nm) & (np.abs(b.speed_rad_s) >= min_speed_rad_s)
            temp = b.temperature_c if b.temperature_c is not None else np.full(len(b.t_ns), np.nan)
            parts.append((b.t_ns[ok], np.full(int(ok.sum()), i), b.torque_nm[ok], b.speed_rad_s[ok], temp[ok],
                          b.measured_loss_nm[ok], np.abs(b.loss_torque_nm[ok])))
    if not parts or sum(len(p[0]) for p in parts) == 0:
        raise BagError("no samples with a measured output torque and |speed| >= "
                         f"{min_speed_rad_s:g} rad/s: calibration needs the output torque topic")
    cols = [np.concatenate([p[j] for p in parts]) for j in range(7)]
    return SampleData(cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6],
                      model.fr_part(cols[2], cols[3]), skipped)


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

    def mean(self, values: np.ndarray) -> np.ndarray:
        return np.add.reduceat(np.broadcast_to(values, self.x.abs_speed.shape), self.start) / self.count

    def column(self, name: str, member: float | None = None) -> np.ndarray:
        """Block means of an effect's regressor (coefficient 1), at any member (not only the grid's);
        a sample without an input the effect needs (a missing temperature) contributes 0."""
        effect = EFFECTS[name]
        values = effect.column(self.x, effect.defaults(), member)
        return self.mean(np.where(np.isnan(values), 0.0, values))


def make_blocks(d: SampleData, block_s: float = 0.25, folds: int = 5, like: Blocks | None = None) -> Blocks:
    """Average samples into blocks (see the module docstring) and compute every candidate column.

    ``like``: reuse another block set's boundaries, dwells and folds (same samples, corrected values).
    """
    t = d.t_ns.astype(np.float64) * 1e-9
    sg = rotation_sign(d.speed, d.torque)
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

    def mean(x: np.ndarray) -> np.ndarray:
        return np.add.reduceat(x, start) / count

    y = d.residual
    ym = mean(y)
    # derivative columns within each bag (np.gradient over time; zero across breaks)
    dtdt = np.zeros(n)
    dwdt = np.zeros(n)
    for b in np.unique(d.bag_id):
        idx = np.flatnonzero(d.bag_id == b)
        if len(idx) > 2:
            tt = t[idx] + 1e-12 * np.arange(len(idx))
            dtdt[idx] = np.gradient(d.torque[idx], tt)
            dwdt[idx] = np.gradient(d.speed[idx], tt)
    # noise of each block mean: within-block variance, inflated for autocorrelation
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
    weight = 1.0 / var_mean
    aw, at = np.abs(d.speed), np.abs(d.torque)
    spd, trq = mean(d.speed), mean(d.torque)
    temp = mean(np.nan_to_num(d.temperature, nan=np.nan))
    # dwells: consecutive blocks at the same operating point (<= 5 s), folds by dwell
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
    fold = dwell % folds
    if like is not None:
        dwell, fold = like.dwell, like.fold
    theta = d.temperature
    have_theta = np.isfinite(theta)
    varies = (
        bool(have_theta.mean() > 0.9 and np.nanmax(theta) - np.nanmin(theta) >= MIN_TEMPERATURE_SPAN_C)
        if have_theta.any()
        else False
    )
    testable = tuple(n for n, e in EFFECTS.items() if varies or not e.needs_temperature)
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
    )
    for name in testable:
        effect = EFFECTS[name]
        if effect.member is None:
            columns[name] = blocks.column(name)
        else:
            blocks.grids[name] = np.stack([blocks.column(name, m) for m in effect.member_grid])
    return blocks


# ------------------------------------------------------------------------------------ fitting
@dataclass
class Fit:
    coef: np.ndarray
    cov: np.ndarray
    wsse: float
    pred: np.ndarray


def wls(x: np.ndarray, y: np.ndarray, w: np.ndarray, groups: np.ndarray | None = None) -> Fit:
    """Weighted least squares with a cluster-robust (by ``groups``) sandwich covariance."""
    sw = np.sqrt(w)
    xs = x * sw[:, None]
    ys = y * sw
    coef, *_ = np.linalg.lstsq(xs, ys, rcond=1e-12)
    pred = x @ coef
    r = y - pred
    bread = np.linalg.pinv(xs.T @ xs)
    if groups is not None and len(np.unique(groups)) > x.shape[1] + 1:
        score = x * (w * r)[:, None]
        ug, inv = np.unique(groups, return_inverse=True)
        sums = np.zeros((len(ug), x.shape[1]))
        np.add.at(sums, inv, score)
        g = len(ug)
        meat = sums.T @ sums * (g / (g - 1))
        cov = bread @ meat @ bread
    else:
        dof = max(len(y) - x.shape[1], 1)
        cov = bread * float(np.sum(w * r * r)) / dof
    return Fit(coef, cov, float(np.sum(w * r * r)), pred)


@dataclass
class Term:
    """One candidate group at one member (exponent / Vogel B): a column in the design."""

    name: str
    column: np.ndarray
    member: float | None = None  # p, q or B

    def params(self, coef: float) -> dict[str, float]:
        """The effect's parameters (short names, registry order): the fitted coefficient, the
        profiled member, the defaults for the rest."""
        effect = EFFECTS[self.name]
        values = effect.defaults()
        values[effect.coefficient] = coef
        if effect.member is not None:
            values[effect.member] = float(self.member)
        return values


def members(blocks: Blocks, name: str) -> list[Term]:
    """The candidate terms of one group: one column, or one per member of its grid ([] when the
    data cannot test it)."""
    if name not in blocks.testable:
        return []
    effect = EFFECTS[name]
    if effect.member is None:
        return [Term(name, blocks.columns[name])]
    return [Term(name, blocks.grids[name][i], float(m)) for i, m in enumerate(effect.member_grid)]


class Calibrator:
    """Forward selection over the physical groups on block means (see the module docstring)."""

    def __init__(
        self, blocks: Blocks, delta_nm: float | None = None, alpha: float = 0.01, min_improvement: float = 0.02
    ) -> None:
        self.b = blocks
        self.alpha = alpha
        self.min_improvement = min_improvement
        nuis = [blocks.columns["dtdt"], blocks.columns["dwdt"]]
        # drop nuisance columns with no variation (steady data): they would be singular
        self.nuisance = [c for c in nuis if np.sqrt(np.average(c * c, weights=blocks.count)) > 1e-9]
        rms_meas = float(np.sqrt(np.average(blocks.measured**2, weights=blocks.count)))
        se_block = float(np.sqrt(np.median(1.0 / blocks.weight)))
        self.delta = delta_nm if delta_nm is not None else max(0.005, 0.02 * rms_meas, 3 * se_block)
        self.rms_measured = rms_meas
        self.log: list[str] = []

    # -------------------------------------------------------------- helpers
    def design(self, terms: Sequence[Term], nuisance: bool = True) -> np.ndarray:
        cols = (self.nuisance if nuisance else []) + [t.column for t in terms]
        return np.column_stack(cols) if cols else np.zeros((len(self.b.y), 0))

    def fit(self, terms: Sequence[Term]) -> Fit:
        x = self.design(terms)
        if x.shape[1] == 0:
            return Fit(
                np.zeros(0), np.zeros((0, 0)), float(np.sum(self.b.weight * self.b.y**2)), np.zeros(len(self.b.y))
            )
        return wls(x, self.b.y, self.b.weight, self.b.dwell)

    def wsse(self, terms: Sequence[Term]) -> float:
        x = self.design(terms)
        if x.shape[1] == 0:
            return float(np.sum(self.b.weight * self.b.y**2))
        sw = np.sqrt(self.b.weight)
        coef, *_ = np.linalg.lstsq(x * sw[:, None], self.b.y * sw, rcond=1e-12)
        r = self.b.y - x @ coef
        return float(np.sum(self.b.weight * r * r))

    def cv_predictions(self, terms: Sequence[Term], only_terms: int | None = None) -> np.ndarray:
        """Prediction of every block from a fit that did not see its fold.

        ``only_terms=n``: the part predicted by the first ``n`` terms alone (what a calibrated
        parameter file adds), without the nuisance columns and later terms fitted alongside them.
        """
        x = self.design(terms)
        pred = np.zeros(len(self.b.y))
        if x.shape[1] == 0:
            return pred
        cols = slice(None) if only_terms is None else slice(len(self.nuisance), len(self.nuisance) + only_terms)
        for k in np.unique(self.b.fold):
            test = self.b.fold == k
            f = wls(x[~test], self.b.y[~test], self.b.weight[~test])
            pred[test] = x[test][:, cols] @ f.coef[cols]
        return pred

    def cv_rmse(self, terms: Sequence[Term]) -> float:
        e = self.b.y - self.cv_predictions(terms)
        return float(np.sqrt(np.average(e * e, weights=self.b.count)))

    def rms_of(self, column: np.ndarray) -> float:
        return float(np.sqrt(np.average(column * column, weights=self.b.count)))

    def _with_member(self, term: Term, member: float) -> Term:
        return Term(term.name, self.b.column(term.name, member), member)

    def optimise(self, terms: list[Term], passes: int = 3) -> list[Term]:
        """Coordinate descent over the exponents / Vogel B of the terms (grid, then a bounded refinement)."""
        from scipy.optimize import minimize_scalar

        terms = list(terms)
        for _ in range(passes):
            changed = False
            for i, t in enumerate(terms):
                if t.member is None:
                    continue
                grid = members(self.b, t.name)
                scores = [self.wsse(terms[:i] + [g] + terms[i + 1 :]) for g in grid]
                j = int(np.argmin(scores))
                lo_b, hi_b = EFFECTS[t.name].member_bounds
                step = (grid[1].member - grid[0].member) if len(grid) > 1 else 0.1
                lo = max(lo_b, grid[j].member - step)
                hi = min(hi_b, grid[j].member + step)
                res = minimize_scalar(
                    lambda m, i=i, t=t: self.wsse(terms[:i] + [self._with_member(t, m)] + terms[i + 1 :]),
                    bounds=(lo, hi),
                    method="bounded",
                    options={"xatol": step * 1e-3},
                )
                best = self._with_member(t, float(res.x)) if res.fun <= scores[j] else grid[j]
                if t.member is None or abs(best.member - t.member) > step * 1e-2:
                    changed = True
                terms[i] = best
            if not changed:
                break
        return terms

    def best_candidate(self, name: str, base: list[Term]) -> list[Term] | None:
        """``base`` plus the group's best member, with every exponent re-optimised jointly."""
        cands = members(self.b, name)
        if not cands:
            return None
        if cands[0].member is None:
            return self.optimise(base + cands)
        scores = [self.wsse(base + [c]) for c in cands]
        return self.optimise(base + [cands[int(np.argmin(scores))]])

    def member_range(self, terms: list[Term], i: int) -> list[float]:
        """Profile-likelihood 95 % range of term i's exponent (the others held at their optimum)."""
        from scipy.optimize import brentq

        t = terms[i]
        w0 = self.wsse(terms)
        dof = max(len(self.b.y) - len(terms) - len(self.nuisance), 1)
        limit = w0 + 3.84 * max(w0 / dof, 1.0)

        def excess(m: float) -> float:
            return self.wsse(terms[:i] + [self._with_member(t, m)] + terms[i + 1 :]) - limit

        lo_b, hi_b = EFFECTS[t.name].member_bounds
        lo = brentq(excess, lo_b, t.member, xtol=1e-4) if excess(lo_b) > 0 else lo_b
        hi = brentq(excess, t.member, hi_b, xtol=1e-4) if excess(hi_b) > 0 else hi_b
        return [float(lo), float(hi)]

    def coefficient(self, terms: list[Term], i: int) -> tuple[float, float]:
        f = self.fit(terms)
        k = len(self.nuisance) + i
        return float(f.coef[k]), float(math.sqrt(max(f.cov[k, k], 0.0)))

    # -------------------------------------------------------------- selection
    def run(self) -> dict:
        selected: list[Term] = []  # accepted
        provisional: list[Term] = []  # best member of each ambiguous set: kept in the fit, not reported
        ambiguous: list[dict] = []
        remaining = [g for g in groups() if members(self.b, g)]
        unavailable = [g for g in groups() if g not in remaining]
        cv_now = self.cv_rmse([])
        while remaining:
            base = selected + provisional
            scored = []
            for g in remaining:
                terms = self.best_candidate(g, base)
                if terms is not None:
                    scored.append((self.cv_rmse(terms), g, terms))
            if not scored:
                break
            scored.sort(key=lambda x: x[0])
            cv_new, g, terms = scored[0]
            c, se = self.coefficient(terms, len(terms) - 1)
            new = terms[-1]
            rms_col = self.rms_of(new.column)
            z = abs(c) / se if se > 0 else math.inf
            z_crit = _z_two_sided(self.alpha / len(remaining))
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
            twins = [
                h
                for cv_h, h, terms_h in scored[1:]
                if cv_h <= cv_new * 1.05 + 1e-12 and self._partial_corr(new, terms_h[-1], base) > 0.995
            ]
            self.log.append(
                f"step {len(self.log) + 1}: best {g}"
                + (f" ({_member_text(new)})" if new.member is not None else "")
                + f" (held-out RMSE {cv_new:.4g} vs {cv_now:.4g} N·m), |z| = {z:.1f}, RMS contribution "
                f"[{lower:.4g}, {upper:.4g}] N·m"
                + (f"; indistinguishable from {', '.join(twins)}" if twins else "")
                + (
                    f"; not accepted: {'; '.join(reasons)}"
                    if reasons
                    else "; ambiguous: kept in the fit, not reported"
                    if twins
                    else "; accepted"
                )
            )
            if reasons:
                break
            # exponents of earlier terms were re-optimised together with the new one
            n_sel = len(selected)
            selected, provisional = terms[:n_sel], terms[n_sel : len(base)]
            if twins:
                group = sorted([g] + twins)
                needs = "; ".join(
                    sorted(
                        {
                            separating_data(a, b)
                            or "data over a wider range of speed, torque, direction and temperature"
                            for a in group
                            for b in group
                            if a < b
                        }
                    )
                )
                ambiguous.append({"effects": group, "needs": needs, "rms_contribution_nm": [lower, upper]})
                provisional.append(new)
                remaining = [r for r in remaining if r not in group]
            else:
                selected.append(new)
                remaining.remove(g)
            cv_now = cv_new
        # the ambiguous sets stay in the final fit (so the accepted coefficients are not biased)
        final = selected + provisional
        ranges = {t.name: self.member_range(final, i) for i, t in enumerate(final) if t.member is not None}
        rejected = []
        blocked = {e for a in ambiguous for e in a["effects"]}
        for g in groups():
            if g in (t.name for t in selected) or g in unavailable:
                continue
            if g in blocked:
                rejected.append({"name": g, "upper_rms_nm": math.nan, "estimate_rms_nm": math.nan, "ambiguous": True})
                continue
            terms = self.best_candidate(g, final)
            if terms is None:
                continue
            c, se = self.coefficient(terms, len(terms) - 1)
            rms_col = self.rms_of(terms[-1].column)
            rejected.append(
                {
                    "name": g,
                    "upper_rms_nm": (abs(c) + 1.96 * se) * rms_col,
                    "estimate_rms_nm": abs(c) * rms_col,
                    "ambiguous": False,
                }
            )
        return {
            "selected": selected,
            "provisional": provisional,
            "ranges": ranges,
            "ambiguous": ambiguous,
            "rejected": rejected,
            "unavailable": unavailable,
        }

    def _partial_corr(self, a: Term, b: Term, base: Sequence[Term]) -> float:
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


def _member_text(t: Term) -> str:
    return f"{EFFECTS[t.name].member} = {t.member:.3g}"


def _z_two_sided(alpha: float) -> float:
    from scipy.stats import norm

    return float(norm.isf(alpha / 2))


def error_stats(err: np.ndarray, measured: np.ndarray, count: np.ndarray) -> dict[str, float]:
    rmse = float(np.sqrt(np.average(err * err, weights=count)))
    rms_meas = float(np.sqrt(np.average(measured * measured, weights=count)))
    return {
        "rmse_nm": rmse,
        "mae_nm": float(np.average(np.abs(err), weights=count)),
        "max_abs_nm": float(np.max(np.abs(err))) if len(err) else 0.0,
        "rel_rmse_pct": 100.0 * rmse / rms_meas if rms_meas > 0 else math.nan,
    }


# ------------------------------------------------------------------------------------ result
@dataclass
class CalibrationResult:
    verdict: str
    effects: list[dict]
    error_before: dict
    error_after: dict
    holdout: str
    samples: int
    delta_nm: float
    rejected: list[dict]
    ambiguous: list[dict]
    unavailable: list[str]
    log: list[str]
    sample_level: dict
    config: Config
    blocks: Blocks | None = None
    pred_after: np.ndarray | None = None

    def to_json(self) -> dict:
        """The ``interface.md`` object (plus extra keys: delta, rejected, ambiguous, ...)."""
        return {
            "verdict": self.verdict,
            "effects": self.effects,
            "error_before": self.error_before,
            "error_after": self.error_after,
            "holdout": self.holdout,
            "samples": self.samples,
            "delta_nm": self.delta_nm,
            "rejected": self.rejected,
            "ambiguous": self.ambiguous,
            "unavailable": self.unavailable,
            "sample_level_errors": self.sample_level,
        }


def calibrate(
    data: SampleData, config: Config, delta_nm: float | None = None, block_s: float = 0.25, folds: int = 5
) -> CalibrationResult:
    """Run the whole analysis on loaded samples."""
    blocks = make_blocks(data, block_s, folds)
    if len(blocks.y) < 4 * folds:
        raise BagError(f"only {len(blocks.y)} blocks of {block_s:g} s: too little data to calibrate")
    cal = Calibrator(blocks, delta_nm)
    out = cal.run()
    selected: list[Term] = out["selected"]
    final = selected + out["provisional"]
    blocks0, data_c = blocks, data
    if {t.name for t in final} & {"torque_offset", "torque_gain"}:
        cal, final, data_c = _refit_sensor_errors(cal, data, final, config, block_s, folds)
        selected = final[: len(selected)]
    blocks = cal.b
    pred_before = np.zeros(len(blocks.y))  # the paper's model alone
    # what the calibrated parameter file adds: the accepted effects (fitted with the rest, held out)
    pred_after = cal.cv_predictions(final, only_terms=len(selected))
    err_b = blocks0.y - pred_before  # residual of the model at the measured torque
    err_a = blocks.y - pred_after
    full = cal.fit(final)
    effects = []
    k0 = len(cal.nuisance)
    coef_keys = {n: e.coefficient for n, e in EFFECTS.items()}
    expo_keys = {n: e.member for n, e in EFFECTS.items()}
    for i, term in enumerate(selected):
        c = float(full.coef[k0 + i])
        se = float(math.sqrt(max(full.cov[k0 + i, k0 + i], 0.0)))
        ci = {coef_keys[term.name]: [c - 1.96 * se, c + 1.96 * se]}
        if term.member is not None and term.name in out["ranges"]:
            # the coefficient's interval covers the exponent's range too (c and p are correlated)
            lo_m, hi_m = out["ranges"][term.name]
            for m in (lo_m, hi_m):
                alt = list(final)
                alt[i] = cal._with_member(term, m)
                ca, sa = cal.coefficient(alt, i)
                lo_c, hi_c = ci[coef_keys[term.name]]
                ci[coef_keys[term.name]] = [min(lo_c, ca - 1.96 * sa), max(hi_c, ca + 1.96 * sa)]
            ci[expo_keys[term.name]] = [lo_m, hi_m]
        rms = cal.rms_of(term.column)
        effects.append(
            {
                "name": term.name,
                "params": term.params(c),
                "ci95": ci,
                "rms_contribution_nm": abs(c) * rms,
                "rms_contribution_ci95_nm": [max(0.0, abs(c) - 1.96 * se) * rms, (abs(c) + 1.96 * se) * rms],
            }
        )
    if out["ambiguous"]:
        verdict = "inconclusive"
    elif selected:
        verdict = "effects_found"
    elif all(r["upper_rms_nm"] < cal.delta for r in out["rejected"]):
        verdict = "no_missing_effect"
    else:
        verdict = "inconclusive"
    # sample-level errors (noise included) for the report
    idx_block = np.repeat(np.arange(len(blocks.y)), blocks.count)
    s_b = data.residual - pred_before[idx_block]
    s_a = data_c.residual - pred_after[idx_block]
    sample_level = {
        "before": error_stats(s_b, data.measured_loss, np.ones(len(s_b))),
        "after": error_stats(s_a, data.measured_loss, np.ones(len(s_a))),
    }
    holdout = (
        f"{folds}-fold cross-validation grouped by dwell ({int(blocks.dwell.max()) + 1} dwells of steady operation, "
        f"at most 5 s each; whole dwells held out, never single rows); errors are of {blocks.block_s:g} s block "
        f"means of every held-out block, predicted by a fit that did not see its fold "
        f"({len(blocks.y)} blocks)"
    )
    # a fitted value outside a parameter's physical range (e.g. recordings of different rigs mixed)
    # is not written to the parameter file: the verdict says so
    writable = []
    for e in effects:
        try:
            _calibrated_config(config, [e])
            writable.append(e)
        except ParameterError as exc:
            cal.log.append(f"{e['name']} not written to the parameter file: {exc}")
            out["rejected"].append(
                {
                    "name": e["name"],
                    "upper_rms_nm": e["rms_contribution_ci95_nm"][1],
                    "estimate_rms_nm": e["rms_contribution_nm"],
                    "ambiguous": False,
                    "reason": f"fitted value outside the physical range: {exc}",
                }
            )
            verdict = "inconclusive"
    effects = writable
    new_config = _calibrated_config(config, effects)
    return CalibrationResult(
        verdict,
        effects,
        error_stats(err_b, blocks.measured, blocks.count),
        error_stats(err_a, blocks.measured, blocks.count),
        holdout,
        int(len(data.t_ns)),
        cal.delta,
        out["rejected"],
        out["ambiguous"],
        out["unavailable"],
        cal.log,
        sample_level,
        new_config,
        blocks,
        pred_after,
    )


def _refit_sensor_errors(
    cal: Calibrator,
    data: SampleData,
    final: list[Term],
    config: Config,
    block_s: float,
    folds: int,
    iterations: int = 3,
) -> tuple[Calibrator, list[Term], SampleData]:
    """Torque-sensor errors also corrupt the model's input: refit with ``T = (T_meas − b)/(1 + g)``.

    A fixed-point iteration (the correction is second order, so it converges in 2–3 steps); the
    estimator evaluates the model at the same corrected torque.
    """
    from dataclasses import replace as dc_replace

    model = LossModel(config.gearbox)
    names = [t.name for t in final]
    for _ in range(iterations):
        f = cal.fit(final)
        k0 = len(cal.nuisance)
        b = float(f.coef[k0 + names.index("torque_offset")]) if "torque_offset" in names else 0.0
        g = float(f.coef[k0 + names.index("torque_gain")]) if "torque_gain" in names else 0.0
        t_c = (data.torque - b) / (1.0 + g)
        corrected = dc_replace(
            data, torque=t_c, model_loss=model.loss_magnitude(t_c, data.speed), fr_part=model.fr_part(t_c, data.speed)
        )
        new = Calibrator(make_blocks(corrected, block_s, folds, like=cal.b), cal.delta, cal.alpha, cal.min_improvement)
        new.log = cal.log
        final = [new._with_member(t, t.member) if t.member is not None else members(new.b, t.name)[0] for t in final]
        cal = new
    return cal, final, corrected


def _calibrated_config(config: Config, effects: list[dict]) -> Config:
    """``config`` with exactly the accepted effects enabled, at their fitted parameters."""
    flat = {k: v for k, v in config.to_flat().items()}
    for name in groups():
        flat[f"effects.{name}.enabled"] = False
    for e in effects:
        flat[f"effects.{e['name']}.enabled"] = True
        for q in EFFECTS[e["name"]].parameters:
            flat[f"effects.{e['name']}.{q.key}"] = e["params"][q.short]
    return validate(flat)


def calibrated_yaml(result: CalibrationResult, sources: Sequence[str]) -> str:
    header = (
        "# Written by `rollergear calibrate` from " + ", ".join(map(str, sources)) + "\n"
        f"# verdict: {result.verdict}; held-out RMSE {result.error_before['rmse_nm']:.4g} -> "
        f"{result.error_after['rmse_nm']:.4g} N·m\n"
    )
    return config_to_yaml(result.config, header)


def write_report(result: CalibrationResult, data: SampleData, out_dir: Path, sources: Sequence[str]) -> Path:
    """Markdown report with PNG plots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    b = result.blocks
    assert b is not None and result.pred_after is not None
    before = b.y
    after = b.y - result.pred_after
    plots = []
    for key, x, label in (
        ("speed", b.speed, "drive speed [rad/s]"),
        ("torque", b.torque, "drive torque [N·m]"),
        ("temperature", b.temperature, "oil temperature [°C]"),
    ):
        if not np.isfinite(x).any():
            continue
        fig, ax = plt.subplots(1, 2, figsize=(11, 4), dpi=100, sharey=True)
        ax[0].scatter(x, before, s=4, alpha=0.5)
        ax[0].set_title("before: measured − model")
        ax[1].scatter(x, after, s=4, alpha=0.5, color="tab:green")
        ax[1].set_title("after: measured − (model + accepted effects)")
        for a in ax:
            a.axhline(0, color="k", lw=0.5)
            a.set_xlabel(label)
            a.grid(alpha=0.3)
        ax[0].set_ylabel(f"residual, {b.block_s:g} s block means [N·m]")
        fig.tight_layout()
        p = out_dir / f"residual_vs_{key}.png"
        fig.savefig(p)
        plt.close(fig)
        plots.append(p)
    fig, ax = plt.subplots(figsize=(6, 5), dpi=100)
    model_mean = b.measured - b.y
    ax.scatter(b.measured, model_mean, s=4, alpha=0.5, label="model")
    ax.scatter(b.measured, model_mean + result.pred_after, s=4, alpha=0.5, label="model + accepted effects")
    lim = [float(np.min(b.measured)), float(np.max(b.measured))]
    ax.plot(lim, lim, "k--", lw=0.8)
    ax.set_xlabel("measured loss [N·m]")
    ax.set_ylabel("estimated loss [N·m]")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    p = out_dir / "measured_vs_estimated.png"
    fig.savefig(p)
    plt.close(fig)
    plots.append(p)

    eb, ea = result.error_before, result.error_after
    lines = [
        "# Calibration report\n",
        f"Recordings: {', '.join(map(str, sources))}  ",
        f"Samples used: {result.samples:,} (|ω| ≥ 2 rad/s, measured output torque present)  ",
        f"Verdict: **{result.verdict.replace('_', ' ')}**  ",
        f"Practical minimum effect size δ = {result.delta_nm:.4g} N·m (RMS contribution); "
        f"RMS measured loss {np.sqrt(np.average(b.measured**2, weights=b.count)):.4g} N·m\n",
        "## Error on held-out data\n",
        result.holdout + ".\n",
        "| | RMSE [N·m] | MAE [N·m] | max \\|error\\| [N·m] | RMSE / RMS measured loss |",
        "|---|---|---|---|---|",
        *(f"| {label} | {e['rmse_nm']:.4g} | {e['mae_nm']:.4g} | {e['max_abs_nm']:.4g} | {e['rel_rmse_pct']:.2f} % |"
          for label, e in (("before (model)", eb), ("after (model + accepted effects)", ea))),
        f"\nReduction of held-out RMSE: {100 * (1 - ea['rmse_nm'] / eb['rmse_nm']) if eb['rmse_nm'] else 0:.1f} %. "
        f"Per sample (sensor noise included): RMSE {result.sample_level['before']['rmse_nm']:.4g} → "
        f"{result.sample_level['after']['rmse_nm']:.4g} N·m.\n",
        "## Accepted effects\n",
    ]
    if result.effects:
        lines += ["| effect | parameters | 95 % intervals | RMS contribution [N·m] (95 %) |", "|---|---|---|---|"]
        for e in result.effects:
            pr = ", ".join(f"{k} = {v:.4g}" for k, v in e["params"].items())
            ci = ", ".join(f"{k} ∈ [{lo:.4g}, {hi:.4g}]" for k, (lo, hi) in e["ci95"].items())
            lo, hi = e["rms_contribution_ci95_nm"]
            lines.append(f"| {e['name']} | {pr} | {ci} | {e['rms_contribution_nm']:.4g} ({lo:.4g}–{hi:.4g}) |")
    else:
        lines.append("None.")
    if result.ambiguous:
        lines.append("\n## Effects the data cannot tell apart\n")
        for a in result.ambiguous:
            lo, hi = a["rms_contribution_nm"]
            lines.append(
                f"- {' / '.join(a['effects'])}: an effect of RMS {lo:.3g}–{hi:.3g} N·m is there, but these "
                f"columns are the same on this data. To separate them record {a['needs']}."
            )
    lines.append("\n## Groups not accepted (upper 95 % bound of their RMS contribution)\n")
    for r in result.rejected:
        lines.append(
            f"- {r['name']}: ≤ {r['upper_rms_nm']:.3g} N·m"
            + (" (ambiguous, see above)" if r["ambiguous"] else "")
            + (f" — {r['reason']}" if r.get("reason") else "")
        )
    for u in result.unavailable:
        lines.append(
            f"- {u}: not testable on this data (needs an oil temperature that varies by "
            f"≥ {MIN_TEMPERATURE_SPAN_C:g} °C)"
        )
    lines.append("\n## Selection log\n")
    lines += [f"- {entry}" for entry in result.log]
    lines.append("\n## Plots\n")
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    lines.append("\nMethod: see the docstring of `rollergear_ros/calibrate.py` and docs/closing-the-loop.md.")
    report = out_dir / "report.md"
    report.write_text("\n".join(lines) + "\n")
    (out_dir / "result.json").write_text(json.dumps(result.to_json(), indent=1))
    return report
