"""Forward selection over the candidates: every one tested, every decision with its reason.

Step 5 of :mod:`.calibrate`, over the fits of :class:`~.selection.Calibrator`:

1. **Start** from the parameter file's own effects (kept or dropped below, like any other).
2. **Forward**: at each step the remaining candidates are fitted beside what is accepted and ranked
   by held-out error (the smaller explanation first among those that fit as well); they are tested
   in that order and the first that passes is accepted -- a candidate that fails does not end the
   selection, the next one is tested.  The selection ends when none passes.  A law with an exponent
   comes as its line (p = 1) unless its curve predicts held-out operating points better
   (:meth:`~.selection.Calibrator.best_candidate`); beside the final set each is settled again
   (:meth:`_Procedure._straighten`).
3. **Readings**: where two readings of the same part of the loss both pass (a torque offset and a
   drag that differs by direction; a back-driving friction and a torque gain plus a load friction:
   :attr:`~core.effects.Effect.alternative_to`), both are named with their held-out errors and what
   tells them apart, and the one with fewer terms is taken (between equally many, the established
   reading the other is declared an alternative to), unless ``--assume`` chose -- or unless, in the
   final set, the other leaves the held-out residual at the noise of a block mean and the taken one
   does not: then the data tell them apart, and the other is taken.
4. **Backward**: an accepted term that no longer passes beside the others (its |z|, the lower bound
   of its RMS contribution against δ, the held-out improvement it brings) is dropped, the weakest
   first, and said.
5. **Decisions**: each candidate's held-out RMSE with and without it, |z|, RMS contribution and the
   reasons it was not accepted -- or, for those the data cannot test, why not.

No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from .blocks import groups
from .leastsquares import z_two_sided
from .selection import AmbiguousSet, Calibrator, RejectedEffect, Term, members, viscosity_level
from .structure import NOISE_FACTOR
from ..core.effects import EFFECTS, separating_data
from ..core.modelparams import MODEL_PARAMETERS

__all__ = ["Decision", "Selection", "select"]


@dataclass(frozen=True)
class Decision:
    """What became of one candidate, and why."""

    name: str
    accepted: bool
    step: int | None  #: the step it was accepted at (0: kept from the parameter file), or last tested at
    heldout_rmse_nm: float  #: with it: the final set (accepted), or the final set and it (not)
    heldout_without_nm: float  #: without it
    z: float
    rms_contribution_ci95_nm: list[float]
    reasons: list[str]  #: why it was not accepted (empty: accepted)
    note: str = ""  #: from the parameter file, assumed, the other reading of ..., why it cannot be tested

    def to_json(self) -> dict:
        return {"name": self.name, "accepted": self.accepted, "step": self.step,
                "heldout_rmse_nm": _finite(self.heldout_rmse_nm),
                "heldout_without_nm": _finite(self.heldout_without_nm), "z": _finite(self.z),
                "rms_contribution_ci95_nm": [_finite(v) for v in self.rms_contribution_ci95_nm],
                "reasons": self.reasons, "note": self.note}

    def sentence(self) -> str:
        """``drag_constant: accepted at step 3 (held-out RMSE 2.58 -> 2.04 N·m, |z| = 40.6)``."""
        errors = (f"held-out RMSE {self.heldout_without_nm:.4g} -> {self.heldout_rmse_nm:.4g} N·m"
                  if math.isfinite(self.heldout_rmse_nm) else "")
        z = f"|z| = {self.z:.1f}" if math.isfinite(self.z) else ""
        said = ", ".join(x for x in (errors, z) if x)
        if self.accepted:
            where = "kept from the parameter file" if self.step == 0 else f"accepted at step {self.step}"
            return f"{self.name}: {where}" + (f" ({said})" if said else "") + (f"; {self.note}" if self.note else "")
        why = "; ".join(self.reasons) or self.note
        return f"{self.name}: not accepted" + (f" ({said})" if said else "") + f": {why}"


@dataclass
class Selection:
    """What the selection found (:func:`select`)."""

    selected: list  #: accepted terms, in the order accepted
    provisional: list  #: the best term of each ambiguous set: kept in the fit, not reported
    ranges: dict[str, list[float]]  #: profile-likelihood 95 % range of each term's member
    ambiguous: list[AmbiguousSet]
    rejected: list[RejectedEffect]
    unavailable: list[str]  #: candidates the data cannot test
    second_ranges: dict[str, list[float]] = field(default_factory=dict)  #: the same for a second member (Vogel C)
    #: candidates set aside at some step because their fit needed a negative friction (the model
    #: over-predicts somewhere)
    negative: list[str] = field(default_factory=list)
    decisions: list[Decision] = field(default_factory=list)
    untestable: dict[str, str] = field(default_factory=dict)  #: candidate -> why the data cannot test it


@dataclass
class _Forward:
    """Where a forward selection stands."""

    remaining: list[str]  #: candidates not yet decided
    cv_now: float  #: held-out RMSE of what is accepted so far
    step: int = 0
    selected: list[Term] = field(default_factory=list)  #: accepted
    #: the best member of each ambiguous set: kept in the fit, not reported
    provisional: list[Term] = field(default_factory=list)
    ambiguous: list[AmbiguousSet] = field(default_factory=list)
    negative: list[str] = field(default_factory=list)  #: set aside for a clear negative friction
    accepted_at: dict[str, int] = field(default_factory=dict)  #: name -> step (0: from the file)
    tested_at: dict[str, int] = field(default_factory=dict)  #: name -> last step it was tested at
    notes: dict[str, str] = field(default_factory=dict)  #: name -> a note for its decision
    readings: list[tuple[tuple[str, ...], tuple[str, ...], int]] = field(default_factory=list)  #: taken, other, set


def select(cal: Calibrator, initial: Sequence[Term] = (), assume: Sequence[str] = (),
           check: Callable[[Term, float], str | None] | None = None) -> Selection:
    """The selection (see the module docstring) over ``cal``'s candidates; ``initial``: the parameter
    file's accepted effects as terms (where it starts); ``assume``: candidates to take where the data
    cannot tell them from another, or between two readings; ``check``: a last word on a candidate's
    value (:meth:`~.selection.Calibrator.screen`)."""
    return _Procedure(cal, tuple(assume), check).run(list(initial))


class _Procedure:
    def __init__(self, cal: Calibrator, assume: tuple[str, ...], check) -> None:
        self.cal, self.assume, self.check = cal, assume, check
        self.log = cal.log

    # ------------------------------------------------------------------ the run
    def run(self, initial: list[Term]) -> Selection:
        cal = self.cal
        from_file = [t for t in initial if t.name in cal.b.testable]
        names = {t.name for t in from_file}
        state = _Forward(remaining=[g for g in groups() if g in cal.b.testable and g not in names],
                         cv_now=cal.cv_rmse([]))
        if from_file:
            state.selected = cal.optimise(from_file)
            state.cv_now = cal.cv_rmse(state.selected)
            state.accepted_at.update(dict.fromkeys(names, 0))
            self.log.append(f"start: the parameter file's {', '.join(sorted(names))} (held-out RMSE "
                            f"{state.cv_now:.4g} N·m, refitted)")
            self._whole_oil_law(state, from_file)
        for t in initial:
            if t.name not in cal.b.testable:
                state.notes[t.name] = "in the parameter file, but this data cannot test it: kept as it is"
        self._file_readings(state, names)
        while state.remaining and self._step(state):
            pass
        self._settle_readings(state)
        self._backward(state)
        self._straighten(state)
        final = state.selected + state.provisional
        cal.stage("exponent intervals")
        ranges = {t.name: cal.member_range(final, i) for i, t in enumerate(final) if t.member is not None}
        second_ranges = {t.name: cal.member_range(final, i, second=True) for i, t in enumerate(final)
                         if t.second is not None}
        self._reading_errors(state, final)
        decisions, rejected, unavailable = self._decisions(state, final)
        untestable = {g: why for g, why in cal.b.untestable.items()}
        return Selection(state.selected, state.provisional, ranges, state.ambiguous, rejected, unavailable,
                         second_ranges, state.negative, decisions, untestable)

    def _whole_oil_law(self, state: _Forward, from_file: list[Term]) -> None:
        """The parameter file's viscosity law refitted whole: its shape (Vogel B and C) together with
        its level (η at θ_ref, the rolling part's parameter) where the data can test that -- a law
        refitted at the file's η(θ_ref) bends its shape to make up another oil's level.  Taken when it
        clearly predicts better, as :meth:`~.selection.Calibrator.best_candidate` pairs them."""
        cal = self.cal
        if not any(t.name in EFFECTS and EFFECTS[t.name].scales_fr for t in from_file):
            return
        level = viscosity_level()
        if level is None or level not in state.remaining or not members(cal.b, level, None):
            return
        whole = cal.optimise(from_file + members(cal.b, level))
        cv_whole = cal.cv_rmse(whole)
        if cal.screen(whole, self.check) is not None or cv_whole >= (1.0 - cal.min_improvement) * state.cv_now:
            return
        self.log.append(f"start: the file's viscosity law refitted whole, with its level {level} (held-out RMSE "
                        f"{state.cv_now:.4g} -> {cv_whole:.4g} N·m)")
        state.selected, state.cv_now = whole, cv_whole
        state.accepted_at[level] = 0
        state.notes[level] = "the level of the parameter file's viscosity law, refitted with it"
        state.remaining = [r for r in state.remaining if r != level]

    def _step(self, state: _Forward) -> bool:
        """One step: the remaining candidates tested best first, the first that passes accepted (or
        kept in the fit as an ambiguous set); False when none passes."""
        cal = self.cal
        state.step += 1
        step = state.step
        base = state.selected + state.provisional
        scored = self._ranked(state, base)
        for cv_new, g, terms in scored:
            state.tested_at[g] = step
            new = terms[-1]
            lower, upper, z, reasons = cal.test(terms, g, state.cv_now, cv_new, len(state.remaining), self.check)
            head = (f"step {step}: {g}" + (f" ({_member_text(new)})" if new.member is not None else "")
                    + f" (held-out RMSE {cv_new:.4g} vs {state.cv_now:.4g} N·m), |z| = {z:.1f}, RMS contribution "
                    f"[{lower:.4g}, {upper:.4g}] N·m")
            if reasons:
                self.log.append(f"{head}; not accepted: {'; '.join(reasons)}")
                continue
            twin_terms = self._twins(scored, g, cv_new, new, base, step)
            twins = list(twin_terms)
            assumed = next((a for a in [g, *twins] if a in self.assume), None) if twins else None
            if twins:
                self.log.append(f"{head}; indistinguishable from {', '.join(twins)}; "
                                + (f"ambiguous: accepted as {assumed}, as assumed" if assumed
                                   else "ambiguous: kept in the fit, not reported"))
                if assumed is not None and assumed != g:  # the twin's fit: near the same error, by definition
                    cv_new, terms = twin_terms[assumed]
                self._accept(state, base, terms, _ambiguous_set(g, twins, [lower, upper], assumed))
                state.cv_now = cv_new
                return True
            reading = self._reading(state, base, g, terms, cv_new, scored)
            if reading is not None:
                cv_new, terms, taken = reading
                self.log.append(f"{head}; passes, and so does the other reading of the same part of the loss: "
                                f"taken as {' + '.join(taken)}")
            else:
                self.log.append(f"{head}; accepted")
            self._accept(state, base, terms, None)
            state.cv_now = cv_new
            return True
        self.log.append(f"step {step}: no candidate passes" if scored else
                        f"step {step}: no candidate left that is an explanation")
        return False

    def _ranked(self, state: _Forward, base: list) -> list:
        """The remaining candidates' best fits with ``base`` that are explanations, best first -- the
        smaller explanation first among those that fit (nearly) as well as the best: the one with the
        fewest free parameters, a model parameter before an effect, a plain law before one with an
        exponent or a memory.  Entries ``(held-out RMSE, candidate, terms)``."""
        cal = self.cal
        scored = []
        for g in state.remaining:
            cal.stage(f"step {state.step}: trying {g}")
            terms = cal.best_candidate(g, base)
            if terms is not None:
                scored.append((cal.cv_rmse(terms), g, terms))
        if not scored:
            return []
        scored.sort(key=lambda x: x[0])
        scored = self._explanations(scored, state)
        if not scored:
            return []
        near = [x for x in scored if x[0] <= scored[0][0] * 1.01 + 1e-12]
        simplest = min(near, key=lambda x: (complexity(x[1]), x[0]))
        if simplest is not scored[0]:
            scored.remove(simplest)
            scored.insert(0, simplest)
        return scored

    def _explanations(self, scored: list, state: _Forward) -> list:
        """The scored candidates that are an explanation: one asking for a negative friction, an
        exponent at its bound or a parameter out of its range is set aside (said; a clear negative
        friction is noted in ``state.negative``)."""
        cal = self.cal
        kept = []
        z_crit = z_two_sided(cal.alpha / len(state.remaining))
        for entry in scored:
            why_not = cal.screen(entry[2], self.check)
            if why_not is None:
                kept.append(entry)
                continue
            self.log.append(f"step {state.step}: {entry[1]} set aside: {why_not}")
            state.tested_at[entry[1]] = state.step
            # a negative friction over the operating range the data ask for clearly (significant, beyond
            # delta) and better than any explanation: the model over-predicts, and the paper's model
            # switched off is worth weighing (calibrate)
            if not kept and "negative friction" in why_not and entry[1] not in state.negative \
                    and _level(entry[1]) and cal.clear(entry[2], state.cv_now, entry[0], z_crit):
                state.negative.append(entry[1])
        return kept

    def _accept(self, state: _Forward, base: list, terms: list, ambiguous: AmbiguousSet | None) -> None:
        """Take the step's fit (``terms``: ``base`` re-fitted, then the new terms) into the state: the
        new terms selected, or with its twins an ambiguous set (selected when assumed, else kept in
        the fit provisionally)."""
        # exponents of earlier terms were re-optimised together with the new one; a term that came
        # with it (the viscosity law's level) is accepted with it
        n_sel = len(state.selected)
        added = terms[len(base):]
        state.selected, state.provisional = terms[:n_sel], terms[n_sel:len(base)]
        for t in added[:-1]:
            state.selected.append(t)
            state.accepted_at[t.name] = state.step
        new = added[-1]
        state.remaining = [r for r in state.remaining if r not in {t.name for t in added}]
        if ambiguous is not None:
            state.ambiguous.append(ambiguous)
            (state.selected if ambiguous.assumed else state.provisional).append(new)
            state.remaining = [r for r in state.remaining if r not in ambiguous.effects]
            if ambiguous.assumed:
                state.accepted_at[ambiguous.assumed] = state.step
        else:
            state.selected.append(new)
            state.accepted_at[new.name] = state.step

    # ------------------------------------------------------------------ twins and readings
    def _twins(self, scored: list, g: str, cv_new: float, new: Term, base: list[Term], step: int) -> dict:
        """The candidates the data cannot tell from ``g`` (name -> (held-out RMSE, terms)): none when
        ``g`` is a parameter of the model (the smaller explanation), never one that only adds a memory
        the data do not show, never the other reading of ``g`` (:meth:`_reading`)."""
        cal = self.cal
        twin_terms = {
            h: (cv_h, terms_h)
            for cv_h, h, terms_h in scored
            if h != g and cv_h <= cv_new * 1.05 + 1e-12 and not _readings_of(g, h)
            and cal.partial_corr(new, terms_h[-1], base) > 0.995
        }
        if g in MODEL_PARAMETERS and twin_terms:  # a parameter of the model is the smaller explanation
            self.log.append(f"step {step}: {g} fits as well as {', '.join(twin_terms)}: the model's "
                            "own parameter is taken (no new term)")
            twin_terms = {}
        memory = [h for h in twin_terms if _adds_only_memory(h, g)]
        if memory:  # a memory the data do not show is not claimed: the memoryless law is taken
            self.log.append(f"step {step}: {g} fits as well as {', '.join(memory)}: no lag after the "
                            "reversals shows, the term without memory is taken")
            twin_terms = {h: v for h, v in twin_terms.items() if h not in memory}
        return twin_terms

    def _reading(self, state: _Forward, base: list, g: str, terms: list, cv_new: float,
                 scored: list) -> tuple[float, list, tuple[str, ...]] | None:
        """Where ``g`` is one of two readings of the same part of the loss
        (:attr:`~core.effects.Effect.alternative_to`) and the other passes too: both named (an ambiguous
        set with the reading taken), the reading taken -- the assumed one, else the one with fewer
        terms, else the established one -- as ``(held-out RMSE, terms, names)``; None when there is no
        other reading that passes."""
        cal = self.cal
        for mine, other in _pairs_of(g):
            if any(n in {t.name for t in base} for n in (*mine, *other)) or any(
                    n not in state.remaining and n != g for n in (*mine, *other)):
                continue
            fitted = list(base)
            for name in other:
                fitted = cal.best_candidate(name, fitted)
                if fitted is None:
                    break
            if fitted is None or cal.screen(fitted, self.check) is not None:
                continue
            cv_other = cal.cv_rmse(fitted)
            k = len(base)
            # each of its terms passes beside the others (the reading as a whole against the base)
            if any(cal.test(_moved_last(fitted, k + i), name,
                            cal.cv_rmse(cal.optimise(fitted[:k + i] + fitted[k + i + 1:])) if len(other) > 1
                            else state.cv_now, cv_other, len(state.remaining), self.check)[3]
                   for i, name in enumerate(other)):
                continue  # the other reading does not pass: no second reading
            assumed_mine = any(n in self.assume for n in mine)
            assumed_other = any(n in self.assume for n in other)
            if assumed_mine != assumed_other:
                take_other = assumed_other
            else:
                take_other = len(other) < len(mine) or (len(other) == len(mine) and EFFECTS.get(g) is not None
                                                        and EFFECTS[g].alternative_to == other)
            taken, dropped = (other, mine) if take_other else (mine, other)
            needs = _reading_needs(mine, other)
            amb = AmbiguousSet(sorted({*mine, *other}), needs, [math.nan, math.nan],
                               assumed=next((n for n in taken if n in self.assume), None),
                               taken=" + ".join(taken))
            state.ambiguous.append(amb)
            state.readings.append((taken, dropped, len(state.ambiguous) - 1))
            if len(dropped) == 1 and not (assumed_mine or assumed_other):
                # a reading of one effect is not added on top of the other one (unless a reading was
                # assumed: then the other may still add what is left, tested as any candidate)
                state.remaining = [r for r in state.remaining if r != dropped[0] or r in taken]
                state.notes[dropped[0]] = (f"the other reading of {' + '.join(taken)} (both pass; "
                                           f"--assume {dropped[0]} takes it)")
            return (cv_other, fitted, taken) if take_other else (cv_new, terms, taken)
        return None

    def _file_readings(self, state: _Forward, names: set[str]) -> None:
        """A reading the parameter file holds whole (its torque offset) is the one taken: the other one
        (a drag that differs by direction) is named beside it, not added on top -- unless assumed, or
        unless the data tell them apart (:meth:`_settle_readings`)."""
        for e in EFFECTS.values():
            mine, other = (e.name,), tuple(e.alternative_to)
            if not other or e.name in names or not set(other) <= names or e.name not in state.remaining:
                continue
            if any(n in self.assume for n in (*mine, *other)):
                continue
            amb = AmbiguousSet(sorted({*mine, *other}), _reading_needs(mine, other), [math.nan, math.nan],
                               taken=" + ".join(other))
            state.ambiguous.append(amb)
            state.readings.append((other, mine, len(state.ambiguous) - 1))
            state.remaining = [r for r in state.remaining if r != e.name]
            state.notes[e.name] = (f"the other reading of the parameter file's {' + '.join(other)} (--assume "
                                   f"{e.name} takes it)")

    def _settle_readings(self, state: _Forward) -> None:
        """Where one of two readings, in the final set, leaves the held-out residual at the noise of a
        block mean and the other does not, the data tell them apart: that one is taken (unless assumed)."""
        cal = self.cal
        noise = NOISE_FACTOR * cal.noise_rms()
        for k, (taken, other, index) in enumerate(state.readings):
            amb = state.ambiguous[index]
            if amb.assumed is not None:
                continue
            final = state.selected + state.provisional
            alt = [t for t in final if t.name not in taken]
            for name in other:
                alt = cal.best_candidate(name, alt) if alt is not None else None
            if alt is None or cal.screen(alt, self.check) is not None:
                continue
            cv_taken, cv_other = cal.cv_rmse(final), cal.cv_rmse(alt)
            if cv_other <= noise < cv_taken:
                self.log.append(f"readings: {' + '.join(other)} leaves the held-out residual at the noise of a block "
                                f"mean ({cv_other:.4g} N·m against {noise / NOISE_FACTOR:.4g}), {' + '.join(taken)} "
                                f"does not ({cv_taken:.4g}): the data tell them apart, {' + '.join(other)} is taken")
                n_sel = len([t for t in state.selected if t.name not in taken])
                state.selected, state.provisional = alt[:n_sel] + alt[len(final) - len(taken):], \
                    alt[n_sel:len(final) - len(taken)]
                for name in taken:
                    state.accepted_at.pop(name, None)
                    state.notes[name] = f"the other reading of {' + '.join(other)}, which the data favour"
                for name in other:
                    state.accepted_at[name] = state.step
                    state.notes.pop(name, None)
                    state.remaining = [r for r in state.remaining if r != name]
                amb.taken = " + ".join(other)
                state.readings[k] = (other, taken, index)

    def _reading_errors(self, state: _Forward, final: list[Term]) -> None:
        """Each pair of readings' held-out errors and parameters, the other reading fitted in place of
        the one taken in the final set."""
        cal = self.cal
        for taken, other, index in state.readings:
            rest = [t for t in final if t.name not in taken]
            alt = rest
            for name in other:
                alt = cal.best_candidate(name, alt) if alt is not None else None
            entries = []
            for names, terms in ((taken, final), (other, alt)):
                if terms is None:
                    continue
                fit = cal.fit(terms)
                k0 = len(cal.nuisance)
                params = {t.name: t.params(float(fit.coef[k0 + i])) for i, t in enumerate(terms) if t.name in names
                          and t.name in EFFECTS}
                entries.append({"effects": list(names), "heldout_rmse_nm": cal.cv_rmse(terms), "params": params,
                                "written": names == taken})
            state.ambiguous[index].readings = entries

    # ------------------------------------------------------------------ backward
    def _backward(self, state: _Forward) -> None:
        """Drop, the weakest first, an accepted term that no longer passes beside the others."""
        cal = self.cal
        while len(state.selected) > 0:
            final = state.selected + state.provisional
            cv_all = cal.cv_rmse(final)
            failing = []
            for i, t in enumerate(state.selected):
                if t.name in self.assume or any(a.assumed == t.name for a in state.ambiguous):
                    continue
                rest = cal.optimise([u for j, u in enumerate(final) if j != i])
                cv_without = cal.cv_rmse(rest)
                lower, _upper, z, reasons = cal.test(_moved_last(final, i), t.name, cv_without, cv_all,
                                                     len(state.selected), self.check)
                unfixed = None if reasons else cal.level_unfixed(final, i)  # judged beside the whole set only
                if reasons or unfixed:
                    failing.append((z, i, t, cv_without, reasons or [unfixed], unfixed))
            if not failing:
                return
            z, i, t, cv_without, reasons, unfixed = min(failing, key=lambda f: f[0])
            self.log.append(f"backward: {t.name} dropped: beside the others it no longer passes "
                            f"({'; '.join(reasons)}; held-out RMSE {cv_all:.4g} with it, {cv_without:.4g} without)")
            state.notes[t.name] = (f"dropped beside the final set: {unfixed}" if unfixed else
                                   "dropped: no longer needed beside the effects accepted after it")
            del state.selected[i]
            state.selected = cal.optimise(state.selected + state.provisional)[:len(state.selected)]
            state.accepted_at.pop(t.name, None)

    def _straighten(self, state: _Forward) -> None:
        """Beside the final set, each law with a line (:attr:`~core.effects.Effect.linear`) is its curve only
        where the curve predicts held-out operating points better than the line by more than the minimum
        improvement and stops inside its search: a line taken when the law came in (the rest of the loss
        still unexplained) is curved now if the data between the operating points ask for it, and a curve
        the later terms moved back near the line is the line again."""
        cal = self.cal
        for i, t in enumerate(state.selected):
            if t.member is None or t.name not in EFFECTS or EFFECTS[t.name].linear is None:
                continue
            final = state.selected + state.provisional
            if t.fixed:
                free = Term(t.name, t.column, t.member, t.second, t.law)
                line, curve = final, cal.optimise(final[:i] + [free] + final[i + 1:])
            else:
                line, curve = cal.optimise(final[:i] + [cal.line_of(t)] + final[i + 1:]), final
            lo, hi = cal.search_ranges(t.name)[EFFECTS[t.name].member]
            bent = curve[i].member
            curved = not min(abs(bent - lo), abs(bent - hi)) <= 1e-3 * (hi - lo) \
                and cal.cv_rmse_points(curve) < (1.0 - cal.min_improvement) * cal.cv_rmse_points(line)
            chosen = curve if curved else line
            if chosen is final or cal.screen(chosen, self.check) is not None:
                continue
            self.log.append(f"{t.name}: beside the final set its {EFFECTS[t.name].member} = {chosen[i].member:.3g} "
                            + ("(its curve predicts held-out operating points better than its line)" if curved
                               else "(its line: its curve predicts held-out operating points no better)"))
            n = len(state.selected)
            state.selected, state.provisional = chosen[:n], chosen[n:]

    # ------------------------------------------------------------------ decisions
    def _decisions(self, state: _Forward, final: list[Term]) -> tuple[list[Decision], list[RejectedEffect], list[str]]:
        """Every candidate's decision, the rejected ones' bounds (``rejected``, as before), and the
        candidates the data cannot test."""
        cal = self.cal
        cal.stage("every candidate's decision")
        decisions: list[Decision] = []
        rejected: list[RejectedEffect] = []
        unavailable: list[str] = []
        cv_final = cal.cv_rmse(final)
        selected = {t.name for t in state.selected}
        blocked = {e for a in state.ambiguous if a.taken is None for e in a.effects if e != a.assumed}
        n_open = max(len([g for g in groups() if g in cal.b.testable and g not in selected]), 1)
        for g in groups():
            if g in selected:
                i = next(k for k, t in enumerate(final) if t.name == g)
                rest = cal.optimise([u for k, u in enumerate(final) if k != i])
                cv_without = cal.cv_rmse(rest)
                c, se = cal.coefficient(final, i)
                rms = cal.contribution_rms(final, i)
                note = "assumed (--assume)" if g in self.assume else state.notes.get(g, "")
                if final[i].fixed and g in cal.line_notes:  # a law held at its line: why not its curve
                    note = "; ".join(x for x in (note, cal.line_notes[g]) if x)
                decisions.append(Decision(g, True, state.accepted_at.get(g), cv_final, cv_without,
                                          abs(c) / se if se > 0 else math.inf,
                                          [max(0.0, abs(c) - 1.96 * se) * rms, (abs(c) + 1.96 * se) * rms], [], note))
                continue
            if g not in cal.b.testable:
                why = cal.b.untestable.get(g, "this data cannot test it")
                unavailable.append(g)
                decisions.append(Decision(g, False, None, math.nan, math.nan, math.nan, [math.nan, math.nan],
                                          [why], state.notes.get(g, "")))
                continue
            if g in blocked:
                decisions.append(Decision(g, False, state.tested_at.get(g), math.nan, cv_final, math.nan,
                                          [math.nan, math.nan], ["the data cannot tell it from another (see "
                                                                 "ambiguous): kept in the fit, not written"]))
                rejected.append(RejectedEffect(g, math.nan, math.nan, ambiguous=True,
                                               reason="cannot be told apart from another effect"))
                continue
            terms = cal.best_candidate(g, final)
            if terms is None:
                if g in EFFECTS and EFFECTS[g].oil_law:  # follows the oil: no law to follow
                    unavailable.append(g)
                    why = ("follows the oil's viscosity law, and no law was fitted (viscosity_temperature) or given "
                           "(--oil)")
                    decisions.append(Decision(g, False, None, math.nan, math.nan, math.nan, [math.nan, math.nan],
                                              [why]))
                continue
            cv_with = cal.cv_rmse(terms)
            screen = cal.screen(terms, self.check)
            lower, upper, z, reasons = cal.test(terms, g, cv_final, cv_with, n_open, self.check, full=False)
            if screen:
                reasons = [screen] + [r for r in reasons if "not significant" in r]
            note = state.notes.get(g, "")
            if note and note.startswith("the other reading"):
                reasons = [note] + reasons
                note = ""
            if not reasons:  # passes beside the final set, yet was not taken: say what held it back
                reasons = [note or "passes beside the final set only as a change the selection did not take"]
            decisions.append(Decision(g, False, state.tested_at.get(g), cv_with, cv_final, z, [lower, upper],
                                      reasons, note))
            c, se = cal.coefficient(terms, len(terms) - 1)
            rms_col = cal.contribution_rms(terms, len(terms) - 1)
            rejected.append(RejectedEffect(g, (abs(c) + 1.96 * se) * rms_col, abs(c) * rms_col,
                                           reason="; ".join(reasons)))
        return decisions, rejected, unavailable


# ---------------------------------------------------------------------------- helpers
def _level(name: str) -> bool:
    """A candidate that adds a loss over the operating range (not a transient's shape: a memory, a
    law that fades with speed): a negative one says the model's level is too high."""
    e = EFFECTS.get(name)
    return e is not None and e.state_step is None and e.vanishes_above is None


def _moved_last(terms: list[Term], i: int) -> list[Term]:
    """``terms`` with the ``i``-th last (the one a test looks at)."""
    return terms[:i] + terms[i + 1:] + [terms[i]]


def _pairs_of(name: str) -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    """The pairs of readings ``name`` is part of, as ``(its side, the other side)``."""
    out = []
    for e in EFFECTS.values():
        if not e.alternative_to:
            continue
        mine, other = (e.name,), tuple(e.alternative_to)
        if name in mine:
            out.append((mine, other))
        elif name in other and len(other) == 1:
            out.append((other, mine))
    return out


def _readings_of(a: str, b: str) -> bool:
    """Whether ``a`` and ``b`` are the two readings of one part (never twins: both are named)."""
    return any(b in other for _mine, other in _pairs_of(a))


def _reading_needs(mine: tuple[str, ...], other: tuple[str, ...]) -> str:
    """What tells two readings apart (from the descriptor that declares them)."""
    for e in (*mine, *other):
        if e in EFFECTS and EFFECTS[e].alternative_needs:
            return EFFECTS[e].alternative_needs
    return "data over a wider range of speed, torque, direction and temperature"


def complexity(name: str) -> int:
    """How much a candidate explains with: a model parameter 0 (it adds no term), an effect 1 for its
    coefficient, one more for each profiled member and for a memory."""
    if name in MODEL_PARAMETERS:
        return 0
    e = EFFECTS[name]
    return 1 + (e.member is not None) + (e.second_member is not None) + (e.state_step is not None)


def _adds_only_memory(twin: str, name: str) -> bool:
    """Whether ``twin`` is an effect with memory and ``name`` one without that it settles to (in steady
    motion the same column: Dahl and a constant drag)."""
    if twin in MODEL_PARAMETERS or name in MODEL_PARAMETERS:
        return False
    return EFFECTS[twin].state_step is not None and EFFECTS[name].state_step is None \
        and name in EFFECTS[twin].separated_from


def separating(a: str, b: str) -> str | None:
    """The data that tells two candidates apart (effects: their descriptors; a model parameter: its own)."""
    for x in (a, b):
        if x in MODEL_PARAMETERS:
            return MODEL_PARAMETERS[x].tells_apart
    return separating_data(a, b)


def _ambiguous_set(g: str, twins: list[str], rms_range: list[float], assumed: str | None) -> AmbiguousSet:
    """``g`` and the candidates the data cannot tell from it, with what would separate them."""
    group = sorted([g] + twins)
    needs = "; ".join(sorted({separating(a, b) or "data over a wider range of speed, torque, direction and "
                              "temperature" for a in group for b in group if a < b}))
    return AmbiguousSet(group, needs, rms_range, assumed)


def _member_text(t: Term) -> str:
    effect = EFFECTS[t.name]
    second = f", {effect.second_member} = {t.second:.3g}" if t.second is not None else ""
    return f"{effect.member} = {t.member:.3g}{second}"


def _finite(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None

