"""One analysis of a set of samples (:func:`calibrate_once`, for :mod:`.calibrate`): the selection from the
parameter file's own effects with the engineer's line weighed beside it, a refit at the corrected torque
where a sensor error was taken, the errors before (the file as given) and after (held out), the file to
write, and the claim -- what that file leaves of these samples, replayed through the one forward path."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from .blocks import Blocks, make_blocks
from .forward import Selection, select
from .noise import sensor_delta
from .nuisance import lag_channel, lag_from_fit, median_period_s, ChannelLag
from .outcome import CalibrationResult, FoundEffect, FoundParameter
from .samples import SampleData, file_residual
from ..core.lagalign import LAG_CHANNELS
from ..core.modelform import ModelForm
from .handfit import hand_fit, weigh
from .jointfit import fitted_covariance
from .leastsquares import Fit
from .selection import Calibrator, ErrorStats, Term, error_stats, members
from .structure import adequacy, angle_spectrum, residual_structure
from .written import calibrated_config, changed, not_written_because
from ..base.errors import BagError, ParameterError
from ..core.effects import EFFECTS, reading_errors, viscosity_law
from ..core.model import LossModel
from ..core.modelparams import MODEL_PARAMETERS
from ..core.oil import vogel_from_datasheet
from ..core.params import Config

#: a data sheet's viscosity law: Vogel B searched within this factor, C within this span [K], and the
#: viscosity at the reference temperature within this factor of the data sheet's
DATASHEET_B_FACTOR = 1.5
DATASHEET_C_SPAN_K = 40.0
DATASHEET_ETA_FACTOR = 1.5


@dataclass(frozen=True)
class Analysis:
    """How :func:`calibrate` analyses (its arguments besides the data and the parameter set)."""

    delta_nm: float | None
    block_s: float
    folds: int
    stage: Callable[[str], None]
    assume: Sequence[str]


def calibrate_once(data: SampleData, config: Config, how: Analysis, before: CalibrationResult | None = None,
                    applied: Mapping[str, float] | None = None) -> CalibrationResult:
    """One analysis with ``config``'s model (:func:`calibrate`); ``before``: the errors "before" are
    that result's (the parameter file as given), when this one switched the paper's model off;
    ``applied``: the lags the samples were aligned by (channel -> s).  In named steps: select the terms,
    the errors before, the file to write, the file as given where a refit predicts no better, the claim
    the written file makes, the result."""
    sel = _select_terms(data, config, how)
    before_errors = _errors_before(data, sel.blocks0, config, before)
    cal, out = sel.cal, sel.out
    blocks = cal.b
    # held out: exactly what the file writes -- the accepted terms, fitted with the rest of the set
    # (nuisance columns, ambiguous sets kept in the fit) on the other folds
    pred_after = cal.cv_predictions(sel.final, only_terms=len(sel.selected))
    err_a = blocks.y - pred_after
    error_after = error_stats(err_a, blocks.measured, blocks.count)
    verdict = _verdict(out, sel.selected, cal.delta)
    s_a = sel.data_c.residual - pred_after[np.repeat(np.arange(len(blocks.y)), blocks.count)]
    sample_level = {"before": before_errors.sample_level, "after": error_stats(s_a, data.measured_loss,
                                                                                np.ones(len(s_a)))}
    new_config = _config_to_write(data, config, sel, verdict, applied)
    notes: list[str] = [data.ratio_text] if data.ratio_text else []
    effects = sel.effects
    same_terms = {e.name for e in effects} == {t.name for t in sel.start} and not sel.parameters
    if sel.start and same_terms and before is None and error_after.rmse_nm >= before_errors.error.rmse_nm:
        # the file's own effects, refitted, predict no better than as given: the file stands
        notes.append(f"the parameter file's effects ({', '.join(t.name for t in sel.start)}) predict the held-out "
                     f"data as well as a refit of them (RMSE {before_errors.error.rmse_nm:.4g} against "
                     f"{error_after.rmse_nm:.4g} N·m): written as given")
        effects = [_as_given(e, config) for e in effects]
        new_config = before_errors.given
        error_after, pred_after = before_errors.error, sel.blocks0.y - before_errors.block_residual
        err_a = before_errors.block_residual
    # the claim is the file: what the given and the written file leave of these samples, each replayed
    # through the one forward path (the estimator as replay runs it); the held-out error claimed is
    # never below what the written file leaves of the very samples it was fitted to
    written_blocks, sample_level["after"], s_a = _file_errors(data, sel.blocks0, new_config)
    if written_blocks.rmse_nm > error_after.rmse_nm:
        notes.append(f"the written file replayed on these samples leaves {written_blocks.rmse_nm:.4g} N·m (block "
                     f"means), more than the selection's held-out {error_after.rmse_nm:.4g} N·m: the error after is "
                     "the written file's")
        error_after = written_blocks
    why_not = not_written_because(before_errors.error, error_after, changed(config, new_config))
    written = why_not is None
    if not written:
        verdict = "inconclusive"
        notes.append(why_not)
    fit_adequacy = _adequacy(data, config, cal, sel.full, sel.final, sel.selected)
    angle = angle_spectrum(data.t_ns * 1e-9, data.bag_id, data.speed, _output_speed(data), s_a) \
        if not data.steady_state else None
    result = CalibrationResult(
        verdict, effects, before_errors.error, error_after, _holdout_text(blocks, how.folds), int(len(data.t_ns)),
        cal.delta, out.rejected, out.ambiguous, out.unavailable, cal.log, sample_level, new_config, fit_adequacy,
        blocks, pred_after, sel.parameters, written, notes, out.negative,
        residual_structure(blocks, err_a, angle=angle, spin_test=data.spin_test))
    result.before_residual, result.after_residual = before_errors.sample_residual, s_a
    result.decisions, result.minimum, result.untestable = out.decisions, cal.minimum, out.untestable
    result.lags, result.inertia = _nuisances(cal, sel.full, data, applied or {})
    result.from_file = [t.name for t in sel.start]
    result.hand_fit = sel.hand
    result.groups = _heldout_groups(blocks, err_a)
    result.calibrator, result.terms = cal, sel.final
    return result


@dataclass
class _Selected:
    """What the selection took (step 1 of :func:`calibrate_once`)."""

    cal: Calibrator  #: refitted at the corrected torque where a sensor error was taken
    out: Selection  #: the selection's outcome (:func:`.forward.select`)
    blocks0: Blocks  #: the block means at the torque as read
    data_c: SampleData  #: the samples at the corrected torque
    start: list[Term]  #: the parameter file's own effects
    selected: list[Term]
    final: list[Term]  #: the selected terms and the provisional ones
    full: Fit  #: the final terms fitted on every block
    effects: list[FoundEffect]
    parameters: list[FoundParameter]
    hand: dict | None  #: the engineer's least-squares line, weighed on the same folds


def _select_terms(data: SampleData, config: Config, how: Analysis) -> _Selected:
    """The selection from the file's own effects, the hand fit weighed beside it, a refit at the corrected
    torque where a sensor error was taken, the values kept in range."""
    blocks0, cal, ranges = _calibrator(data, config, how)
    start = _file_terms(cal, config)
    out = select(cal, start, how.assume, _value_check(config, ranges))
    # the engineer's least-squares line on the same folds: the written file is never worse than it
    hand = weigh(cal, out, hand_fit(cal, _value_check(config, ranges)))
    if hand is not None and hand["written"]:  # the line is written as it was weighed: through the points' means
        cal = cal.at_operating_points()
    selected: list[Term] = out.selected
    final = selected + out.provisional
    data_c = data
    if any(_is_sensor_error(t.name) for t in final):
        how.stage("refit at the corrected torque")
        cal, final, data_c = _refit_sensor_errors(cal, data, final, config, how)
        selected = final[: len(selected)]
    how.stage("held-out errors and intervals")
    full, selected, final = _in_range(cal, selected, final, _value_check(config, ranges), out)
    effects, parameters = _found(cal, out, full, final, selected, config)
    return _Selected(cal, out, blocks0, data_c, start, selected, final, full, effects, parameters, hand)


@dataclass(frozen=True)
class _Before:
    """The parameter file as given, on these samples (step 2 of :func:`calibrate_once`)."""

    given: Config  #: at the recordings' speed noise and ratio where its own were off them
    error: ErrorStats  #: block means
    sample_level: ErrorStats  #: per sample
    sample_residual: np.ndarray
    block_residual: np.ndarray


def _errors_before(data: SampleData, blocks0: Blocks, config: Config, before: CalibrationResult | None) -> _Before:
    """What the file as given leaves (rig facts corrected either way, said), replayed through the one forward
    path; or ``before``'s, when this analysis switched the paper's model off."""
    given = config.as_given()
    given = given.with_values(data.overrides) if data.overrides else given
    if before is None:
        error_before, sample_before, s_b = _file_errors(data, blocks0, given)
    else:
        s_b, error_before = before.before_residual, before.error_before
        sample_before = before.sample_level["before"]
    return _Before(given, error_before, sample_before, s_b, blocks0.mean(s_b))


def _config_to_write(data: SampleData, config: Config, sel: _Selected, verdict: str,
                     applied: Mapping[str, float] | None) -> Config:
    """The file to write: the accepted effects and parameters, the lags the samples were aligned by (the
    written file aligns them as the selection did), the covariance, the model form, the table's ratio and
    the recordings' rig facts where the file's were off them."""
    cal = sel.cal
    new_config = calibrated_config(config, sel.effects, sel.parameters, kept=_untested_file_effects(config, cal))
    new_config = new_config.with_values({f"estimator.{c}_lag_s": (applied or {}).get(c, 0.0) for c in LAG_CHANNELS})
    covariance = fitted_covariance(cal, sel.final, len(sel.selected), config)
    new_config = new_config.with_values({"calibration.covariance": covariance.to_text() if covariance else ""})
    new_config = new_config.with_values({"calibration.model_form": _model_form(
        cal, sel.out, sel.full, sel.final, sel.selected, data, verdict).to_text()})
    if data.ratio is not None:  # the table's own ratio: what a map of the file states
        new_config = new_config.with_values({"gearbox.ratio": data.ratio})
    if data.overrides:  # the recordings' speed noise and ratio, where the file's were off them
        new_config = new_config.with_values(data.overrides)
    return new_config


def _file_terms(cal: Calibrator, config: Config) -> list[Term]:
    """The parameter file's accepted effects as terms at its exponents (where the selection starts)."""
    terms = []
    for name, params in config.effects.active().items():
        if name not in cal.b.testable:
            continue
        effect = EFFECTS[name]
        law = tuple(params[k] for k in ("B", "C", "theta_ref")) if effect.oil_law else None
        member = second = None
        if effect.member is not None:
            lo, hi = cal.search_ranges(name)[effect.member]
            member = float(min(max(params[effect.member], lo), hi))
        if effect.second_member is not None:
            lo, hi = cal.search_ranges(name)[effect.second_member]
            second = float(min(max(params[effect.second_member], lo), hi))
        terms.append(Term(name, cal.b.column(name, member, second, law), member, second, law))
    return terms


