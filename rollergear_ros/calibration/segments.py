"""Changes inside the recordings: where the gearbox stopped being the one it was.

A parameter fitted across a change is neither side's (a drag that appears half-way is fitted as half
a drag, or as a model parameter moved far from both).  After a first analysis, the recordings (in
time order; a split between two recordings first) are searched for the one split that explains
their residual best when a flexible
design -- the accepted terms, every testable candidate at the middle of its exponent's grid, a
level and a direction-dependent level -- is fitted on each side apart (weighted least squares over
block means; every split at a block boundary, both sides at least :data:`MIN_STRETCH_S` and
:data:`MIN_STRETCH_SHARE` of the blocks).  Only the operating points both sides visit (direction and
speed in 10 % bins, the load in 50 % bins) can tell a change from the operating point: each side holds at
least :data:`MIN_SHARED_SHARE` of its samples there (a test plan that sweeps the speed has none: said,
and no change is claimed).  The best split is a change when

* the accepted terms with a level and a direction-dependent level, fitted on each side apart,
  predict the held-out blocks at those operating points better than one fit across it (by more than
  the selection's minimum improvement, the analysis' folds: whole operating points),
* what the change changes -- the RMS of the difference between the flexible fits on each side and one
  across, over the blocks at operating points both sides visit (where only one side has data, a side's
  fit extrapolates) -- exceeds δ, and
* their coefficients differ significantly (a cluster-robust Wald test by dwell at :data:`CHANGE_ALPHA`).

Its time comes with the range of splits whose fit is within the χ² threshold of the best.  The
latest stretch is then searched again, up to :data:`MAX_CHANGES` changes.  Recordings whose clocks
overlap (each from 0) are in no order in time: no latest stretch, so no change is searched across
or inside them (:func:`in_time_order`); each recording is tested against the others instead, by the
same test (:func:`differing_recording`).  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .leastsquares import orthonormal_basis, wls
from .selection import Calibrator, Term, members
from ..core.effects import EFFECTS, viscosity_law

__all__ = ["Outlier", "Split", "differing_recording", "find_changes", "in_time_order", "running_time",
           "small_design"]

MIN_STRETCH_S = 20.0  #: a stretch between changes is at least this long ...
MIN_STRETCH_SHARE = 0.1  #: ... and holds at least this share of the blocks searched
MAX_CHANGES = 4
#: each side of a change holds at least this share of its samples at operating points the other side visits
MIN_SHARED_SHARE = 0.2
CHANGE_ALPHA = 1e-4  #: the Wald test of a change (strict: the split is the best of many)


@dataclass(frozen=True)
class Split:
    """A change found: the first block after it, and its numbers."""

    block: int
    t_s: float  #: seconds after the first sample analysed (the recordings one after another)
    ci95_s: tuple[float, float]
    rms_change_nm: float
    heldout_one_nm: float
    heldout_two_nm: float
    between_recordings: bool = False  #: at the start of a recording
    shift_nm: float = 0.0  #: the loss after it minus before, at the operating points both sides visit


def find_changes(cal: Calibrator, terms: list[Term], said: list[str] | None = None) -> list[Split]:
    """The changes in ``cal``'s blocks (the recordings one after another, in their own order:
    :func:`~.samples.recording_key`, first stamp first), the latest last; ``said``: gets a sentence for a
    split that fits better but shares too few operating points with the rest to be told from them."""
    b = cal.b
    if b.steady_state or b.t_s is None or len(b.y) < 8 * cal_folds(cal) or not in_time_order(b):
        return []
    t = running_time(b)
    # each design as an orthonormal basis of its columns: the same fits, tests and splits, computed at
    # the basis's condition (1), not the design's (~1e9 with a drag per rad/s beside a level)
    x = orthonormal_basis(_design(cal, terms, flexible=True), b.weight)
    small = orthonormal_basis(_design(cal, terms, flexible=False), b.weight)
    changes: list[Split] = []
    lo = 0
    while len(changes) < MAX_CHANGES:
        # between two recordings first (one may be another gearbox, or the same one days later), then within
        split = _best_split(cal, x, small, t, lo, len(b.y), boundaries=True, said=said) or \
            _best_split(cal, x, small, t, lo, len(b.y), said=said)
        if split is None:
            break
        changes.append(split)
        lo = split.block
    return changes


def running_time(b) -> np.ndarray:
    """Each block's time [s] on one clock: the recordings one after another in their own order
    (:func:`~.samples.recording_key`), each from where the one before ended."""
    t = b.t_s[b.start].astype(float)
    bag = b.bag_id[b.start]
    out = np.empty(len(t))
    offset = 0.0
    for k in np.unique(bag):  # bag ids count the recordings in that order
        i = np.flatnonzero(bag == k)
        out[i] = t[i] - t[i[0]] + offset
        offset = out[i[-1]] + 1.0
    return out


@dataclass(frozen=True)
class Outlier:
    """A recording that differs from the others, when their times overlap (no order in time)."""

    bag: int  #: its index among the recordings as loaded (:func:`~.samples.recording_key` order)
    rms_change_nm: float
    heldout_one_nm: float
    heldout_two_nm: float


def differing_recording(cal: Calibrator, terms: list[Term], said: list[str] | None = None) -> Outlier | None:
    """Of recordings whose times overlap, the one that differs most from the others by the test of a
    change (see the module docstring: the held-out gain of a fit of its own, what it changes at the
    operating points it shares with the others beyond δ, a Wald test), or None: they can be fitted as
    one gearbox."""
    b = cal.b
    if b.steady_state or b.t_s is None or len(b.y) < 8 * cal_folds(cal) or in_time_order(b):
        return None
    x = orthonormal_basis(_design(cal, terms, flexible=True), b.weight)
    small = orthonormal_basis(_design(cal, terms, flexible=False), b.weight)
    bag = b.bag_id[b.start]
    found = []
    for k in np.unique(bag).tolist():
        why: list[float] = []
        tested = _change(cal, x, small, 0, bag == k, why)
        if why and said is not None and not said:
            said.append(f"the recordings' times overlap, and one of them shares {100 * why[0]:.0f} % of its samples' "
                        f"operating points with the others (needs {100 * MIN_SHARED_SHARE:g} %): whether they are one "
                        "gearbox cannot be told from the operating point -- they are analysed as one (calibrate them "
                        "apart if they are not)")
        if tested is not None:
            one, two, rms_change, _shift = tested
            found.append((one - two, -k, Outlier(int(k), rms_change, one, two)))
    return max(found, key=lambda f: f[:2])[2] if found else None


def in_time_order(b) -> bool:
    """Whether the recordings' clocks put them one after another (each starts after the one before
    ended): only then is there a latest stretch.  Recordings whose times overlap (each from 0, a
    table's import, a DAQ's relative clock) have no order in time to search for a change in."""
    ids = np.unique(b.bag_id)
    if len(ids) < 2:
        return True
    spans = sorted((float(b.t_s[b.bag_id == k].min()), float(b.t_s[b.bag_id == k].max())) for k in ids)
    return all(after[0] > before[1] for before, after in zip(spans, spans[1:]))


def cal_folds(cal: Calibrator) -> int:
    return int(cal.b.fold.max()) + 1 if len(cal.b.fold) else 1


def small_design(cal: Calibrator, terms: list[Term]) -> np.ndarray:
    """The accepted terms' columns with a level and a direction-dependent level (one fit across a change)."""
    return _design(cal, terms, flexible=False)


