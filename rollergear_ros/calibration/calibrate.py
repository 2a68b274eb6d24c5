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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .blocks import Blocks, make_blocks
from ..core.effects import EFFECTS, reading_errors, viscosity_law
from ..base.errors import BagError, UsageError
from ..core.model import LossModel
from ..core.modelparams import MODEL_PARAMETERS
from ..core.oil import vogel_from_datasheet
from ..core.params import Config, ParameterError, config_to_yaml, validate
from .samples import SampleData, load_samples
from .selection import AmbiguousSet, Calibrator, ErrorStats, RejectedEffect, Term, error_stats, members

__all__ = ["Adequacy", "CalibrationResult", "CalibrationSettings", "SampleData", "calibrate", "calibrated_yaml",
           "load_samples"]


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
class FoundParameter:
    """A parameter of the paper's model that calibrate changed (:mod:`core.modelparams`)."""

    name: str  #: its parameter-file key (``gearbox.eta0_pa_s``)
    file: float  #: the value in the parameter file calibrated
    fitted: float
    ci95: list[float]
    rms_contribution_nm: float  #: RMS of the change it makes to the model's loss
    same_part: list[str] = field(default_factory=list)  #: parameters of the same part, not told apart

    def to_json(self) -> dict:
        return {"name": self.name, "file": self.file, "fitted": self.fitted, "ci95": self.ci95,
                "label": MODEL_PARAMETERS[self.name].label, "unit": MODEL_PARAMETERS[self.name].unit,
                "rms_contribution_nm": self.rms_contribution_nm, "not_told_apart_from": self.same_part}

    def sentence(self) -> str:
        """``oil viscosity at the reference temperature: 0.13 Pa·s (file 0.1; 95 % 0.127–0.133)``."""
        p = MODEL_PARAMETERS[self.name]
        unit = f" {p.unit}" if p.unit else ""
        text = (f"{p.label} ({self.name}): {self.fitted:.4g}{unit} (file {self.file:.4g}; 95 % "
                f"{self.ci95[0]:.4g}–{self.ci95[1]:.4g})")
        if self.same_part:
            text += f"; {', '.join(self.same_part)} scales the same part: not told apart, left at the file's value"
        return text


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
             paper_model: bool, viscous: bool = False) -> Adequacy:
    """The shares of the measured loss, and a sentence a reader of the report can act on;
    ``viscous``: the model's share is at the oil's viscosity law (said)."""
    scale = 100.0 / measured_mean_nm if measured_mean_nm > 0 else math.nan
    model = model_mean_nm * scale
    effects = {n: v * scale for n, v in effects_mean_nm.items()}
    rest = 100.0 - model - sum(effects.values())
    listed = ", ".join(f"{n} {v:.0f} %" for n, v in effects.items()) or "no accepted effect"
    at = " (at the oil's viscosity law)" if viscous else ""
    if not paper_model:
        text = (f"the paper's ball-track model is switched off (estimator.paper_model: false); the accepted effects "
                f"explain the loss: {listed}")
    elif model > 150.0:
        text = (f"the ball-track model{at} predicts {model:.0f} % of the measured loss: it does not describe this "
                f"gearbox (the accepted effects must cancel most of it: {listed}); try estimator.paper_model: false")
    elif model < 50.0:
        text = f"the ball-track model{at} explains {model:.0f} % of this gearbox's loss; the rest is {listed}"
    else:
        text = f"the ball-track model{at} explains {model:.0f} % of the loss; {listed}"
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
    parameters: list[FoundParameter] = field(default_factory=list)
    written: bool = True  #: ``config`` is what --out writes (False: it would predict worse than the file)
    notes: list[str] = field(default_factory=list)  #: what was decided and why (paper model off, not written)
    negative: list[str] = field(default_factory=list)  #: candidates whose fit needed a negative friction
    structure: dict | None = None  #: the unexplained residual against each input (:func:`residual_structure`)
    before_residual: np.ndarray | None = None  #: per sample, the file as given (the "before" errors)
    after_residual: np.ndarray | None = None  #: per sample, after the accepted terms (held out, per block)

    def to_json(self) -> dict:
        """The ``interface.md`` object (plus extra keys: delta, rejected, ambiguous, ...)."""
        return {
            "verdict": self.verdict,
            "effects": [e.to_json() for e in self.effects],
            "parameters": [p.to_json() for p in self.parameters],
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
            "written": self.written,
            "notes": self.notes,
            "residual_structure": self.structure,
        }