def _untested_file_effects(config: Config, cal: Calibrator) -> list[str]:
    """The parameter file's accepted effects this data cannot test: written as they are."""
    return [n for n in config.effects.enabled() if n not in cal.b.testable]


def _model_form(cal: Calibrator, out, full, final: list[Term], selected: list[Term], data: SampleData,
                verdict: str) -> ModelForm:
    """What the written file leaves unresolved (the terms kept in the fit and not written, at their
    fitted values; the ambiguous sets in words), the largest speed and torque analysed and the span of oil
    temperatures (to 0.01 °C, outward: the extremes stay inside it)."""
    k0 = len(cal.nuisance)
    alternatives = []
    for i, term in enumerate(final[len(selected):], start=len(selected)):
        if term.name in EFFECTS:
            alternatives.append((term.name, term.params(float(full.coef[k0 + i]))))
    unresolved = "; ".join(f"{' or '.join(a.effects)} (the data cannot tell them apart: needs {a.needs})"
                           for a in out.ambiguous if a.assumed is None and a.taken is None)
    speed, torque = np.abs(data.speed), np.abs(data.torque)
    theta = data.temperature[np.isfinite(data.temperature)]
    return ModelForm(verdict, tuple(alternatives), unresolved,
                     float(speed.max()) if len(speed) else math.inf, float(torque.max()) if len(torque) else math.inf,
                     (math.floor(100 * float(theta.min())) / 100, math.ceil(100 * float(theta.max())) / 100)
                     if len(theta) else None)


