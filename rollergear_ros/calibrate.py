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

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .blocks import Blocks, groups, make_blocks
from .effects import EFFECTS
from .errors import BagError, UsageError
from .model import LossModel
from .params import Config, ParameterError, config_to_yaml, validate
from .report import write_report
from .samples import SampleData, load_samples
from .selection import AmbiguousSet, Calibrator, ErrorStats, RejectedEffect, Term, error_stats, members

__all__ = ["Adequacy", "CalibrationResult", "SampleData", "calibrate", "calibrated_yaml", "load_samples",
           "write_report"]


@dataclass(frozen=True)
class FoundEffect:
    """An accepted effect: its parameters (short names of the registry) with 95 % intervals."""

    name: str
    params: dict[str, float]
    ci95: dict[str, list[float]]  #: the coefficient's (covering the member's range) and the member's
    rms_contribution_nm: float
    rms_contribution_ci95_nm: list[float]
    at_bound: list[str] = field(default_factory=list)  #: members (p, q, B, C) at a bound of their range

    def to_json(self) -> dict:
        return {"name": self.name, "params": self.params, "ci95": self.ci95,
                "rms_contribution_nm": self.rms_contribution_nm,
                "rms_contribution_ci95_nm": self.rms_contribution_ci95_nm, "at_bound": self.at_bound}

    def bound_note(self) -> str | None:
        """A sentence when a member sits at a bound of its physical range (the data want a law the
        vocabulary lacks: the fit is the closest within it), else None."""
        if not self.at_bound:
            return None
        ranges = EFFECTS[self.name].profiled_ranges()
        said = ", ".join(f"{m} = {self.params[m]:.4g} at the bound of its range [{ranges[m][0]:g}, {ranges[m][1]:g}]"
                         for m in self.at_bound)
        return f"{self.name}: {said} -- the data want a law outside the vocabulary; this is the closest within it"


@dataclass(frozen=True)
class Adequacy:
    """Which share of the measured loss the paper's model and each accepted effect explain
    (means over all samples, relative to the mean measured loss), said in words."""

    model_share_pct: float  #: the paper's model (0 when switched off)
    effects_share_pct: dict[str, float]  #: accepted effect -> its share (sensor errors included)
    unexplained_pct: float  #: what neither explains (mean error after)
    paper_model: bool  #: the paper's model was part of the fit (``estimator.paper_model``)
    statement: str

    def to_json(self) -> dict:
        return {"model_share_pct": self.model_share_pct, "effects_share_pct": self.effects_share_pct,
                "unexplained_pct": self.unexplained_pct, "paper_model": self.paper_model,
                "statement": self.statement}


def adequacy(model_mean_nm: float, measured_mean_nm: float, effects_mean_nm: dict[str, float],
             paper_model: bool) -> Adequacy:
    """The shares of the measured loss, and a sentence a reader of the report can act on."""
    scale = 100.0 / measured_mean_nm if measured_mean_nm > 0 else math.nan
    model = model_mean_nm * scale
    effects = {n: v * scale for n, v in effects_mean_nm.items()}
    rest = 100.0 - model - sum(effects.values())
    listed = ", ".join(f"{n} {v:.0f} %" for n, v in effects.items()) or "no accepted effect"
    if not paper_model:
        text = (f"the paper's ball-track model is switched off (estimator.paper_model: false); the accepted effects "
                f"explain the loss: {listed}")
    elif model > 150.0:
        text = (f"the ball-track model predicts {model:.0f} % of the measured loss: it does not describe this "
                f"gearbox (the accepted effects must cancel most of it: {listed}); try estimator.paper_model: false")
    elif model < 50.0:
        text = f"the ball-track model explains {model:.0f} % of this gearbox's loss; the rest is {listed}"
    else:
        text = f"the ball-track model explains {model:.0f} % of the loss; {listed}"
    if abs(rest) >= 1.0:
        text += f"; {rest:.0f} % is unexplained"
    return Adequacy(model, effects, rest, paper_model, text)