@dataclass(frozen=True)
class CalibrationSettings:
    """How :func:`calibrate` analyses (besides the data and the parameter set)."""

    #: practical minimum effect size (RMS N·m); None: from the data
    delta_nm: float | None = None
    block_s: float = 0.25  #: averaging block length [s]
    folds: int = 5  #: cross-validation folds (held-out dwells)
    #: told what the analysis is doing (a progress bar)
    stage: Callable[[str], None] | None = None
    #: effects to accept when the data cannot tell them from another (a set of indistinguishable
    #: effects otherwise stays in the fit unreported and makes the verdict inconclusive); what the
    #: user knows of the rig decides, not the data
    assume: Sequence[str] = ()


def calibrate(data: SampleData, config: Config,
              settings: CalibrationSettings = CalibrationSettings()) -> CalibrationResult:
    """Run the whole analysis on loaded samples (``settings``: :class:`CalibrationSettings`).

    Candidates are the registry's effects and the model's own parameters (:mod:`core.modelparams`);
    none is accepted as a negative friction, at the bound of its exponent's search, or outside its
    physical range.  When candidates were set aside for needing a negative friction (the paper's
    model over-predicts), the analysis is repeated with the paper's model switched off and the one
    that predicts held-out data better is the result, saying so.  The errors after are those of
    exactly the parameter file the result writes; a file that would predict held-out data worse
    than the one calibrated is not written (:attr:`CalibrationResult.written`).
    """
    unknown = [a for a in settings.assume if a not in EFFECTS]
    if unknown:
        raise UsageError(f"unknown effect(s) to assume: {', '.join(unknown)} (one of {', '.join(EFFECTS)})")
    stage = settings.stage or (lambda text: None)
    how = _Analysis(settings.delta_nm, settings.block_s, settings.folds, stage, tuple(settings.assume))
    result = _calibrate_once(data, config, how)
    if result.negative and config.estimator.paper_model:
        stage("the paper's model switched off")
        off = config.with_values({"estimator.paper_model": False})
        zero = np.zeros(len(data.t_ns))
        without = replace(data, model_loss=zero, fr_part=zero, parts={})
        alt = _calibrate_once(without, off, how, before=result)
        on_text = f"{result.error_after.rmse_nm:.4g}" if result.written else "no file"
        explains = (alt.error_after.rel_rmse_pct <= ALTERNATIVE_MAX_ERROR_PCT
                    or not (alt.structure or {}).get("strongest"))
        if alt.written and alt.verdict == "effects_found" and explains and (
                not result.written or alt.error_after.rmse_nm
                < (1.0 - ALTERNATIVE_MIN_IMPROVEMENT) * result.error_after.rmse_nm):
            alt.notes.insert(0, (
                f"the paper's model over-predicts this gearbox's loss: with it, the fits needed a negative friction "
                f"({', '.join(result.negative)}); written with estimator.paper_model: false, whose effects predict the "
                f"held-out data better (RMSE {alt.error_after.rmse_nm:.4g} N·m against {on_text} with the model)"))
            return alt
        if not alt.written:
            why = "it would not be written"
        elif alt.verdict != "effects_found":
            why = f"its verdict is {alt.verdict}"
        elif not explains:
            why = (f"its effects leave {alt.error_after.rel_rmse_pct:.0f} % of the loss unexplained "
                   f"({(alt.structure or {}).get('statement', '')})")
        else:
            why = "it predicts no better"
        result.notes.append(
            f"fits with a negative friction were set aside ({', '.join(result.negative)}); the paper's model switched "
            f"off was weighed and not taken: {why} (held-out RMSE {alt.error_after.rmse_nm:.4g} N·m against "
            f"{on_text} with the model)")
    return result