def _file_errors(data: SampleData, blocks: Blocks, config: Config) -> tuple[ErrorStats, ErrorStats, np.ndarray]:
    """What the parameter file ``config`` leaves of ``data``'s measured loss, replayed through the one
    forward path (:func:`~.samples.file_residual`): its errors over ``blocks``' means and over the
    samples (those it measures a loss of), and the residual of each sample (0 where it measures none)."""
    r = file_residual(data, config)
    ok = np.isfinite(r)
    sample = error_stats(r[ok], data.measured_loss[ok], np.ones(int(ok.sum())))
    sums = np.add.reduceat(np.where(ok, r, 0.0), blocks.start)
    n = np.add.reduceat(ok.astype(float), blocks.start)
    has = n > 0
    block = error_stats(sums[has] / n[has], blocks.measured[has], blocks.count[has])
    return block, sample, np.where(ok, r, 0.0)


def _as_given(found: FoundEffect, config: Config) -> FoundEffect:
    """An accepted effect at the parameter file's values (its intervals from the refit)."""
    return replace(found, params=config.effects.params(found.name))


def _nuisances(cal: Calibrator, full, data: SampleData,
               applied: Mapping[str, float]) -> tuple[list[ChannelLag], dict | None]:
    """Each channel's lag behind the drive torque (what the samples were aligned by plus what this fit
    still finds) and the drive's inertia, with 95 % intervals."""
    period = median_period_s(data)
    lags, inertia = [], None
    for k, name in enumerate(cal.nuisance_names):
        c, se = float(full.coef[k]), float(math.sqrt(max(full.cov[k, k], 0.0)))
        channel = lag_channel(name)
        if channel is not None:
            lags.append(lag_from_fit(name, c, se, period, applied.get(channel, 0.0)))
        elif name == "inertia":
            inertia = {"j_kg_m2": c, "ci95": [c - 1.96 * se, c + 1.96 * se],
                       "text": f"the drive's inertia between the torque sensor and the loss: J = {c:.4g} kg·m² "
                               f"(95 %: {c - 1.96 * se:.4g} to {c + 1.96 * se:.4g}), J·dω/dt removed in the analysis"}
    for channel, lag in applied.items():  # aligned, and nothing left of it in the fit
        if not any(x.channel == channel for x in lags):
            lags.append(ChannelLag(channel, lag, (lag, lag), True))
    return lags, inertia


