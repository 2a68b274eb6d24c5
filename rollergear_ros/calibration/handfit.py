"""The engineer's baseline: Coulomb + viscous friction + a torque offset, fitted by linear least squares.

What a rig engineer fits by hand in a minute -- a constant drag, a drag proportional to the speed and
the torque reading's zero error (``drag_constant``, ``drag_speed`` at p = 1, ``torque_offset``), and
where both directions are measured the viscous drag per direction too (``drag_direction`` at p = 1) --
is always in the race, on the same folds as the selection (:mod:`.grouping`: whole operating points
held out).  The written file predicts held-out operating points at least as well as this line: where
the selection's set does not, the line is written instead and the result says why (a law with a free
exponent that takes the Coulomb part first, a curve bent where the data are straight).  The per-direction
form is taken only where it predicts clearly better (by the selection's minimum improvement).  The line is
fitted as by hand, to the operating points' means (:meth:`~.selection.Calibrator.at_operating_points`): on its
folds, and in the file where it is written.
No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .selection import Calibrator, Term

__all__ = ["HandFit", "hand_fit", "weigh", "written_heldout_rmse"]

#: both directions are measured when each holds at least this share of the blocks' samples
BOTH_DIRECTIONS_SHARE = 0.05


@dataclass(frozen=True)
class HandFit:
    """The least-squares line on this data's folds."""

    terms: list[Term]
    #: held-out error of what it would write at each operating point (:func:`written_heldout_rmse`)
    heldout_rmse_nm: float
    per_direction: bool  #: the viscous drag fitted per direction
    not_physical: str | None  #: why it cannot be written as a file (a negative friction), None: it can

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.terms]

    def text(self) -> str:
        what = "Coulomb + viscous per direction" if self.per_direction else "Coulomb + viscous"
        if any(t.name == "torque_offset" for t in self.terms):
            what += " + offset"
        return f"least-squares {what}"


def written_heldout_rmse(cal: Calibrator, terms: Sequence[Term], written: int | None = None) -> float:
    """The held-out error of what a file of the first ``written`` of ``terms`` predicts (the rest and the
    nuisances fitted beside them, not written), on ``cal``'s folds, at each operating point
    (:func:`~.selection.operating_point_rmse`): the map's error where it was not fitted."""
    return cal.cv_rmse_points(terms, len(terms) if written is None else written)


#: held-out errors within this share of each other are a tie (the selection stands): which of two equal fits the
#: CPU's last bits rank first decides nothing
TIE = 1e-9
#: an ambiguity the line resolves by its own reading: a constant in one direction is its Coulomb friction
CONSTANT_READINGS = frozenset({"drag_constant", "torque_offset"})


def hand_fit(cal: Calibrator, check: Callable[[Term, float], str | None] | None = None,
             min_improvement: float | None = None) -> HandFit | None:
    """The least-squares line through ``cal``'s operating points (None where the data cannot test a constant
    drag)."""
    cal = cal.at_operating_points()
    b = cal.b
    if "drag_constant" not in b.testable or "drag_speed" not in b.testable:
        return None
    terms = [Term("drag_constant", b.column("drag_constant")),
             Term("drag_speed", b.column("drag_speed", 1.0), 1.0, fixed=True)]
    both = _both_directions(cal)
    if both and "torque_offset" in b.testable:
        terms.append(Term("torque_offset", b.column("torque_offset")))
    fits = [(written_heldout_rmse(cal, terms), terms, False)]
    if both and "drag_direction" in b.testable:
        more = terms + [Term("drag_direction", b.column("drag_direction", 1.0), 1.0, fixed=True)]
        fits.append((written_heldout_rmse(cal, more), more, True))
    gain = cal.min_improvement if min_improvement is None else min_improvement
    rmse, chosen, per_direction = fits[0]
    if len(fits) > 1 and fits[1][0] < (1.0 - gain) * rmse \
            and not _not_significant(cal, fits[1][1], {t.name for t in chosen}):
        rmse, chosen, per_direction = fits[1]
    return HandFit(chosen, rmse, per_direction, cal.screen(chosen, check))


def _not_significant(cal: Calibrator, terms: list[Term], beside: set[str]) -> list[str]:
    """The terms not in ``beside`` whose coefficient is not significant in the fit of ``terms``
    (cluster-robust, α Bonferroni-corrected over them)."""
    from .leastsquares import z_two_sided

    extra = [i for i, t in enumerate(terms) if t.name not in beside]
    if not extra:
        return []
    fit = cal.fit(terms)
    k0 = len(cal.nuisance)
    z_crit = z_two_sided(cal.alpha / len(extra))
    return [terms[i].name for i in extra
            if abs(fit.coef[k0 + i]) < z_crit * math.sqrt(max(fit.cov[k0 + i, k0 + i], 0.0))]