ALTERNATIVE_MIN_IMPROVEMENT = 0.02  #: the paper's model is switched off only for a held-out RMSE this much lower
#: ... and only when the effects then explain the loss: a held-out error within this share of it, or a
#: residual left without structure (switching the model off is a claim about the gearbox)
ALTERNATIVE_MAX_ERROR_PCT = 10.0
#: a data sheet's viscosity law: Vogel B searched within this factor, C within this span [K], and the
#: viscosity at the reference temperature within this factor of the data sheet's
DATASHEET_B_FACTOR = 1.5
DATASHEET_C_SPAN_K = 40.0
DATASHEET_ETA_FACTOR = 1.5


@dataclass(frozen=True)
class _Analysis:
    """How :func:`calibrate` analyses (its arguments besides the data and the parameter set)."""

    delta_nm: float | None
    block_s: float
    folds: int
    stage: Callable[[str], None]
    assume: Sequence[str]


def _calibrate_once(data: SampleData, config: Config, how: _Analysis,
                    before: CalibrationResult | None = None) -> CalibrationResult:
    """One analysis with ``config``'s model (:func:`calibrate`); ``before``: the errors "before" are
    that result's (the parameter file as given), when this one switched the paper's model off."""
    blocks, cal, ranges = _calibrator(data, config, how)
    out = cal.run(how.assume, _value_check(config, ranges))
    selected: list[Term] = out.selected
    final = selected + out.provisional
    blocks0, data_c = blocks, data
    if any(_is_sensor_error(t.name) for t in final):
        how.stage("refit at the corrected torque")
        cal, final, data_c = _refit_sensor_errors(cal, data, final, config, how)
        selected = final[: len(selected)]
    how.stage("held-out errors and intervals")
    blocks = cal.b
    full = cal.fit(final)
    effects, parameters = _found(cal, out, full, final, selected, config)
    # held out: exactly what the file writes -- the accepted terms, fitted with the rest of the set
    # (nuisance columns, ambiguous sets kept in the fit) on the other folds
    pred_after = cal.cv_predictions(final, only_terms=len(selected))
    err_b = blocks0.y if before is None else before.blocks.y  # the file as given: its model alone
    err_a = blocks.y - pred_after
    error_before = error_stats(err_b, blocks.measured, blocks.count) if before is None else before.error_before
    error_after = error_stats(err_a, blocks.measured, blocks.count)
    verdict = _verdict(out, selected, cal.delta)
    idx_block = np.repeat(np.arange(len(blocks.y)), blocks.count)
    s_b = data.residual if before is None else before.before_residual
    s_a = data_c.residual - pred_after[idx_block]
    sample_level = {
        "before": error_stats(s_b, data.measured_loss, np.ones(len(s_b))),
        "after": error_stats(s_a, data.measured_loss, np.ones(len(s_a))),
    }
    new_config = _calibrated_config(config, effects, parameters)
    if data.ratio is not None:  # the table's own ratio: what a map of the file states
        new_config = new_config.with_values({"gearbox.ratio": data.ratio})
    notes: list[str] = []
    why_not = not_written_because(error_before, error_after, len(selected))
    written = why_not is None
    if not written:
        verdict = "inconclusive"
        notes.append(why_not)
    fit_adequacy = _adequacy(data, config, cal, full, final, selected)
    result = CalibrationResult(
        verdict, effects, error_before, error_after, _holdout_text(blocks, how.folds), int(len(data.t_ns)), cal.delta,
        out.rejected, out.ambiguous, out.unavailable, cal.log, sample_level, new_config, fit_adequacy, blocks,
        pred_after, parameters, written, notes, out.negative, residual_structure(blocks, err_a))
    result.before_residual, result.after_residual = s_b, s_a
    return result