def _output_speed(data: SampleData) -> np.ndarray:
    """The output speed of each sample: measured, else the drive's over the ratio."""
    ratio = data.speed_ratio if data.speed_ratio and data.speed_ratio > 0 else 1.0
    if data.out_speed is None:
        return data.speed / ratio
    return np.where(np.isnan(data.out_speed), data.speed / ratio, data.out_speed)


def _calibrator(data: SampleData, config: Config, how: Analysis) -> tuple[Blocks, Calibrator, dict]:
    """The block means and the selection over them; with an oil's data sheet, the viscosity law's
    start and range from it (and the parameters it narrows: name -> range)."""
    how.stage("block means")
    blocks = make_blocks(data, how.block_s, how.folds)
    if len(blocks.y) < 4 * how.folds:
        raise BagError(f"only {len(blocks.y)} blocks of {how.block_s:g} s: too little data to calibrate")
    cal = Calibrator(blocks, how.delta_nm, sensors_nm=sensor_delta(data, config))
    cal.stage = how.stage
    cal.log.append(cal.minimum.text)
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
            calibrated_config(config, [FoundEffect(term.name, term.params(coef), {}, 0.0, [0.0, 0.0])], [])
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
            lo, hi = _interval_over_ranges(cal, out, final, i, c - 1.96 * se, c + 1.96 * se)
            ends = sorted(p.value(file_value, a) for a in (lo, hi))
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


