"""Message records laid out for whole arrays of messages (no rclpy).

:func:`lay_out_records` places records of several payload widths in one buffer -- each record as
:func:`.records.message_rows` frames it -- with sequence numbers counted per channel, and
:func:`interleave` puts the records of several channels in their order.  A C function (``_records.c``,
built by setup.py where a compiler is found) lays out exactly the same bytes in one pass; numpy does
where it was not built.  Both are tested against the ``mcap`` library's encoder of each record.
"""

from __future__ import annotations

import functools

import numpy as np

from .records import MESSAGE_FIXED, byte_rows, message_rows

try:  # the record layout in C (built by setup.py where a compiler is found)
    from ._records import records as _native_records
except ImportError:  # pragma: no cover - a build without a compiler: numpy lays out the records
    _native_records = None


def lay_out_records(starts: np.ndarray, size: int, channel_id: np.ndarray, log_time: np.ndarray,
                    group: np.ndarray, row: np.ndarray, payloads: list[np.ndarray], counters: np.ndarray,
                    period_hint: list[int] | None = None, native: bool | None = None,
                    publish_time: np.ndarray | None = None) -> np.ndarray:
    """The bytes (``size`` of them) of ``n`` message records (:func:`message_rows`' layout): record
    ``i`` starts at ``starts[i]``, is on channel ``channel_id[i]`` at ``log_time[i]``, published at
    ``publish_time[i]`` (None: its log time), and carries row ``row[i]`` of ``payloads[group[i]]``
    (each an m × L uint8 array).  Sequence numbers count on from ``counters`` (int64, indexed by
    channel id; updated in place), each channel by itself.

    ``native``: the C function (True), numpy (False), or C where built (None); same bytes either way.
    ``period_hint``: for the numpy path, as in :func:`interleave`.
    """
    as_int64 = functools.partial(np.ascontiguousarray, dtype=np.int64)
    starts, channel_id, log_time, group, row = map(as_int64, (starts, channel_id, log_time, group, row))
    publish = log_time if publish_time is None else as_int64(publish_time)
    payloads = [np.ascontiguousarray(p, dtype=np.uint8) for p in payloads]
    _check_layout(starts, size, channel_id, log_time, publish, group, row, payloads, counters)
    if native is None:
        native = _native_records is not None
    out = np.empty(size, dtype=np.uint8)
    if native:
        _native_records(out, starts, channel_id, log_time, publish, group, row, payloads, counters)
        return out
    seq = np.empty(len(starts), dtype=np.int64)
    for cid, where in (by_channel(channel_id) if len(starts) else []):
        k = len(starts) if where is None else len(where)
        seq[slice(None) if where is None else where] = np.arange(counters[cid] + 1, counters[cid] + k + 1)
        counters[cid] += k
    rows = {}
    for g in range(len(payloads)):
        where = np.flatnonzero(group == g)
        if len(where):
            rows[g] = message_rows(channel_id[where], log_time[where], payloads[g][row[where]], seq[where],
                                   None if publish_time is None else publish[where])
    if len(rows) == 1 and len(starts) and (np.diff(starts) == rows[int(group[0])].shape[1]).all():
        out[starts[0]:starts[0] + rows[int(group[0])].nbytes] = rows[int(group[0])].reshape(-1)
        return out
    out[:] = interleave(group, rows, starts, size, period_hint)
    return out


def _check_layout(starts: np.ndarray, size: int, channel_id: np.ndarray, log_time: np.ndarray,
                  publish_time: np.ndarray, group: np.ndarray, row: np.ndarray, payloads: list[np.ndarray],
                  counters: np.ndarray) -> None:
    """Every index of a layout checked before either path writes a byte or counts a message (the C
    function checks them again, for any caller): a bad one is a ValueError, ``counters`` untouched."""
    n = len(starts)
    if not all(len(a) == n for a in (channel_id, log_time, publish_time, group, row)):
        raise ValueError("starts, channel, log_time, publish_time, group and row: one value per record each")
    if not (isinstance(counters, np.ndarray) and counters.dtype == np.int64 and counters.ndim == 1
            and counters.flags.c_contiguous and counters.flags.writeable):
        raise ValueError("counters: a writeable 1-D int64 array")
    if any(p.ndim != 2 for p in payloads):
        raise ValueError("payloads: 2-D uint8 arrays")
    if not n:
        return
    if group.min() < 0 or group.max() >= len(payloads):
        i = int(np.flatnonzero((group < 0) | (group >= len(payloads)))[0])
        raise ValueError(f"group[{i}] = {int(group[i])}: no such payload array")
    heights = np.array([p.shape[0] for p in payloads], dtype=np.int64)
    widths = np.array([p.shape[1] for p in payloads], dtype=np.int64)
    bad = (row < 0) | (row >= heights[group])
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"row[{i}] = {int(row[i])}: beyond its payload array")
    bad = (channel_id < 0) | (channel_id >= len(counters)) | (channel_id > 0xFFFF)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"channel[{i}] = {int(channel_id[i])}: no counter")
    bad = (starts < 0) | (starts > size - 9 - MESSAGE_FIXED - widths[group])
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"starts[{i}] = {int(starts[i])}: the record ends beyond out")