def _design(cal: Calibrator, terms: list[Term], flexible: bool) -> np.ndarray:
    """The accepted terms' columns (nuisances first), a level and a direction-dependent level; with
    ``flexible``, every testable candidate's at the middle of its exponent's grid too -- what the
    operating point explains, so that a residual that follows it (a warm-up's temperature, a speed the
    accepted terms miss) is no change in time."""
    b = cal.b
    x = cal.design(terms)
    sign = np.sign(b.speed)
    extra = [np.ones(len(b.y))]
    if len(np.unique(sign)) > 1:
        extra.append(sign)
    for name in b.testable if flexible else ():
        cands = members(b, name, cal.oil_law(terms) or _default_law(name))
        if cands:
            extra.append(cands[len(cands) // 2].column)
    full = np.column_stack([x, *extra]) if x.shape[1] else np.column_stack(extra)
    keep = _independent(full, b.weight)
    return full[:, keep]


def _independent(x: np.ndarray, w: np.ndarray) -> list[int]:
    """Columns of ``x`` that add something (a pivoted QR of the weighted design)."""
    from scipy.linalg import qr

    xs = x * np.sqrt(w)[:, None]
    norms = np.linalg.norm(xs, axis=0)
    xs = xs / np.where(norms > 0, norms, 1.0)
    _q, r, piv = qr(xs, mode="economic", pivoting=True)
    d = np.abs(np.diag(r))
    rank = int(np.sum(d > 1e-8 * (d[0] if len(d) else 1.0)))
    return sorted(piv[:rank].tolist())


def _default_law(name: str) -> tuple[float, float, float] | None:
    """An effect that follows the oil, at its registry's Vogel law (for the search's design only)."""
    e = EFFECTS.get(name)
    if e is None or not e.oil_law:
        return None
    law = viscosity_law().simulated_defaults()
    return (law["B"], law["C"], law["theta_ref"])


def _best_split(cal: Calibrator, x: np.ndarray, small: np.ndarray, t: np.ndarray, lo: int, hi: int,
                boundaries: bool = False, said: list[str] | None = None) -> Split | None:
    """The best split of blocks ``[lo, hi)`` if it is a change (see the module docstring): found and
    tested with the flexible design ``x``, held out with the ``small`` one (a flexible design fitted
    on part of a stretch extrapolates to its held-out dwells); ``boundaries``: only between recordings."""
    b = cal.b
    y, w = b.y[lo:hi], b.weight[lo:hi]
    xs = x[lo:hi]
    n, k = xs.shape
    tt = t[lo:hi]
    if n < 4 * k or tt[-1] - tt[0] < 2 * MIN_STRETCH_S:
        return None
    a = np.einsum("i,ij,il->ijl", w, xs, xs)
    v = xs * (w * y)[:, None]
    s = w * y * y
    ca, cv, cs = np.cumsum(a, axis=0), np.cumsum(v, axis=0), np.cumsum(s)
    min_n = max(int(MIN_STRETCH_SHARE * n), 2 * k, 10)
    cand = np.arange(min_n, n - min_n)  # the first block of the right side
    cand = cand[(tt[cand] - tt[0] >= MIN_STRETCH_S) & (tt[-1] - tt[cand] >= MIN_STRETCH_S)]
    bag = b.bag_id[b.start[lo:hi]]
    between = cand[bag[cand] != bag[cand - 1]]
    if len(between) and boundaries:  # recordings one after another: a change between them first
        cand = between
    if not len(cand):
        return None
    left = _sse(ca[cand - 1], cv[cand - 1], cs[cand - 1])
    right = _sse(ca[-1] - ca[cand - 1], cv[-1] - cv[cand - 1], cs[-1] - cs[cand - 1])
    total = left + right
    if not np.any(np.isfinite(total)):
        return None
    best = float(np.nanmin(total))
    j = int(np.flatnonzero(total <= best + TIE * abs(best))[0])
    split = int(cand[j])
    why: list[float] = []
    tested = _change(cal, xs, small[lo:hi], lo, np.arange(n) >= split, why)
    if tested is None:
        text = (f"the residual's best split in time, at {float(tt[split]):.1f} s, falls between stretches that share "
                f"{100 * why[0]:.0f} % of their samples' operating points (needs {100 * MIN_SHARED_SHARE:g} % on "
                "each side): a change there cannot be told from the operating point -- no change is claimed, every "
                "sample is analysed at once (a repeated operating point after the suspected change would tell)"
                if why else "")
        if text and said is not None and text not in said:
            said.append(text)
        return None
    one, two, rms_change, shift = tested
    dof = max(n - 2 * k, 1)
    sigma2 = max(float(total[j]) / dof, 1e-300)
    near = cand[np.isfinite(total) & (total <= total[j] + 3.84 * sigma2)]
    ci = (float(tt[near.min()]), float(tt[near.max()]))
    return Split(lo + split, float(tt[split]), ci, rms_change, one, two, bool(bag[split] != bag[split - 1]), shift)


def _change(cal: Calibrator, xs: np.ndarray, small: np.ndarray, lo: int, later: np.ndarray,
            why: list[float] | None = None) -> tuple[float, float, float, float] | None:
    """Whether the blocks ``later`` (a mask over the stretch from block ``lo``) differ from the others
    (see the module docstring): their held-out RMSE with one fit and with a fit on each side, and what
    the change changes; None when it is no change (``why``: gets the smaller side's share of samples at
    shared operating points where that is too few for the two sides to be compared).

    Only the operating points both sides visit can tell a change from the operating point (elsewhere a
    side's fit extrapolates: a difference there is the law's shape): each side holds at least
    :data:`MIN_SHARED_SHARE` of its samples at them, and the held-out comparison is made there."""
    b = cal.b
    n = len(later)
    y, w = b.y[lo:lo + n], b.weight[lo:lo + n]
    shared = _shared_places(b.place[lo:lo + n], later) if b.place is not None else np.ones(n, bool)
    count = b.count[lo:lo + n]
    shares = [float(np.sum(count[side & shared]) / max(np.sum(count[side]), 1.0)) for side in (~later, later)]
    if min(shares) < MIN_SHARED_SHARE:
        if why is not None:
            why.append(min(shares))
        return None
    one = _cv_rmse(cal, small, y, w, lo, None, shared)
    two = _cv_rmse(cal, small, y, w, lo, later, shared)
    if not (one > 0 and (one - two) / one > cal.min_improvement):
        return None
    one_fit = xs @ wls(xs, y, w).coef
    two_fits = np.empty(n)
    for side in (~later, later):
        two_fits[side] = xs[side] @ wls(xs[side], y[side], w[side]).coef
    diff = (two_fits - one_fit)[shared]
    rms_change = float(np.sqrt(np.average(diff * diff, weights=b.count[lo:lo + n][shared])))
    if rms_change <= cal.delta or not _significant(xs, y, w, b.dwell[lo:lo + n], later):
        return None
    # the signed shift: the later side's fit against the earlier one's, at the operating points both visit
    before_fit, after_fit = (wls(xs[side], y[side], w[side]).coef for side in (~later, later))
    shift = float(np.average(xs[shared] @ (after_fit - before_fit), weights=b.count[lo:lo + n][shared]))
    return one, two, rms_change, shift


def _shared_places(place: np.ndarray, later: np.ndarray) -> np.ndarray:
    """The blocks at an operating point (:func:`~.grouping.places`) both sides visit."""
    both = np.intersect1d(place[~later], place[later])
    return np.isin(place, both[both >= 0])


#: the split search's normal equations (over an orthonormal basis: the whole stretch's is the identity)
#: get this ridge, so that a direction one side barely holds is not fitted from rounding noise
RIDGE = 1e-9
#: splits whose residual sums of squares lie within this share of the best are a tie, taken at the
#: earliest: which of them the CPU's rounding ranks first decides nothing
TIE = 1e-7


def _sse(a: np.ndarray, v: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Weighted residual sum of squares of each fit from its cross-products (with :data:`RIDGE`)."""
    k = a.shape[-1]
    beta = np.linalg.solve(a + RIDGE * np.eye(k), v[..., None])[..., 0]
    return s - np.einsum("ij,ij->i", beta, v)


def _cv_rmse(cal: Calibrator, x: np.ndarray, y: np.ndarray, w: np.ndarray, lo: int,
             later: np.ndarray | None, judged: np.ndarray | None = None) -> float:
    """Held-out RMSE (the analysis' folds: whole operating points) of one fit over the blocks, or of one
    fit on each side (``later`` and the others), over the blocks ``judged`` (None: all)."""
    fold = cal.b.fold[lo:lo + len(y)]
    count = cal.b.count[lo:lo + len(y)]
    pred = np.zeros(len(y))
    sides = [np.arange(len(y))] if later is None else [np.flatnonzero(~later), np.flatnonzero(later)]
    for side in sides:
        for f in np.unique(fold[side]):
            test = side[fold[side] == f]
            train = side[fold[side] != f]
            if len(train) <= x.shape[1]:
                return math.inf
            coef = wls(x[train], y[train], w[train]).coef
            pred[test] = x[test] @ coef
    e = y - pred
    if judged is not None:
        e, count = e[judged], count[judged]
    return float(np.sqrt(np.average(e * e, weights=count)))


#: a direction of the design counts on a side holding at least this share of its weight (with the
#: basis orthonormal over the stretch, the shares of the two sides add up to 1)
TESTABLE_SHARE = 1e-6


def _significant(x: np.ndarray, y: np.ndarray, w: np.ndarray, dwell: np.ndarray, later: np.ndarray) -> bool:
    """A cluster-robust Wald test (by dwell) that the ``later`` side's coefficients differ from the others',
    over the directions of ``x`` both sides hold (at least :data:`TESTABLE_SHARE` of its weight each):
    a direction one side barely holds has no coefficient there to compare (its difference would be
    rounding noise divided by next to nothing)."""
    from scipy.special import chdtri  # chi2.isf without importing scipy.stats

    q = orthonormal_basis(x, w)
    before = ~later
    qb = q[before] * np.sqrt(w[before])[:, None]
    share, vectors = np.linalg.eigh(qb.T @ qb)  # each direction's share of the weight left of the split
    both = (share >= TESTABLE_SHARE) & (share <= 1.0 - TESTABLE_SHARE)
    if not both.any():
        return False
    rotated = q @ vectors
    tested = rotated[:, both] * (~before)[:, None]
    fit = wls(np.column_stack([rotated, tested]), y, w, dwell)
    k = rotated.shape[1]
    d = fit.coef[k:]
    cov = fit.cov[k:, k:]
    try:
        stat = float(d @ np.linalg.solve(cov, d))
    except np.linalg.LinAlgError:
        stat = float(d @ np.linalg.pinv(cov) @ d)
    return math.isfinite(stat) and stat > chdtri(int(both.sum()), CHANGE_ALPHA)