def _in_range(cal: Calibrator, selected: list[Term], final: list[Term], check: Callable[[Term, float], str | None],
              out) -> tuple[Fit, list[Term], list[Term]]:
    """The fit of the whole set, without the accepted terms whose value leaves its range in it: a term
    checked when it was accepted can turn negative once fitted with all the others (the ambiguous
    sets' members, the refit at the corrected torque).  Each one dropped is logged, and a negative
    friction noted in ``out.negative`` (the analysis then weighs the paper's model switched off)."""
    full = cal.fit(final)
    while True:
        k0 = len(cal.nuisance)
        reasons = [(i, check(t, float(full.coef[k0 + i]))) for i, t in enumerate(selected)]
        bad = next(((i, why) for i, why in reasons if why), None)
        if bad is None:
            return full, selected, final
        i, why = bad
        name = selected[i].name
        cal.log.append(f"{name}: not accepted: fitted with the whole set, {why}")
        if float(full.coef[k0 + i]) < 0 and name in EFFECTS and name not in out.negative:
            out.negative.append(name)
        selected, final = selected[:i] + selected[i + 1:], final[:i] + final[i + 1:]
        full = cal.fit(final)


def _interval_over_ranges(cal: Calibrator, out, final: list[Term], i: int, lo: float, hi: float) -> tuple[float, float]:
    """Term ``i``'s coefficient interval ``[lo, hi]`` widened over the 95 % ranges of the exponents (and
    Vogel B, C) of the other terms fitted with it: a model parameter's level and an effect's shape
    are fitted together, so the level's interval covers the shapes the data allow."""
    for j, t in enumerate(final):
        if j == i or t.member is None:
            continue
        ends = [(m, None) for m in out.ranges.get(t.name, ())] + [(None, s) for s in out.second_ranges.get(t.name, ())]
        for member, second in ends:
            alt = list(final)
            alt[j] = cal._with_member(t, t.member if member is None else member, second)
            c, se = cal.coefficient(alt, i)
            lo, hi = min(lo, c - 1.96 * se), max(hi, c + 1.96 * se)
    return lo, hi


def _verdict(out, selected: list[Term], delta_nm: float) -> str:
    """``effects_found``, ``no_missing_effect`` (every rejected candidate bounded below ``delta``) or
    ``inconclusive`` (an ambiguous set nobody resolved, or a candidate that could not be bounded)."""
    if any(a.assumed is None and a.taken is None for a in out.ambiguous):
        return "inconclusive"
    if selected:
        return "effects_found"
    if all(r.upper_rms_nm < delta_nm for r in out.rejected if not r.ambiguous and "negative" not in r.reason
           and "bound of its search" not in r.reason and "physical range" not in r.reason):
        return "no_missing_effect"
    return "inconclusive"


def _adequacy(data: SampleData, config: Config, cal: Calibrator, full, final: list[Term], selected: list[Term]):
    """How much of the measured loss the calibrated file explains, and by what (:func:`.structure.adequacy`)."""
    k0 = len(cal.nuisance)
    blocks = cal.b
    contributions = {term.name: float(np.sum(blocks.count * full.coef[k0 + i] * cal.effective_column(term, final)))
                     / len(data.t_ns) for i, term in enumerate(selected)}
    # the model's share is the model's as the file evaluates it: at its calibrated parameters and at the
    # oil's viscosity (a Fr-scaling effect is the model's rolling part at η(θ), not a loss of its own)
    in_model = {k for k in contributions if k in MODEL_PARAMETERS or EFFECTS[k].scales_fr}
    model_mean = float(np.mean(data.model_loss)) + sum(contributions[k] for k in in_model)
    # a sensor's error is no loss, a difference between directions no loss of its own: said apart
    apart = [k for k in contributions if k not in in_model and (not EFFECTS[k].physical or EFFECTS[k].signed)]
    measured = float(np.mean(data.measured_loss)) - sum(contributions[k] for k in apart)
    losses = {k: v for k, v in contributions.items() if k not in in_model and k not in apart}
    return adequacy(model_mean, measured, losses, config.estimator.paper_model,
                    viscous=any(k in EFFECTS for k in in_model), apart=apart)