@dataclass
class CalibrationResult:
    """What ``calibrate`` found; :meth:`to_json` is the ``calibrate --json`` object."""

    verdict: str  #: effects_found | no_missing_effect | inconclusive
    effects: list[FoundEffect]
    error_before: ErrorStats  #: held-out, the model alone
    error_after: ErrorStats  #: held-out, the model with the accepted effects
    holdout: str  #: how the held-out data was chosen
    samples: int
    delta_nm: float  #: the practical minimum effect size
    rejected: list[RejectedEffect]
    ambiguous: list[AmbiguousSet]
    unavailable: list[str]
    log: list[str]
    sample_level: dict[str, ErrorStats]  #: before/after per sample (sensor noise included)
    config: Config  #: the input parameters with the accepted effects
    adequacy: Adequacy | None = None
    blocks: Blocks | None = None
    pred_after: np.ndarray | None = None

    def to_json(self) -> dict:
        """The ``interface.md`` object (plus extra keys: delta, rejected, ambiguous, ...)."""
        return {
            "verdict": self.verdict,
            "effects": [e.to_json() for e in self.effects],
            "error_before": self.error_before.to_json(),
            "error_after": self.error_after.to_json(),
            "holdout": self.holdout,
            "samples": self.samples,
            "delta_nm": self.delta_nm,
            "rejected": [r.to_json() for r in self.rejected],
            "ambiguous": [a.to_json() for a in self.ambiguous],
            "unavailable": self.unavailable,
            "sample_level_errors": {k: v.to_json() for k, v in self.sample_level.items()},
            "adequacy": self.adequacy.to_json() if self.adequacy else None,
        }


def calibrate(
    data: SampleData, config: Config, delta_nm: float | None = None, block_s: float = 0.25, folds: int = 5,
    stage: Callable[[str], None] | None = None, assume: Sequence[str] = (),
) -> CalibrationResult:
    """Run the whole analysis on loaded samples; ``stage`` is told what it is doing (a progress bar).

    ``assume``: effects to accept when the data cannot tell them from another (a set of
    indistinguishable effects otherwise stays in the fit unreported and makes the verdict
    inconclusive); what the user knows of the rig decides, not the data.
    """
    unknown = [a for a in assume if a not in EFFECTS]
    if unknown:
        raise UsageError(f"unknown effect(s) to assume: {', '.join(unknown)} (one of {', '.join(EFFECTS)})")
    stage = stage or (lambda text: None)
    stage("block means")
    blocks = make_blocks(data, block_s, folds)
    if len(blocks.y) < 4 * folds:
        raise BagError(f"only {len(blocks.y)} blocks of {block_s:g} s: too little data to calibrate")
    cal = Calibrator(blocks, delta_nm)
    cal.stage = stage
    out = cal.run(assume)
    selected: list[Term] = out.selected
    final = selected + out.provisional
    blocks0, data_c = blocks, data
    if {t.name for t in final} & {"torque_offset", "torque_gain"}:
        stage("refit at the corrected torque")
        cal, final, data_c = _refit_sensor_errors(cal, data, final, config, block_s, folds)
        selected = final[: len(selected)]
    stage("held-out errors and intervals")
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
        if term.member is not None and term.name in out.ranges:
            # the coefficient's interval covers the exponent's range too (c and p are correlated)
            lo_m, hi_m = out.ranges[term.name]
            for m in (lo_m, hi_m):
                alt = list(final)
                alt[i] = cal._with_member(term, m)
                ca, sa = cal.coefficient(alt, i)
                lo_c, hi_c = ci[coef_keys[term.name]]
                ci[coef_keys[term.name]] = [min(lo_c, ca - 1.96 * sa), max(hi_c, ca + 1.96 * sa)]
            ci[expo_keys[term.name]] = [lo_m, hi_m]
        if term.second is not None and term.name in out.second_ranges:
            ci[EFFECTS[term.name].second_member] = out.second_ranges[term.name]
        rms = cal.rms_of(term.column)
        params = term.params(c)
        effects.append(FoundEffect(term.name, params, ci, abs(c) * rms,
                                   [max(0.0, abs(c) - 1.96 * se) * rms, (abs(c) + 1.96 * se) * rms],
                                   _members_at_bound(term.name, params)))
    if any(a.assumed is None for a in out.ambiguous):
        verdict = "inconclusive"
    elif selected:
        verdict = "effects_found"
    elif all(r.upper_rms_nm < cal.delta for r in out.rejected):
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
        f"{folds}-fold cross-validation over the rows of the steady-state table(s) (each row a dwell mean, "
        f"weighted equally; fold k holds every {folds}th row, so every fold spans the map); errors are of the "
        f"rows' losses predicted by a fit that did not see them ({len(blocks.y)} rows; no sensor noise model: "
        "a table's rows are taken as exact means)"
        if blocks.steady_state else
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
            problem = _at_search_bound(e)
        except ParameterError as exc:
            problem = f"fitted value outside the physical range: {exc}"
        if problem is None:
            writable.append(e)
        else:
            cal.log.append(f"{e.name} not written to the parameter file: {problem}")
            out.rejected.append(RejectedEffect(e.name, e.rms_contribution_ci95_nm[1], e.rms_contribution_nm,
                                               reason=problem))
            verdict = "inconclusive"
    effects = writable
    new_config = _calibrated_config(config, effects)
    if data.ratio is not None:  # the table's own ratio: what a map of the file states
        new_config = new_config.with_values({"gearbox.ratio": data.ratio})
    written = {e.name for e in effects}
    contributions = {term.name: float(np.sum(blocks.count * full.coef[k0 + i] * term.column)) / len(data.t_ns)
                     for i, term in enumerate(selected) if term.name in written}
    fit_adequacy = adequacy(float(np.mean(data.model_loss)), float(np.mean(data.measured_loss)), contributions,
                            config.estimator.paper_model)
    return CalibrationResult(
        verdict,
        effects,
        error_stats(err_b, blocks.measured, blocks.count),
        error_stats(err_a, blocks.measured, blocks.count),
        holdout,
        int(len(data.t_ns)),
        cal.delta,
        out.rejected,
        out.ambiguous,
        out.unavailable,
        cal.log,
        sample_level,
        new_config,
        fit_adequacy,
        blocks,
        pred_after,
    )