def _calibrator(data: SampleData, config: Config, how: _Analysis) -> tuple[Blocks, Calibrator, dict]:
    """The block means and the selection over them; with an oil's data sheet, the viscosity law's
    start and range from it (and the parameters it narrows: name -> range)."""
    how.stage("block means")
    blocks = make_blocks(data, how.block_s, how.folds)
    if len(blocks.y) < 4 * how.folds:
        raise BagError(f"only {len(blocks.y)} blocks of {how.block_s:g} s: too little data to calibrate")
    cal = Calibrator(blocks, how.delta_nm)
    cal.stage = how.stage
    ranges = {}  # parameter -> a narrower range than its physical one (the oil's data sheet)
    oil = config.gearbox.datasheet_oil
    if oil is not None:  # the viscosity law from the oil's data sheet: its start, and a range about it
        law = viscosity_law()
        theta_ref = law.defaults()["theta_ref"]
        b_k, c_k, eta_ref = vogel_from_datasheet(*oil, theta_ref_c=theta_ref)
        cal.starts[law.name] = (b_k, c_k)
        cal.datasheet_law = (b_k, c_k, theta_ref)
        cal.bounds[law.name] = {"B": (b_k / DATASHEET_B_FACTOR, b_k * DATASHEET_B_FACTOR),
                                "C": (max(c_k - DATASHEET_C_SPAN_K, 20.0), c_k + DATASHEET_C_SPAN_K)}
        ranges["gearbox.eta0_pa_s"] = (eta_ref / DATASHEET_ETA_FACTOR, eta_ref * DATASHEET_ETA_FACTOR)
        cal.log.append(f"the oil's data sheet (nu40 {oil[0]:g}, nu100 {oil[1]:g} mm²/s, rho15 {oil[2]:g} kg/m³; "
                       f"ASTM D341): Vogel B = {b_k:.4g} K, C = {c_k:.4g} K, eta({theta_ref:g} °C) = {eta_ref:.4g} "
                       "Pa·s, the start and range of the viscosity law's search")
    return blocks, cal, ranges


def _value_check(config: Config, ranges: Mapping[str, tuple[float, float]]) -> Callable[[Term, float], str | None]:
    """The selection's check of a fitted term: a value the parameter file takes (in its physical
    range, or the narrower one in ``ranges``) or the reason it is none."""

    def check(term: Term, coef: float) -> str | None:
        if term.name in MODEL_PARAMETERS:
            p = MODEL_PARAMETERS[term.name]
            file_value = _flat(config)[p.key]
            value = p.value(file_value, coef)
            lo, hi = ranges.get(p.key, (p.low, p.high))
            if not (math.isfinite(value) and lo <= value <= hi):
                where = "range about the data sheet" if p.key in ranges else "physical range"
                return (f"{p.key} would leave its {where} [{lo:.4g}, {hi:.4g}] (the fit asks for "
                        f"{100 * coef:+.0f} % of its part of the model)")
            return None
        try:
            _calibrated_config(config, [FoundEffect(term.name, term.params(coef), {}, 0.0, [0.0, 0.0])], [])
        except ParameterError as exc:
            return f"fitted value outside the physical range: {exc}"
        return None

    return check


def _found(cal: Calibrator, out, full, final: list[Term], selected: list[Term],
           config: Config) -> tuple[list[FoundEffect], list[FoundParameter]]:
    """The accepted terms as effects (values, intervals, contributions) and model parameters."""
    k0 = len(cal.nuisance)
    effects, parameters = [], []
    for i, term in enumerate(selected):
        c = float(full.coef[k0 + i])
        se = float(math.sqrt(max(full.cov[k0 + i, k0 + i], 0.0)))
        rms = cal.contribution_rms(final, i)
        if term.name in MODEL_PARAMETERS:
            p = MODEL_PARAMETERS[term.name]
            file_value = _flat(config)[p.key]
            ends = sorted(p.value(file_value, a) for a in (c - 1.96 * se, c + 1.96 * se))
            same = [k for k, q in MODEL_PARAMETERS.items() if q.same_part_as == term.name]
            parameters.append(FoundParameter(term.name, file_value, p.value(file_value, c),
                                             [float(np.nan_to_num(ends[0], nan=p.low)),
                                              float(np.nan_to_num(ends[1], nan=p.high))], abs(c) * rms, same))
            continue
        effect = EFFECTS[term.name]
        if term.law is not None:  # the oil's law as the set has it (fitted once, with the viscosity law)
            term = replace(term, law=cal.oil_law(final))
        ci = {effect.coefficient: cal.coefficient_interval(final, i, out.ranges.get(term.name))}
        if term.member is not None and term.name in out.ranges:
            ci[effect.member] = out.ranges[term.name]
        if term.second is not None and term.name in out.second_ranges:
            ci[effect.second_member] = out.second_ranges[term.name]
        params = term.params(c)
        effects.append(FoundEffect(term.name, params, ci, abs(c) * rms,
                                   [max(0.0, abs(c) - 1.96 * se) * rms, (abs(c) + 1.96 * se) * rms],
                                   _members_at_bound(term.name, params)))
    return effects, parameters


