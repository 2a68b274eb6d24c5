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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from .analysis import Analysis, calibrate_once
from .nuisance import apply_lags
from .outcome import CalibrationResult, Change, segment_summary
from .samples import SampleData, load_samples
from .segments import differing_recording, find_changes, in_time_order
from .drift import find_drift
from .written import describing
from ..base.errors import UsageError
from ..base.instants import Instant, iso_ns
from ..core.effects import EFFECTS
from ..core.model import LossModel
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
    how = Analysis(settings.delta_nm, settings.block_s, settings.folds, stage, tuple(settings.assume))
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


def _readings_as_written(data: SampleData, config: Config, settings: CalibrationSettings, how: Analysis,
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


def _over_time(data: SampleData, config: Config, settings: CalibrationSettings, how: Analysis) -> CalibrationResult:
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


def _analyse(data: SampleData, config: Config, how: Analysis) -> CalibrationResult:
    """One analysis of all of ``data``: aligned where a channel lags, and weighed against the paper's
    model switched off where fits needed a negative friction."""
    result = calibrate_once(data, config, how)
    first, original, lags = result, data, {}
    for _ in range(MAX_ALIGNMENTS):  # a channel clearly behind the drive torque: aligned, analysed again
        more = {lag.channel: lag.lag_s for lag in result.lags if lag.applied and lag.lag_s != lags.get(lag.channel)}
        if not more:
            break
        how.stage("aligning the channels that lag")
        lags.update(more)
        model = LossModel(config.gearbox, enabled=config.estimator.paper_model)
        data = apply_lags(original, lags, model)
        result = calibrate_once(data, config, how, applied=lags)
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


def _without_paper_model(data: SampleData, config: Config, how: Analysis,
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
    alt = calibrate_once(without, off, how, before=result, applied=applied)
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