def _members_at_bound(name: str, params: dict[str, float]) -> list[str]:
    """Members within 0.1 % of their range's width of a bound (a bounded search stops just inside)."""
    return [short for short, (lo, hi) in EFFECTS[name].profiled_ranges().items()
            if min(abs(params[short] - lo), abs(params[short] - hi)) <= 1e-3 * (hi - lo)]


def _at_search_bound(found: FoundEffect) -> str | None:
    """Why a fit whose exponent or Vogel B/C stopped at the bound of its search is no estimate
    (the data wants a value the search does not allow: another law, or recordings of different rigs)."""
    for short, (lo, hi) in EFFECTS[found.name].profiled_ranges().items():
        v = found.params[short]
        if min(abs(v - lo), abs(v - hi)) <= 1e-6 * max(abs(lo), abs(hi), 1.0):
            return (f"fitted value outside the physical range: {short} = {v:.4g} stopped at the bound of "
                    f"its search [{lo:g}, {hi:g}]")
    return None


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

    model = LossModel(config.gearbox, enabled=config.estimator.paper_model)
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


def _calibrated_config(config: Config, effects: list[FoundEffect]) -> Config:
    """``config`` with exactly the accepted effects enabled, at their fitted parameters."""
    flat = {k: v for k, v in config.to_flat().items()}
    for name in groups():
        flat[f"effects.{name}.enabled"] = False
    for e in effects:
        flat[f"effects.{e.name}.enabled"] = True
        for q in EFFECTS[e.name].parameters:
            flat[f"effects.{e.name}.{q.key}"] = e.params[q.short]
    return validate(flat)


def calibrated_yaml(result: CalibrationResult, sources: Sequence[str]) -> str:
    header = (
        "# Written by `rollergear calibrate` from " + ", ".join(map(str, sources)) + "\n"
        f"# verdict: {result.verdict}; held-out RMSE {result.error_before.rmse_nm:.4g} -> "
        f"{result.error_after.rmse_nm:.4g} N·m\n"
    )
    return config_to_yaml(result.config, header)