def _verdict(out, selected: list[Term], delta_nm: float) -> str:
    """``effects_found``, ``no_missing_effect`` (every rejected candidate bounded below ``delta``) or
    ``inconclusive`` (an ambiguous set nobody resolved, or a candidate that could not be bounded)."""
    if any(a.assumed is None for a in out.ambiguous):
        return "inconclusive"
    if selected:
        return "effects_found"
    if all(r.upper_rms_nm < delta_nm for r in out.rejected if not r.reason):
        return "no_missing_effect"
    return "inconclusive"


def _adequacy(data: SampleData, config: Config, cal: Calibrator, full, final: list[Term], selected: list[Term]):
    """How much of the measured loss the calibrated file explains, and by what (:func:`adequacy`)."""
    k0 = len(cal.nuisance)
    blocks = cal.b
    contributions = {term.name: float(np.sum(blocks.count * full.coef[k0 + i] * cal.effective_column(term, final)))
                     / len(data.t_ns) for i, term in enumerate(selected)}
    # the model's share is the model's as the file evaluates it: at its calibrated parameters and at the
    # oil's viscosity (a Fr-scaling effect is the model's rolling part at η(θ), not a loss of its own)
    in_model = {k for k in contributions if k in MODEL_PARAMETERS or EFFECTS[k].scales_fr}
    model_mean = float(np.mean(data.model_loss)) + sum(contributions[k] for k in in_model)
    return adequacy(model_mean, float(np.mean(data.measured_loss)),
                    {k: v for k, v in contributions.items() if k not in in_model},
                    config.estimator.paper_model, viscous=any(k in EFFECTS for k in in_model))


def not_written_because(error_before: ErrorStats, error_after: ErrorStats, accepted: int) -> str | None:
    """Why a calibration is not written (None: it is): with anything accepted, it would predict the
    held-out data no better than the parameter file calibrated (nothing accepted: the file as it was)."""
    if accepted and error_after.rmse_nm >= error_before.rmse_nm:
        return (f"not written: the calibrated parameters would predict the held-out data worse than the file alone "
                f"(RMSE {error_after.rmse_nm:.4g} >= {error_before.rmse_nm:.4g} N·m)")
    return None


def _flat(config: Config) -> dict:
    return config.to_flat()


def _holdout_text(blocks: Blocks, folds: int) -> str:
    if blocks.steady_state:
        return (f"{folds}-fold cross-validation over the rows of the steady-state table(s) (each row a dwell mean, "
                f"weighted equally; fold k holds every {folds}th row, so every fold spans the map); errors are of the "
                f"rows' losses predicted by a fit that did not see them ({len(blocks.y)} rows; no sensor noise model: "
                "a table's rows are taken as exact means)")
    return (f"{folds}-fold cross-validation grouped by dwell ({int(blocks.dwell.max()) + 1} dwells of steady "
            f"operation, at most 5 s each; whole dwells held out, never single rows); errors are of {blocks.block_s:g} "
            f"s block means of every held-out block, predicted by a fit that did not see its fold "
            f"({len(blocks.y)} blocks)")


RESIDUAL_BINS = 8  #: quantile bins of an input for the residual's structure
STRUCTURE_SHARE = 0.1  #: below this share of the variance, no input explains the residual left


