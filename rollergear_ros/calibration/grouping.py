"""Which blocks are one operating point, and which are held out together (for :mod:`.blocks`).

* :func:`cells`: an operating point within a recording (direction, speed and load in 2 % bins,
  rising, falling or holding, the oil temperature by the degree): blocks of one cell visited again
  tell how much a block mean scatters (δ's repeatability, :mod:`.noise`);
* :func:`places`: an operating point across recordings (direction, speed and load in 10 % bins):
  where two stretches of the data can be compared (:mod:`.segments`);
* :func:`dwells`: consecutive blocks at one operating point (at most :data:`DWELL_MAX_S`), the unit
  cross-validation holds out, and their folds -- the recordings taken in an order of their own.

No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .samples import SampleData, recording_key

__all__ = ["CELL_RELATIVE", "DWELL_MAX_S", "PLACE_RELATIVE", "OperatingGroups", "cells", "dwells",
           "operating_groups", "pauses", "places"]


#: operating-point cells (visited again): the speed's and the torque's magnitude in bins this wide
#: (relative), the oil temperature in bins of :data:`CELL_TEMPERATURE_C`
CELL_RELATIVE = 0.02
CELL_TEMPERATURE_C = 1.0


def cells(d: SampleData, start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """A label per block for its operating-point cell: the recording, the direction, the speed's and
    (unless a spin test, whose drive torque is the loss measured) the torque's magnitude in bins
    :data:`CELL_RELATIVE` wide, whether the speed rises, falls or holds, the oil temperature's in
    :data:`CELL_TEMPERATURE_C`; -1 for a block that does not hold one operating point (its speed spans
    more than a bin)."""
    def mean(x):
        return np.add.reduceat(x, start) / count

    w = mean(d.speed)
    keys = [d.bag_id[start], np.sign(w), _log_bin(np.abs(w)), _speeding(d, start, count, w)]
    load = d.load_torque
    if not d.spin_test and load is not None:
        keys.append(_log_bin(np.abs(mean(np.nan_to_num(load)))))
    theta = mean(np.nan_to_num(d.temperature, nan=-1e6))
    keys.append(np.floor(theta / CELL_TEMPERATURE_C))
    span = np.maximum.reduceat(d.speed, start) - np.minimum.reduceat(d.speed, start)
    steady = span <= 2 * CELL_RELATIVE * np.maximum(np.abs(w), 1e-12) + 6.0 * max(d.sign_width_rad_s, 0.0)
    _u, label = np.unique(np.column_stack(keys), axis=0, return_inverse=True)
    return np.where(steady & (w != 0), label.ravel(), -1)


#: operating points across recordings (:func:`places`): the speed's and the load's magnitude in bins this
#: wide (relative)
PLACE_RELATIVE = 0.1


def places(d: SampleData, start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """A label per block for its operating point, the same in any recording: the direction, the speed's
    and (unless a spin test, whose drive torque is the loss measured) the load's magnitude in bins
    :data:`PLACE_RELATIVE` wide; -1 at standstill.  Two stretches of the data can only be told apart
    where both visit one (a loss that differs between speeds neither shares is the law's shape)."""
    def mean(x):
        return np.add.reduceat(x, start) / count

    w = mean(d.speed)
    keys = [np.sign(w), _log_bin(np.abs(w), PLACE_RELATIVE)]
    load = d.load_torque
    if not d.spin_test and load is not None:
        keys.append(_log_bin(np.abs(mean(np.nan_to_num(load))), PLACE_RELATIVE))
    _u, label = np.unique(np.column_stack(keys), axis=0, return_inverse=True)
    return np.where(w != 0, label.ravel(), -1)


def _speeding(d: SampleData, start: np.ndarray, count: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per block: +1 speeding up, −1 slowing down, 0 holding (the same speed passed on the way up and
    on the way down is not the same situation for a friction with memory)."""
    n = len(d.speed)
    within = np.arange(n) - np.repeat(start, count)
    k = np.repeat(np.maximum(count // 3, 1), count)
    first, last = within < k, within >= np.repeat(count, count) - k
    thirds = np.maximum(count // 3, 1).astype(float)
    a = np.abs(d.speed)
    drift = (np.add.reduceat(np.where(last, a, 0.0), start) - np.add.reduceat(np.where(first, a, 0.0), start)) / thirds
    tol = CELL_RELATIVE * np.abs(w) + 3.0 * max(d.sign_width_rad_s, 0.0)
    return np.where(drift > tol, 1.0, np.where(drift < -tol, -1.0, 0.0))


def _log_bin(x: np.ndarray, relative: float = CELL_RELATIVE) -> np.ndarray:
    """Magnitudes ``x`` (≥ 0) in logarithmic bins ``relative`` wide."""
    return np.floor(np.log(np.maximum(x, 1e-12)) / np.log1p(relative))


#: consecutive blocks are one dwell while speed and torque stay within this share of their level
#: plus :data:`DWELL_SCALE_SHARE` of the data's scale (the 95th percentile of their magnitude)
DWELL_LEVEL_SHARE = 0.03
DWELL_SCALE_SHARE = 0.01
DWELL_MAX_S = 5.0  #: a dwell ends after this long (whole dwells are held out: folds need many)


def dwells(d: SampleData, spd: np.ndarray, trq: np.ndarray, start: np.ndarray, block_s: float,
            folds: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dwells (consecutive blocks at the same operating point, at most :data:`DWELL_MAX_S`; each row
    of a table) and the folds, by dwell."""
    nb = len(start)
    if d.steady_state:
        dwell = np.arange(nb, dtype=np.int64)
        return dwell, _folds(d, dwell, start, folds)
    dwell = np.zeros(nb, dtype=np.int64)
    scale_w = DWELL_SCALE_SHARE * float(np.percentile(np.abs(spd), 95)) if nb else 0.0
    scale_t = DWELL_SCALE_SHARE * float(np.percentile(np.abs(trq), 95)) if nb else 0.0
    t_start = t[start].tolist()
    bag = d.bag_id[start].tolist()
    w, q = spd.tolist(), trq.tolist()
    cur, since = 0, t_start[0] if nb else 0.0
    for i in range(1, nb):
        same = (abs(w[i] - w[i - 1]) <= DWELL_LEVEL_SHARE * abs(w[i - 1]) + scale_w
                and abs(q[i] - q[i - 1]) <= DWELL_LEVEL_SHARE * abs(q[i - 1]) + scale_t
                and bag[i] == bag[i - 1] and t_start[i] - since < DWELL_MAX_S - 1e-9)
        if not same:
            cur += 1
            since = t_start[i]
        dwell[i] = cur
    return dwell, _folds(d, dwell, start, folds)


#: a pause longer than this many of its neighbours' sample periods ends a run (a test plan's gap between
#: steady runs, a recording's dropout)
GAP_PERIODS = 5.0
#: a run holds one operating point when the means of its chunks (speed, load) stay within this share of its
#: level, or within :data:`STEADY_STANDARD_ERRORS` of their noise (a ramp, a step or a reversal does not)
STEADY_SHARE = 0.1
STEADY_STANDARD_ERRORS = 4.0
#: a run shorter than this many samples holds its operating point (nothing tells otherwise)
STEADY_MIN_SAMPLES = 12
#: a run's level is judged from this many chunk means
STEADY_CHUNKS = 12
#: across stretches (:attr:`OperatingGroups.place`), loads in bins this wide (relative)
PLACE_LOAD_RELATIVE = 0.5
#: the oil temperature in bins this wide [°C] where it varies: held out like a speed or a load
GROUP_TEMPERATURE_C = 5.0


@dataclass(frozen=True)
class OperatingGroups:
    """The operating points the data hold, what cross-validation holds out together (:func:`operating_groups`)."""

    group: np.ndarray  #: per block: its operating-point group
    fold: np.ndarray  #: per block: its fold
    #: per block: its group's operating point in any recording (direction, speed, load in coarser bins)
    place: np.ndarray
    labels: list[str]  #: per group: what it is, in words ("+1.05 rad/s, load 0.0188 N·m")
    steady_share: float  #: the share of the samples in runs that hold one operating point
    transients: bool  #: whether a run's operating point moves (a ramp, a step, a reversal without a pause)
    by_operating_point: bool  #: False: too few operating points for the folds (held out by time instead)


def operating_groups(d: SampleData, start: np.ndarray, count: np.ndarray, dwell: np.ndarray,
                     folds: int) -> OperatingGroups:
    """The blocks' operating-point groups and folds: whole operating points are held out, never part of one.

    A recording is cut into runs at its pauses (:data:`GAP_PERIODS`).  A run whose operating point holds
    -- its chunks' mean speed (and output torque) within :data:`STEADY_SHARE` of its level or within the
    noise, none the other way -- is one operating point: its mean speed and load (a stick-slipping 1 rpm
    run is 1 rpm, not the 0…12 rpm its readings show).  Elsewhere (a drive cycle, ramps between dwells)
    each dwell is one, at its mean.  An operating point is its direction, its speed and load in 10 % bins
    (the load not in a spin test: the drive torque is the loss) and, where it varies, the oil temperature
    in :data:`GROUP_TEMPERATURE_C` bins; the same operating point met again, in any run or recording, is
    the same group.  Folds go over the speed, load and temperature bins diagonally (both directions of a
    speed bin together), so each fold holds out speeds and loads between others the fit sees.  With fewer operating
    points than folds the dwells are held out instead (said by :attr:`OperatingGroups.by_operating_point`)."""
    nb = len(start)
    if d.steady_state:  # each row is an operating point of its own
        w, load = d.speed[start], _abs_or_zero(d.load_torque, start)
        runs = np.arange(nb)
        run_steady = np.ones(nb, bool)
        steady_share, transients = 1.0, False
    else:
        runs, run_steady, run_w, run_load, steady_share, transients = _runs(d, start, count)
        w, load = _group_means(d, start, count, np.where(run_steady[runs], runs, -1 - dwell))
        steady_block = run_steady[runs]
        w = np.where(steady_block, run_w[runs], w)
        load = np.where(steady_block, run_load[runs], load)
    theta = np.add.reduceat(np.nan_to_num(d.temperature, nan=0.0), start) / count
    have_theta = np.isfinite(d.temperature)
    varies = bool(have_theta.mean() > 0.9 and np.ptp(d.temperature[have_theta]) >= GROUP_TEMPERATURE_C) \
        if have_theta.any() else False
    speed_bin = _log_bin(np.abs(w), PLACE_RELATIVE)
    load_bin = np.zeros(nb) if d.spin_test or d.load_torque is None else _log_bin(load, PLACE_RELATIVE)
    temp_bin = np.floor(theta / GROUP_TEMPERATURE_C) if varies else np.zeros(nb)
    keys = np.column_stack([np.sign(w), speed_bin, load_bin, temp_bin])
    _u, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    # across stretches an operating point is its direction, speed and a coarser load (a drive cycle's loads
    # seldom repeat to 10 %, and a law is smooth over a load's half): where two stretches can be compared
    coarse = np.column_stack([keys[:, 0], speed_bin, np.zeros(nb) if d.spin_test or d.load_torque is None
                              else _log_bin(load, PLACE_LOAD_RELATIVE)])
    _p, place = np.unique(coarse, axis=0, return_inverse=True)
    place = np.where(w != 0, place.ravel(), -1)
    labels = _group_labels(d, group, w, load, theta, varies)
    ranks = [np.unique(k, return_inverse=True)[1].ravel() for k in (speed_bin, load_bin, temp_bin)]
    fold = (ranks[0] + 2 * ranks[1] + 3 * ranks[2]) % max(folds, 1)
    by_point = len(np.unique(fold)) >= folds and len(np.unique(group)) >= folds
    if not by_point:
        fold = _folds(d, dwell, start, folds) if not d.steady_state else dwell % folds
    return OperatingGroups(group, fold, place, labels, steady_share, transients, by_point)


def _abs_or_zero(x: np.ndarray | None, idx: np.ndarray) -> np.ndarray:
    return np.zeros(len(idx)) if x is None else np.abs(np.nan_to_num(x[idx]))


def _group_means(d: SampleData, start: np.ndarray, count: np.ndarray, label: np.ndarray) -> tuple[np.ndarray,
                                                                                                   np.ndarray]:
    """Each block's speed and |load| as the mean over the blocks sharing its ``label`` (weighted by samples)."""
    w_sum = np.add.reduceat(d.speed, start)
    load = d.load_torque
    l_sum = np.add.reduceat(np.abs(np.nan_to_num(load)), start) if load is not None else np.zeros(len(start))
    _u, inv = np.unique(label, return_inverse=True)
    n = np.bincount(inv, weights=count)
    return (np.bincount(inv, weights=w_sum) / n)[inv], (np.bincount(inv, weights=l_sum) / n)[inv]


def _runs(d: SampleData, start: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                       np.ndarray, float, bool]:
    """Each block's run (a recording cut at its pauses), whether each run holds one operating point, each
    run's mean speed and |load| (over every sample the estimator read in it: a sticking drive's readings of 0
    included), the share of the analysed samples in steady runs, and whether any run holds a transient."""
    streams = d.recordings if d.recordings is not None and d.source_index is not None else None
    run_of_sample = np.empty(len(d.t_ns), dtype=np.int64)
    steady, speed, load = [], [], []
    for b in np.unique(d.bag_id):
        mine = np.flatnonzero(d.bag_id == b)
        if streams is not None:
            rec = streams[int(b)]
            t, w = rec.t_ns.astype(np.float64) * 1e-9, rec.speed_rad_s
            out = None if d.spin_test else rec.out_torque_nm
            at = d.source_index[mine]
        else:
            t, w = d.t_ns[mine].astype(np.float64) * 1e-9, d.speed[mine]
            out = None if d.spin_test or d.out_torque is None else d.out_torque[mine]
            at = np.arange(len(mine))
        cuts = pauses(t)
        offset = len(steady)
        for lo, hi in zip(cuts[:-1], cuts[1:]):
            o = None if out is None else out[lo:hi]
            steady.append(_holds(w[lo:hi]) and (o is None or _holds(np.nan_to_num(o))))
            speed.append(float(np.mean(w[lo:hi])))
            load.append(float(np.mean(np.abs(np.nan_to_num(o)))) if o is not None else 0.0)
        run_of_sample[mine] = offset + np.searchsorted(cuts, at, side="right") - 1
    steady_a = np.array(steady, bool)
    runs = run_of_sample[start]
    sample_steady = steady_a[run_of_sample]
    share = float(np.mean(sample_steady)) if len(sample_steady) else 1.0
    return runs, steady_a, np.array(speed), np.array(load), share, bool(not steady_a.all())


def pauses(t: np.ndarray) -> np.ndarray:
    """Where a recording's samples (times ``t`` [s]) pause: the run boundaries ``[0, …, len(t)]``.  A pause is
    a step longer than :data:`GAP_PERIODS` of the shorter step beside it, or a step back in time."""
    n = len(t)
    if n < 3:
        return np.array([0, n])
    dt = np.diff(t)
    before = np.r_[dt[0], dt[:-1]]
    after = np.r_[dt[1:], dt[-1]]
    local = np.maximum(np.minimum(before, after), 0.0)
    pause = (dt > GAP_PERIODS * local) | (dt < 0)
    return np.r_[0, np.flatnonzero(pause) + 1, n]


def _holds(x: np.ndarray) -> bool:
    """Whether a run's reading ``x`` holds one level: every one of :data:`STEADY_CHUNKS` chunk means within
    :data:`STEADY_SHARE` of the run's mean or within :data:`STEADY_STANDARD_ERRORS` standard errors of it (a
    sample's noise from the run's second differences: a ramp's are 0, a step's one sample, a stick-slip's
    bursts count as noise), and no chunk the other way (a reversal, sweeps both ways about 0)."""
    n = len(x)
    if n < STEADY_MIN_SAMPLES:
        return True
    sigma = float(np.sqrt(np.mean(np.diff(x, 2) ** 2) / 6.0))
    chunks = np.array([float(np.mean(c)) for c in np.array_split(x, min(STEADY_CHUNKS, n // 4))])
    level = float(np.mean(x))
    tolerance = max(STEADY_SHARE * abs(level), STEADY_STANDARD_ERRORS * sigma / math.sqrt(n / len(chunks)))
    return bool(np.max(np.abs(chunks - level)) <= tolerance and not np.any(chunks * level < 0))


def _group_labels(d: SampleData, group: np.ndarray, w: np.ndarray, load: np.ndarray, theta: np.ndarray,
                  varies: bool) -> list[str]:
    """Each group's operating point in words: its mean speed, load and oil temperature."""
    labels = []
    for g in range(int(group.max()) + 1 if len(group) else 0):
        k = np.flatnonzero(group == g)
        text = f"{float(np.mean(w[k])):+.4g} rad/s"
        if not d.spin_test and d.load_torque is not None:
            text += f", load {float(np.mean(load[k])):.4g} N·m"
        if varies:
            text += f", oil {float(np.mean(theta[k])):.0f} °C"
        labels.append(text)
    return labels


def _folds(d: SampleData, dwell: np.ndarray, start: np.ndarray, folds: int) -> np.ndarray:
    """Each dwell's fold: dwells counted in turn, the recordings taken in an order of their own (first
    stamp, length, content) -- not the order they were given in, so that which dwells are held out
    together, and what the selection decides from it, is the same for the same recordings listed
    in any order."""
    bag = d.bag_id[start]
    ids = np.unique(bag)
    if len(ids) < 2:
        return dwell % folds

    def key(b: int) -> tuple:
        mine = d.bag_id == b
        # a table's rows are stamped by their place in the tables given: only their values count
        return recording_key(0 if d.steady_state else int(d.t_ns[mine][0]), d.torque[mine], d.speed[mine])

    offset, fold = 0, np.empty(len(dwell), dtype=np.int64)
    for b in sorted(ids.tolist(), key=key):
        mine = bag == b
        # each of its dwells' place among them (a table's group may interleave with another's rows)
        distinct, rank = np.unique(dwell[mine], return_inverse=True)
        fold[mine] = (rank + offset) % folds
        offset += len(distinct)
    return fold