def _flat(config: Config) -> dict:
    return config.to_flat()


def _heldout_groups(blocks: Blocks, err: np.ndarray) -> list[dict]:
    """The held-out error of each operating-point group (:mod:`.grouping`), the worst first."""
    groups = blocks.groups
    if groups is None or not len(err):
        return []
    out = []
    for g, label in enumerate(groups.labels):
        k = groups.group == g
        n = float(np.sum(blocks.count[k]))
        if n <= 0:
            continue
        rmse = float(np.sqrt(np.average(err[k] ** 2, weights=blocks.count[k])))
        out.append({"operating_point": label, "samples": int(n), "blocks": int(np.count_nonzero(k)),
                    "heldout_rmse_nm": rmse, "heldout_mean_nm": float(np.average(err[k], weights=blocks.count[k]))})
    return sorted(out, key=lambda r: -r["heldout_rmse_nm"])


def _holdout_text(blocks: Blocks, folds: int) -> str:
    groups = blocks.groups
    if groups is not None and groups.by_operating_point:
        what = "rows of the steady-state table(s), each its own operating point" if blocks.steady_state else (
            f"{len(groups.labels)} operating points (direction, speed and load in 10 % bins"
            + (", oil temperature" if any("oil" in x for x in groups.labels) else "")
            + f"; a run that holds one is one, {100 * groups.steady_share:.0f} % of the samples in such runs)")
        return (f"{folds}-fold cross-validation over {what}: every fold holds out whole operating points, both "
                "directions of a speed bin together, spread over the speeds and loads, so each is predicted by a fit "
                f"that saw the others but never it; errors are of the {blocks.block_s:g} s block means "
                f"({len(blocks.y)} blocks)" if not blocks.steady_state else
                f"{folds}-fold cross-validation over {what}: every fold holds out whole operating points, spread over "
                f"the speeds and loads; errors are of the rows' losses predicted by a fit that did not see them "
                f"({len(blocks.y)} rows; no sensor noise model: a table's rows are taken as exact means)")
    if blocks.steady_state:
        return (f"{folds}-fold cross-validation over the rows of the steady-state table(s) (each row a dwell mean, "
                f"weighted equally; fold k holds every {folds}th row, so every fold spans the map); errors are of the "
                f"rows' losses predicted by a fit that did not see them ({len(blocks.y)} rows; no sensor noise model: "
                "a table's rows are taken as exact means)")
    few = (f"only {len(groups.labels)} operating point(s), fewer than the folds: held out by time within them "
           "(the fit is judged where it was fitted); " if groups is not None else "")
    return few + (f"{folds}-fold cross-validation grouped by dwell ({int(blocks.dwell.max()) + 1} dwells of steady "
            f"operation, at most 5 s each, a transient cut into shorter blocks; whole dwells held out, never single "
            f"rows); errors are of {blocks.block_s:g} s block means of every held-out block, predicted by a fit that "
            f"did not see its fold ({len(blocks.y)} blocks)")


def _members_at_bound(name: str, params: dict[str, float]) -> list[str]:
    """Members within 0.1 % of their range's width of a bound (a bounded search stops just inside)."""
    return [short for short, (lo, hi) in EFFECTS[name].profiled_ranges().items()
            if min(abs(params[short] - lo), abs(params[short] - hi)) <= 1e-3 * (hi - lo)]


def _is_sensor_error(term_name: str) -> bool:
    """A term that is an effect corrupting the torque reading (not a model parameter, not a loss)."""
    effect = EFFECTS.get(term_name)
    return effect is not None and effect.reading_error is not None


def _refit_sensor_errors(cal: Calibrator, data: SampleData, final: list[Term], config: Config, how: Analysis,
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
        new.minimum = cal.minimum
        new.log = cal.log
        if cal.point_means:
            new = new.at_operating_points()
        final = [new._with_member(t, t.member) if t.member is not None else members(new.b, t.name)[0] for t in final]
        cal = new
    return cal, final, corrected