def residual_structure(blocks: Blocks, residual: np.ndarray) -> dict:
    """How much of the unexplained (held-out) residual each input explains: the weighted share of its
    variance carried by its mean over ``RESIDUAL_BINS`` quantile bins of speed, torque, oil
    temperature, and by direction (motoring/overrun, forward/reverse).  The strongest is where a
    person looks first when the vocabulary has no answer."""
    w = blocks.count.astype(float)
    r = residual - np.average(residual, weights=w)
    total = float(np.sum(w * r * r))
    inputs = {"speed": np.abs(blocks.speed), "torque": np.abs(blocks.torque), "temperature": blocks.temperature}
    shares: dict[str, float] = {}
    for name, x in inputs.items():
        ok = np.isfinite(x)
        if ok.sum() < 2 * RESIDUAL_BINS or np.ptp(x[ok]) <= 0 or total <= 0:
            continue
        edges = np.unique(np.quantile(x[ok], np.linspace(0, 1, RESIDUAL_BINS + 1)))
        shares[name] = _explained(np.digitize(x[ok], edges[1:-1]), r[ok], w[ok], total)
    for name, key in (("direction", np.sign(blocks.speed)), ("power flow", np.sign(blocks.speed * blocks.torque))):
        if len(np.unique(key)) > 1 and total > 0:
            shares[name] = _explained(np.unique(key, return_inverse=True)[1], r, w, total)
    strongest = max(shares, key=shares.get) if shares else None
    if total <= 0 or strongest is None:
        statement = "nothing left to explain"
    elif shares[strongest] < STRUCTURE_SHARE:
        statement = (f"the residual left shows no structure: no input carries more than "
                     f"{100 * shares[strongest]:.0f} % of its variance (noise)")
        strongest = None
    else:
        statement = (f"the residual left depends most on {strongest} ({100 * shares[strongest]:.0f} % of its "
                     f"variance is its mean per {strongest} bin)")
    return {"explained_share": {k: round(v, 4) for k, v in shares.items()}, "strongest": strongest,
            "statement": statement}


def _explained(label: np.ndarray, r: np.ndarray, w: np.ndarray, total: float) -> float:
    sums = np.bincount(label, weights=w * r)
    weights = np.bincount(label, weights=w)
    means = np.divide(sums, weights, out=np.zeros_like(sums), where=weights > 0)
    return float(np.sum(weights * means * means) / total)


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


def _is_sensor_error(term_name: str) -> bool:
    """A term that is an effect corrupting the torque reading (not a model parameter, not a loss)."""
    effect = EFFECTS.get(term_name)
    return effect is not None and effect.reading_error is not None


def _refit_sensor_errors(cal: Calibrator, data: SampleData, final: list[Term], config: Config, how: _Analysis,
                         iterations: int = 3) -> tuple[Calibrator, list[Term], SampleData]:
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
        b, g = reading_errors({name: {EFFECTS[name].coefficient: float(f.coef[k0 + i])}
                               for i, name in enumerate(names) if _is_sensor_error(name)})
        t_c = (data.torque - b) / (1.0 + g)
        corrected = dc_replace(
            data, torque=t_c, model_loss=model.loss_magnitude(t_c, data.speed), fr_part=model.fr_part(t_c, data.speed),
            parts=model.parts(t_c, data.speed))
        new = Calibrator(make_blocks(corrected, how.block_s, how.folds, like=cal.b), cal.delta, cal.alpha,
                         cal.min_improvement)
        new.log = cal.log
        final = [new._with_member(t, t.member) if t.member is not None else members(new.b, t.name)[0] for t in final]
        cal = new
    return cal, final, corrected


def _calibrated_config(config: Config, effects: list[FoundEffect], parameters: list[FoundParameter]) -> Config:
    """``config`` with exactly the accepted effects enabled, at their fitted parameters, and the
    model's parameters calibrate changed."""
    flat = {k: v for k, v in config.to_flat().items()}
    for name in EFFECTS:
        flat[f"effects.{name}.enabled"] = False
    for e in effects:
        flat[f"effects.{e.name}.enabled"] = True
        for q in EFFECTS[e.name].parameters:
            flat[f"effects.{e.name}.{q.key}"] = e.params[q.short]
    for p in parameters:
        flat[p.name] = p.fitted
    return validate(flat)


def calibrated_yaml(result: CalibrationResult, sources: Sequence[str]) -> str:
    header = (
        "# Written by `rollergear calibrate` from " + ", ".join(map(str, sources)) + "\n"
        f"# verdict: {result.verdict}; held-out RMSE {result.error_before.rmse_nm:.4g} -> "
        f"{result.error_after.rmse_nm:.4g} N·m\n"
        + "".join(f"# {p.name}: {p.fitted:.6g} (was {p.file:.6g}), calibrated: {MODEL_PARAMETERS[p.name].label}\n"
                  for p in result.parameters)
        + "".join(f"# {n}\n" for n in result.notes)
    )
    return config_to_yaml(result.config, header)