def _both_directions(cal: Calibrator) -> bool:
    """Whether each direction holds at least :data:`BOTH_DIRECTIONS_SHARE` of the blocks' samples."""
    b = cal.b
    total = float(np.sum(b.count))
    if total <= 0:
        return False
    forward = float(np.sum(b.count[b.speed > 0])) / total
    return min(forward, 1.0 - forward) >= BOTH_DIRECTIONS_SHARE and math.isfinite(forward)


def weigh(cal: Calibrator, selection, hand: HandFit | None) -> dict | None:
    """Weigh the selection against the hand fit on the same folds, at each operating point
    (:func:`written_heldout_rmse`).  The hand fit becomes the selection -- its terms accepted, the set it
    replaces said in each decision -- where it predicts held-out operating points better than the
    selection's set and each of its terms the set lacks is significant (cluster-robust, α Bonferroni-
    corrected over them: a line fitted to noise beside the set found is no finding); where the selection
    accepted nothing, better by more than the selection's minimum improvement too (the line is then a
    finding of its own).  An unresolved ambiguity other than the line's own constant (terms kept in the
    fit, not written) is not replaced: the line would take a side the data cannot tell.  Returns what the
    result says of it (``hand_fit`` in ``--json``), None without a hand fit."""
    from dataclasses import replace

    if hand is None:
        return None
    final = selection.selected + selection.provisional
    mine = written_heldout_rmse(cal, final, len(selection.selected))
    margin = cal.min_improvement if not selection.selected else TIE
    said = {"effects": hand.names, "text": hand.text(), "heldout_rmse_nm": hand.heldout_rmse_nm,
            "selection_heldout_rmse_nm": mine, "written": False, "reason": ""}
    if hand.heldout_rmse_nm >= (1.0 - margin) * mine:
        said["reason"] = (f"the selection predicts held-out operating points at least as well ({mine:.4g} against "
                          f"{hand.heldout_rmse_nm:.4g} N·m)")
        return said
    weak = _not_significant(cal.at_operating_points(), hand.terms, {u.name for u in selection.selected})
    if weak:
        said["reason"] = (f"it predicts held-out operating points a little better ({hand.heldout_rmse_nm:.4g} against "
                          f"{mine:.4g} N·m), but its {', '.join(weak)} {'is' if len(weak) == 1 else 'are'} not "
                          "significant: no finding, the selection stands")
        return said
    open_sets = [a for a in selection.ambiguous if a.taken is None and a.assumed is None]
    unresolved = {e for a in open_sets for e in a.effects}
    if unresolved - CONSTANT_READINGS:
        said["reason"] = ("it predicts held-out operating points better, but the data cannot tell apart "
                          + "; ".join(" / ".join(a.effects) for a in open_sets) + ": not written")
        return said
    if hand.not_physical:
        said["reason"] = ("it predicts held-out operating points better, but is no loss the gearbox has: "
                          f"{hand.not_physical}")
        return said
    why = (f"the {hand.text()} predicts held-out operating points better than the selection's set "
           f"({hand.heldout_rmse_nm:.4g} against {mine:.4g} N·m)")
    if unresolved:  # the line's constant is Coulomb friction or the reading's zero -- said
        why += ("; the data cannot tell a constant drag from the torque reading's zero error: the line takes it as "
                "Coulomb friction, drag_constant (--assume torque_offset: the sensor's)")
    said.update(written=True, reason=why + ": written instead")
    taken = set(hand.names)
    decisions = []
    for d in selection.decisions:
        if d.name in taken:
            decisions.append(replace(d, accepted=True, reasons=[], note=f"the hand fit's ({hand.text()})"))
        elif d.accepted:
            decisions.append(replace(d, accepted=False, reasons=[why + ": written in place of the set it was in"],
                                     note=""))
        else:
            decisions.append(d)
    selection.decisions = decisions
    # two readings of one part of the loss are the selection's choice: the line replaces it (its own terms
    # are its readings: an offset, a viscous drag per direction)
    selection.ambiguous = [a for a in selection.ambiguous if a.taken is None and not set(a.effects) <= taken]
    selection.selected = list(hand.terms)
    selection.provisional = []
    selection.ranges = {k: v for k, v in selection.ranges.items() if k not in taken}
    selection.second_ranges = {k: v for k, v in selection.second_ranges.items() if k not in taken}
    cal.log.append(f"hand fit: {why}: written instead")
    return said
