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

import numpy as np

from .samples import SampleData, recording_key

__all__ = ["CELL_RELATIVE", "DWELL_MAX_S", "PLACE_RELATIVE", "cells", "dwells", "places"]


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
