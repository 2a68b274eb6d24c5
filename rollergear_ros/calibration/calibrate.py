"""Close the loop: trace the residual to effects the model lacks, fit them, report before/after.

Procedure (``docs/closing-the-loop.md``):

1. **Measured loss** ``T_loss,meas = (T_in·ω_in − T_out·ω_out)/|ω_in|`` (any quadrant) and the
   residual ``y = T_loss,meas − T_loss,model`` per sample (never the efficiency), the model being the
   paper's at the parameter file's values (:mod:`.samples`; the speed reading's noise learned or
   checked against the recording).
2. **Block averages** (:mod:`.blocks`): samples averaged over short blocks (default 0.25 s, never
   across a recording, a sign change of ω or T, or a gap; a transient cut into shorter ones).  Every
   candidate term is linear in its coefficient, so block means of the regressors keep the relation
   exact while noise averages out.  Blocks weigh by their samples (a clearly noisier one less).
3. **Operating points and folds** (:mod:`.grouping`): a run that holds one operating point (a test
   plan's steady run between pauses) is one, elsewhere a dwell of consecutive blocks; the same one met
   again is one group; 5-fold cross-validation holds out whole groups (never part of one, never random
   rows), so a fit is judged where it must interpolate.
4. **Candidates** are the physical laws of the vocabulary and the model's own parameters, one column
   each; a law's exponent (``p``, ``q``) or Vogel ``B``/``C`` is profiled (:mod:`.selection`).  The
   rig's nuisances -- each channel's lag behind the drive torque, the drive's inertia -- are always
   in the fit (:mod:`.nuisance`); a lag worth it is applied to the samples and the analysis run again.
5. **Selection** (:mod:`.forward`) from the parameter file's own effects: every candidate tested
   (a law with an exponent as its line unless its curve predicts held-out operating points better; a
   law only where the data vary its argument), the first that passes at each step accepted --
   significance (cluster-robust by dwell, α = 0.01 Bonferroni-corrected), the lower 95 % bound of its
   RMS contribution above δ, held-out RMSE better by more than 2 % -- then a backward check; two
   readings of one part of the loss both named, each with what ``--assume`` of it writes, the file with
   fewer terms written; columns the data cannot tell apart make the verdict *inconclusive* unless
   ``--assume`` chooses.  The engineer's least-squares line (:mod:`.handfit`) is weighed beside it and
   written where it predicts the held-out operating points better.
6. **Verdict**: ``effects_found``; ``no_missing_effect`` (every candidate's upper 95 % bound < δ); or
   ``inconclusive``.  Errors before (the parameter file as given) and after (exactly what the result
   writes) are on held-out dwells; a result that would predict worse than the file is not written.

δ, the practical minimum effect size, comes from what the data can tell (:mod:`.noise`): 3 × the
standard error of a block mean at one operating point, or the sensors' stated accuracy, or the
user's ``--delta``; the result says which.  No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from .blocks import Blocks, make_blocks
from .forward import Selection, select
from .noise import sensor_delta
from .nuisance import apply_lags, lag_channel, lag_from_fit, median_period_s, ChannelLag
from .outcome import CalibrationResult, Change, FoundEffect, FoundParameter, segment_summary
from .samples import SampleData, file_residual, load_samples
from ..core.lagalign import LAG_CHANNELS
from ..core.modelform import ModelForm
from .segments import differing_recording, find_changes, in_time_order
from .handfit import hand_fit, weigh
from .drift import find_drift
from .jointfit import fitted_covariance
from .leastsquares import Fit
from .selection import Calibrator, ErrorStats, Term, error_stats, members
from .structure import adequacy, angle_spectrum, residual_structure
from .written import calibrated_config, changed, describing, not_written_because
from ..base.errors import BagError, ParameterError, UsageError
from ..base.instants import Instant, iso_ns
from ..core.effects import EFFECTS, reading_errors, viscosity_law
from ..core.model import LossModel
from ..core.modelparams import MODEL_PARAMETERS
from ..core.oil import vogel_from_datasheet
from ..core.params import Config

__all__ = ["CalibrationResult", "CalibrationSettings", "SampleData", "calibrate", "load_samples"]


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
    #: effects otherwise stays in the fit unreported and makes the verdict inconclusive), or to take
    #: between two readings of one part of the loss; what the user knows of the rig decides
    assume: Sequence[str] = ()
    #: changes inside the recordings: "latest" (calibrate the stretch after the last), "each" (also
    #: every stretch), "off" (all samples at once)
    segments: str = "latest"
    #: the window analysed: seconds after the first sample analysed (the end not included), or an instant on the
    #: recordings' clock (:class:`~base.instants.Instant`, included); None: open
    start_s: float | Instant | None = None
    end_s: float | Instant | None = None


def calibrate(data: SampleData, config: Config,
              settings: CalibrationSettings = CalibrationSettings()) -> CalibrationResult:
    """Run the whole analysis on loaded samples (``settings``: :class:`CalibrationSettings`).

    Candidates are the registry's effects and the model's own parameters (:mod:`core.modelparams`);
    none is accepted as a negative friction, at the bound of its exponent's search, or outside its
    physical range.  The parameter file's accepted effects are where the selection starts, and the
    file as given is the "before".  A channel that lags the drive torque clearly is aligned and the
    analysis run again on the aligned samples.  When candidates were set aside for needing a
    negative friction (the paper's model over-predicts), the analysis is repeated with the paper's
    model switched off and the one that predicts held-out data better is the result, saying so.
    A change inside the recordings (:mod:`.segments`) is said, and the latest stretch after it is
    analysed (``settings.segments``: ``latest``; ``each``: every stretch too; ``off``: all at once).
    The errors after are those of exactly the parameter file the result writes; a file that would
    predict held-out data worse than the one calibrated is not written (:attr:`CalibrationResult.written`).
    """
    unknown = [a for a in settings.assume if a not in EFFECTS]
    if unknown:
        raise UsageError(f"unknown effect(s) to assume: {', '.join(unknown)} (one of {', '.join(EFFECTS)})")
    stage = settings.stage or (lambda text: None)
    how = _Analysis(settings.delta_nm, settings.block_s, settings.folds, stage, tuple(settings.assume))
    config = _without_testable_derived(data, config)
    result = _readings_as_written(data, config, settings, how, _over_time(data, config, settings, how))
    if data.beyond_text:  # left out of the analysis, said with the limit and the setting to raise
        result.notes.append(f"left out as implausible: {data.beyond_text}")
    return result


def _without_testable_derived(data: SampleData, config: Config) -> Config:
    """``config`` without the effects it derived (the oil's data sheet's law) that this data can test: those are
    candidates, fitted whole from where the data sheet starts them; one the data cannot test stays in the model
    as the file states it (:attr:`~core.params.EffectParams.derived`)."""
    from dataclasses import replace

    from .blocks import testability

    derived = config.effects.derived
    if not derived:
        return config
    untestable = testability(data)
    testable = [n for n in derived if not untestable[n]]
    if not testable:
        return config
    e = config.effects
    switches = {n: on and n not in testable for n, on in e.switches.items()}
    kept = tuple(n for n in derived if n not in testable)
    return replace(config, effects=replace(e, switches=switches, derived=kept, set_aside=tuple(testable)))


def _readings_as_written(data: SampleData, config: Config, settings: CalibrationSettings, how: _Analysis,
                         result: CalibrationResult) -> CalibrationResult:
    """Each pair of readings of one part of the loss (:mod:`.forward`) said with the numbers a file of the
    other reading has: the analysis run again with ``--assume`` of it, its parameters and held-out error as
    that file writes them -- and where that file holds fewer terms (effects and model parameters counted
    alike; between equally many, fewer fitted values), it is the result, as the manual's tie-break says."""
    for a in result.ambiguous:
        if a.taken is None or a.assumed is not None:
            continue
        other = [e for e in a.effects if e not in a.taken.split(" + ")]
        if not other:
            continue
        how.stage(f"the other reading: {' + '.join(other)}")
        assumed = [*settings.assume, *other]
        alt = _over_time(data, config, replace(settings, assume=assumed), replace(how, assume=tuple(assumed)))
        mine_said, alt_said = _reading_said(result), _reading_said(alt)
        for r in a.readings:
            r.update(mine_said if r["written"] else alt_said | {
                "params": {e.name: e.params for e in alt.effects if e.name in other}})
        if alt.written and _size(alt) < _size(result):
            # the reading dropped, as --assume of it writes it (not as the selection first took it)
            taken = a.taken.split(" + ")
            assumed = [*settings.assume, *taken]
            back = _over_time(data, config, replace(settings, assume=assumed), replace(how, assume=tuple(assumed)))
            back_said = _reading_said(back) | {"params": {e.name: e.params for e in back.effects if e.name in taken}}
            twin = next((b for b in alt.ambiguous if set(b.effects) == set(a.effects)), None)
            if twin is not None:
                twin.assumed, twin.taken = None, " + ".join(other)
                twin.readings = [dict(r, written=not r["written"], **(back_said if r["written"] else {}))
                                 for r in a.readings]
            alt.notes.insert(0, f"two readings of one part of the loss: {' + '.join(other)} holds fewer terms "
                                f"({', '.join(alt_said['writes'])} against {', '.join(back_said['writes'])}): taken")
            return alt
    return result


def _reading_said(result: CalibrationResult) -> dict:
    """What a result's file holds and its held-out error (a reading's numbers)."""
    return {"heldout_rmse_nm": result.error_after.rmse_nm,
            "writes": [e.name for e in result.effects] + [p.name for p in result.parameters]}


def _size(result: CalibrationResult) -> tuple[int, int]:
    """A written file's terms (effects and model parameters alike), then its fitted values (coefficients,
    model parameters, exponents not held at a line)."""
    values = len(result.parameters)
    for e in result.effects:  # a member held at the law's line is no fitted value
        effect = EFFECTS[e.name]
        values += 1 + sum(1 for k in e.ci95 if k != effect.coefficient
                          and not (k == effect.member and e.params.get(k) == effect.linear))
    return len(result.effects) + len(result.parameters), values


def _over_time(data: SampleData, config: Config, settings: CalibrationSettings, how: _Analysis) -> CalibrationResult:
    """The analysis of the window, then the changes inside it: the latest stretch after the last (said),
    each stretch (``--segments each``), a drift, or all samples at once."""
    stage = how.stage
    data, window = _window(data, settings.start_s, settings.end_s)
    result = _analyse(data, config, how)
    if settings.segments == "off" or data.steady_state or result.calibrator is None:
        result.stretch = window or "every sample"
        return result
    stage("changes inside the recordings")
    apart: list[str] = []
    odd = differing_recording(result.calibrator, result.terms, apart)
    if odd is not None:
        raise UsageError(
            f"recording {data.given_index(odd.bag) + 1} of those given differs from the others where their operating "
            f"points meet (held-out RMSE {odd.heldout_one_nm:.4g} N·m with one fit, {odd.heldout_two_nm:.4g} with one "
            f"of its own; it changes the loss by {odd.rms_change_nm:.3g} N·m RMS): a change or another gearbox, and "
            "the recordings' times overlap, so which came later is not known -- calibrate them apart, give them "
            "times that put them one after another, or --segments off to fit them as one")
    confounded: list[str] = []
    splits = find_changes(result.calibrator, result.terms, confounded)
    if not splits:
        result.stretch = window or ("every sample (no change found inside the recordings)"
                                    if in_time_order(result.calibrator.b) else
                                    "every sample (the recordings' times overlap: no order in time to search "
                                    "for a change in)")
        result.notes.extend(apart if odd is None and not in_time_order(result.calibrator.b) else confounded)
        return result
    drift = find_drift(result.calibrator, result.terms, splits)
    blocks = result.calibrator.b
    cuts = [int(blocks.start[sp.block]) for sp in splits]  # the first sample after each change
    changes = [Change(int(data.t_ns[i]), sp.t_s, sp.ci95_s, sp.rms_change_nm, sp.heldout_one_nm, sp.heldout_two_nm,
                      data.given_index(int(data.bag_id[i])),
                      math.nan if sp.between_recordings else _temperature_at(data, i), sp.between_recordings)
               for i, sp in zip(cuts, splits)]
    n = len(data.t_ns)
    stretches = list(zip([0, *cuts], [*cuts, n]))
    start_s = [0.0, *(sp.t_s for sp in splits)]
    summaries = []
    if settings.segments == "each":
        for (lo, hi), t_lo, t_hi in zip(stretches[:-1], start_s, start_s[1:]):
            stage(f"the stretch from {t_lo:.1f} s")
            part = _analyse(data.select(_between(n, lo, hi)), config, how)
            summaries.append(segment_summary(part, t_lo, t_hi))
    lo = stretches[-1][0]
    stage("the latest stretch")
    latest = data.select(_between(n, lo, n))
    final = _analyse(latest, config, how)
    end_s = float(blocks.t_s[-1] - blocks.t_s[0]) if len(np.unique(data.bag_id)) == 1 else math.nan
    if settings.segments == "each":
        summaries.append(segment_summary(final, start_s[-1], end_s))
    final.segments = summaries
    final.notes.extend(confounded)
    if drift is not None:  # no steps: the latest stretch's conditions, said
        final.drift = drift
        final.stretch = (f"the latest stretch, {len(latest.t_ns):,} samples from {changes[-1].t_s:.1f} s, after a "
                         f"drift of {drift.total_nm:+.3g} N·m over {drift.end_s - drift.start_s:.0f} s (following "
                         f"{drift.follows})" + (f" ({window})" if window else ""))
        final.config = describing(final.config, final.stretch)
        final.notes.insert(0, drift.sentence(changes[-1].t_s))
        return final
    final.changes = changes
    when = ", ".join(c.when() for c in changes)
    final.stretch = (f"the latest stretch, {len(latest.t_ns):,} samples after the change at {changes[-1].when()}"
                     + (f" ({window})" if window else ""))
    final.config = describing(final.config, final.stretch)
    final.notes.insert(0, f"the gearbox changed inside the recordings at {when} (one fit across "
                          f"{'them' if len(changes) > 1 else 'it'}: held-out RMSE {changes[-1].heldout_one_nm:.4g} "
                          f"N·m, a fit on each side {changes[-1].heldout_two_nm:.4g}); the latest stretch is "
                          "calibrated (--segments each: every stretch; --start/--end: a window)"
                          + _time_or_temperature(data, changes))
    return final


def _temperature_at(data: SampleData, i: int) -> float:
    """The oil temperature at sample ``i`` (the median of the samples about it; NaN: none)."""
    near = data.temperature[max(i - 50, 0): i + 50]
    near = near[np.isfinite(near)]
    return float(np.median(near)) if len(near) else math.nan


def _time_or_temperature(data: SampleData, changes: list[Change]) -> str:
    """What to add where the oil's temperature rose (or fell) all along: a change in time and a loss
    that follows the oil are the same on such a recording."""
    ok = np.isfinite(data.temperature)
    if ok.mean() < 0.9 or not any(math.isfinite(c.temperature_c) for c in changes):
        return ""
    from scipy.stats import spearmanr

    rho = float(spearmanr(data.t_ns[ok], data.temperature[ok]).statistic)
    if abs(rho) < MONOTONIC_TEMPERATURE:
        return ""
    at = ", ".join(f"{c.temperature_c:.1f} °C" for c in changes if math.isfinite(c.temperature_c))
    return (f"; the oil passed {at} there, and its temperature {'rose' if rho > 0 else 'fell'} all along: this "
            "recording cannot tell a change in time from a loss that follows the oil's temperature (the same "
            "temperatures at another time can: a second warm-up, a cool-down; --segments off analyses it at once)")


#: a recording whose oil temperature follows time this closely (|Spearman ρ|) confounds the two
MONOTONIC_TEMPERATURE = 0.9


def _between(n: int, lo: int, hi: int) -> np.ndarray:
    keep = np.zeros(n, bool)
    keep[lo:hi] = True
    return keep


def _analyse(data: SampleData, config: Config, how: _Analysis) -> CalibrationResult:
    """One analysis of all of ``data``: aligned where a channel lags, and weighed against the paper's
    model switched off where fits needed a negative friction."""
    result = _calibrate_once(data, config, how)
    first, original, lags = result, data, {}
    for _ in range(MAX_ALIGNMENTS):  # a channel clearly behind the drive torque: aligned, analysed again
        more = {lag.channel: lag.lag_s for lag in result.lags if lag.applied and lag.lag_s != lags.get(lag.channel)}
        if not more:
            break
        how.stage("aligning the channels that lag")
        lags.update(more)
        model = LossModel(config.gearbox, enabled=config.estimator.paper_model)
        data = apply_lags(original, lags, model)
        result = _calibrate_once(data, config, how, applied=lags)
    if lags:
        result.notes.insert(0, "the samples were aligned by the lags found ("
                            + ", ".join(f"{c} {1e3 * v:.3g} ms" for c, v in lags.items())
                            + f"; before aligning, held-out RMSE {first.error_before.rmse_nm:.4g} -> "
                            f"{first.error_after.rmse_nm:.4g} N·m); the written file carries them ("
                            + ", ".join(f"estimator.{c}_lag_s: {v:.4g}" for c, v in lags.items())
                            + "): replay and the node align the channels as the selection did")
    if config.estimator.paper_model and (result.negative or _structured(result)):
        result = _without_paper_model(data, config, how, result)
    result.speed_noise = data.speed_noise_text
    return result


def _window(data: SampleData, start: float | Instant | None, end: float | Instant | None) -> tuple[SampleData, str]:
    """The samples of the window ``--start/--end``: each bound seconds after the first sample analysed (the end
    not included), or an instant on the recordings' clock (:class:`~base.instants.Instant`, included); the
    window is said by its first and last sample's instants, as a trace names its window."""
    if start is None and end is None:
        return data, ""
    first = int(data.t_ns[0])
    t = (data.t_ns - first) * 1e-9
    keep = np.ones(len(t), bool)
    if isinstance(start, Instant):
        keep &= data.t_ns >= start
    elif start is not None:
        keep &= t >= start
    if isinstance(end, Instant):
        keep &= data.t_ns <= end
    elif end is not None:
        keep &= t < end
    if not keep.any():
        def said(bound):
            return f"{bound:g} s" if isinstance(bound, float) else str(bound)
        raise UsageError(f"no sample between --start {said(start or 0.0)} and --end {said(end or float(t[-1]))} (the "
                         f"samples analysed run from {iso_ns(first)} to {iso_ns(int(data.t_ns[-1]))}, "
                         f"{float(t[-1]):.1f} s)")
    kept = data.t_ns[keep]
    text = (f"the window {iso_ns(int(kept[0]))} to {iso_ns(int(kept[-1]))} ({(int(kept[0]) - first) * 1e-9:g} to "
            f"{(int(kept[-1]) - first) * 1e-9:g} s after the first sample analysed)")
    return data.select(keep), text


def _structured(result: CalibrationResult) -> str:
    """What the residual left by a file of effects found follows, where one input carries most of its
    variance (more than :data:`MODEL_SHAPE_SHARE`): the statement, or '' (none, or nothing found)."""
    structure = result.structure or {}
    strongest = structure.get("strongest")
    if result.verdict != "effects_found" or not result.written or not strongest \
            or structure.get("explained_share", {}).get(strongest, 0.0) <= MODEL_SHAPE_SHARE:
        return ""
    return structure.get("statement", "")


def _without_paper_model(data: SampleData, config: Config, how: _Analysis,
                         result: CalibrationResult) -> CalibrationResult:
    """The analysis again with the paper's model switched off -- weighed where the fits with it
    needed a negative friction (the model over-predicts) or the file they would write leaves a
    residual that still follows an input (the model's shape is not this gearbox's) -- taken when its
    effects explain the loss and predict the held-out operating points clearly better (said either
    way)."""
    how.stage("the paper's model switched off")
    off = config.with_values({"estimator.paper_model": False})
    zero = np.zeros(len(data.t_ns))
    without = replace(data, model_loss=zero, fr_part=zero, parts={})
    applied = {lag.channel: lag.lag_s for lag in result.lags if lag.applied}
    alt = _calibrate_once(without, off, how, before=result, applied=applied)
    on_text = f"{result.error_after.rmse_nm:.4g}" if result.written else "no file"
    why_weighed = (f"with it, the fits needed a negative friction ({', '.join(result.negative)})" if result.negative
                   else f"with it, {_structured(result)}")
    explains = (alt.error_after.rel_rmse_pct <= ALTERNATIVE_MAX_ERROR_PCT
                or not (alt.structure or {}).get("strongest"))
    if alt.written and alt.verdict == "effects_found" and explains and (
            not result.written or alt.error_after.rmse_nm
            < (1.0 - ALTERNATIVE_MIN_IMPROVEMENT) * result.error_after.rmse_nm):
        alt.notes.insert(0, (
            f"the paper's model {'over-predicts' if result.negative else 'does not have the shape of'} this "
            f"gearbox's loss: {why_weighed}; written with estimator.paper_model: false, whose effects predict the "
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
        f"{why_weighed}: the paper's model switched off was weighed and not taken: {why} (held-out RMSE "
        f"{alt.error_after.rmse_nm:.4g} N·m against {on_text} with the model)")
    return result


#: a lag is re-estimated on the samples aligned by the last estimate at most this often (the first
#: order of ``x(t − τ) ≈ x − τ·dx/dt`` underestimates a lag of several samples a little)
MAX_ALIGNMENTS = 3
ALTERNATIVE_MIN_IMPROVEMENT = 0.02  #: the paper's model is switched off only for a held-out RMSE this much lower
#: ... and only when the effects then explain the loss: a held-out error within this share of it, or a
#: residual left without structure (switching the model off is a claim about the gearbox)
ALTERNATIVE_MAX_ERROR_PCT = 10.0
#: a residual left by the paper's model and its effects that follows one input by more than this
#: share of its variance: the model's shape is not the gearbox's, and the model switched off is weighed
MODEL_SHAPE_SHARE = 0.5
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


def _calibrate_once(data: SampleData, config: Config, how: _Analysis, before: CalibrationResult | None = None,
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
    """What the selection took (step 1 of :func:`_calibrate_once`)."""

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


def _select_terms(data: SampleData, config: Config, how: _Analysis) -> _Selected:
    """The selection from the file's own effects, the hand fit weighed beside it, a refit at the corrected
    torque where a sensor error was taken, the values kept in range."""
    blocks0, cal, ranges = _calibrator(data, config, how)
    start = _file_terms(cal, config)
    out = select(cal, start, how.assume, _value_check(config, ranges))
    # the engineer's least-squares line on the same folds: the written file is never worse than it
    hand = weigh(cal, out, hand_fit(cal, _value_check(config, ranges)))
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
    """The parameter file as given, on these samples (step 2 of :func:`_calibrate_once`)."""

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


def _calibrator(data: SampleData, config: Config, how: _Analysis) -> tuple[Blocks, Calibrator, dict]:
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
        new.minimum = cal.minimum
        new.log = cal.log
        final = [new._with_member(t, t.member) if t.member is not None else members(new.b, t.name)[0] for t in final]
        cal = new
    return cal, final, corrected