def by_channel(ids: np.ndarray) -> list[tuple[int, np.ndarray | None]]:
    """Each channel in ``ids`` with the positions of its messages, ascending (None: all of them)."""
    if ids[0] == ids[-1] and (ids == ids[0]).all():
        return [(int(ids[0]), None)]
    order = np.argsort(ids.astype(np.uint16), kind="stable")  # channel ids are 16-bit: a radix sort
    counts = np.bincount(ids)
    present = np.flatnonzero(counts)
    return list(zip(present.tolist(), np.split(order, np.cumsum(counts[present])[:-1])))


def interleave(group: np.ndarray, rows: dict[int, np.ndarray], offsets: np.ndarray, size: int,
               period_hint: list[int] | None = None) -> np.ndarray:
    """The bytes of records of several widths in the order ``group`` gives: record ``i`` is the next
    unused row of ``rows[group[i]]`` and starts at ``offsets[i]`` (``size`` bytes in all).

    A replay's output repeats one pattern per sample (four Float64 messages, a stamped estimate,
    the copied inputs): where the sequence of ``group`` repeats with a period, the bytes are a 2-D
    array of one period per row, and each slot of the pattern is copied as one strided column
    block; the rest (the messages that break the pattern) are scattered byte by byte.
    ``period_hint``: a one-element list with the period found last time (tried first, updated).
    """
    out = np.empty(size, dtype=np.uint8)
    n = len(group)
    rank = np.empty(n, dtype=np.int64)  # index of each record among its group's rows
    for g in rows:
        where = np.flatnonzero(group == g)
        rank[where] = np.arange(len(where))
    done = np.zeros(n, dtype=bool)
    plans: dict[bytes, list[tuple[int, int, int, int, int]]] = {}
    for m0, m1, period in _periodic_stretches(group, period_hint):
        motif = group[m0:m0 + period]
        plan = plans.get(motif.tobytes())
        if plan is None:  # the motif's runs of one group: (first slot, slots, group, its rows per period, place)
            cuts = np.flatnonzero(np.diff(motif)) + 1
            plan = plans[motif.tobytes()] = [
                (j, j_end - j, int(motif[j]), int(np.count_nonzero(motif == motif[j])),
                 int(np.count_nonzero(motif[:j] == motif[j])))
                for j, j_end in zip([0, *cuts.tolist()], [*cuts.tolist(), period])]
        per_bytes = int(offsets[m0 + period] - offsets[m0])  # m1 - m0 >= 2 periods
        k = (m1 - m0) // period
        block = out[offsets[m0]:offsets[m0] + k * per_bytes].reshape(k, per_bytes)
        for j, length, g, count, slot in plan:
            width = rows[g].shape[1]
            first = int(rank[m0 + j]) - slot  # the stretch's first row of group g
            src = rows[g][first:first + k * count].reshape(k, count * width)
            col = int(offsets[m0 + j] - offsets[m0])
            block[:, col:col + length * width] = src[:, slot * width:(slot + length) * width]
        done[m0:m1] = True
    for g in rows:
        where = np.flatnonzero((group == g) & ~done)
        if len(where):
            width = rows[g].shape[1]
            byte_rows(out, width, writeable=True)[offsets[where]] = rows[g][rank[where]]
    return out


def _periodic_stretches(group: np.ndarray, period_hint: list[int] | None = None, max_period: int = 32,
                        min_repeats: int = 4):
    """(start, stop, period) of the stretches of ``group`` that repeat a pattern ``period`` long at
    least ``min_repeats`` times (the period that covers the most of the sequence; ``period_hint``
    as in :func:`interleave`)."""
    probe = group[:1024]  # the period is chosen on the first messages, then applied to all
    hint = period_hint[0] if period_hint else 0
    if 0 < hint < len(probe) and np.count_nonzero(probe[hint:] == probe[:-hint]) >= 0.9 * (len(probe) - hint):
        best = hint
    else:
        best, best_count = 0, -1
        for period in range(1, min(max_period, len(probe) // min_repeats) + 1):
            count = int(np.count_nonzero(probe[period:] == probe[:-period]))
            if count > best_count + period:  # a multiple of the period matches about as often: the shortest
                best, best_count = period, count
        if best == 0:
            return []
        if period_hint is not None:
            period_hint[:] = [best]
    best_same = group[best:] == group[:-best]
    # runs of True in `same`: group[i] == group[i + period] for i in [s, e) -> [s, e + period) repeats
    edges = np.diff(np.concatenate([[0], best_same.view(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = []
    for s, e in zip(starts.tolist(), stops.tolist()):
        k = (e + best - s) // best
        if k >= min_repeats:
            out.append((s, s + k * best, best))
    return out
