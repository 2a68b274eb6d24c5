"""A time slice of a recording replayed on its own (fleets split long recordings into slices that
add up to the whole replay).  No rclpy import."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ..core.batchpath import BatchEstimate
from .inputs import InputBatch
from .summary import Accumulator, ReplaySummary

__all__ = ["MEMORY_LEAD_NS", "TimeWindow"]


#: the lead-in of a time slice when an accepted effect has memory: the slice's state starts from the
#: motion of this long before it (a Dahl state is exactly its direction after a fraction of a radian)
MEMORY_LEAD_NS = 60 * 10**9


class TimeWindow:
    """A time slice ``[start_ns, end_ns)`` of a recording (``None``: open), replayed on its own.

    The estimator is fed the messages from ``lead_ns`` before the slice to as much after its end --
    twice the longest the estimator holds anything: the oil temperature (5 s), a motor message
    waiting for its partner (``staleness_s``; 5 s over a lossless arrival delivery) -- so that the
    samples at the slice's edges are paired, and carry the temperature, as in a replay of the whole
    recording; only estimates whose sample time lies in the slice are kept.  The counts
    (samples, input messages, skips, change alarms) are those taken while the slice's own messages
    were pushed.  Slices of one recording therefore add up to the whole replay, except that each
    slice's online adaptation and change detector start from the parameter file (as a recording's do).
    With an effect with memory the lead-in is at least :data:`MEMORY_LEAD_NS`: its state at the
    slice's start is then the whole replay's, unless the gearbox rested that long before it.
    """

    def __init__(self, start_ns: int | None, end_ns: int | None, lead_ns: int) -> None:
        self.start_ns, self.end_ns = start_ns, end_ns
        self.lead_ns = lead_ns
        self.done = False  #: the lead-out has been read: stop reading
        self.input_messages = 0
        self.samples = 0
        self._at_start: tuple[dict[str, int], int] | None = None  # (skip counts, alarms) when the slice began
        self._at_end: tuple[dict[str, int], int] | None = None

    def read_range(self) -> tuple[int, int] | None:
        """The log-time range to read (chunks outside it are skipped unread)."""
        lo = -(2**63) if self.start_ns is None else self.start_ns - self.lead_ns
        hi = 2**63 - 1 if self.end_ns is None else self.end_ns + self.lead_ns
        return lo, hi

    def split(self, batch: InputBatch, estimator) -> Iterator[tuple[np.ndarray, ...]]:
        """The batch's messages before, inside and after the slice, in that order, as ``(codes,
        t_ns, values, source_ns or None)`` (counts are snapshot where the slice begins and ends)."""
        t = batch.t_ns
        lo = -(2**63) if self.start_ns is None else self.start_ns
        hi = 2**63 - 1 if self.end_ns is None else self.end_ns
        phase = (t >= lo).astype(np.int8) + (t >= hi)
        for p in (0, 1, 2):
            sel = phase == p
            if p >= 1 and self._at_start is None and sel.any():
                self._at_start = (dict(estimator.counts), estimator.detector.alarms)
            if p == 2 and sel.any() and self._at_end is None:
                self._at_end = (dict(estimator.counts), estimator.detector.alarms)
            if not sel.any():
                continue
            codes = batch.codes[sel]
            if p == 1:
                self.input_messages += batch.messages_between(lo, hi, sel)
                self.samples += int(np.count_nonzero(codes == 0))
            if p == 2 and int(t[sel].max()) >= hi + self.lead_ns:
                self.done = True
            yield codes, t[sel], batch.values[sel], None if batch.source_ns is None else batch.source_ns[sel]

    def keep(self, b: BatchEstimate | None, acc: Accumulator) -> BatchEstimate | None:
        """The estimates of samples inside the slice (one before it primes the energy integral)."""
        if b is None or len(b.t_ns) == 0:
            return b
        t = b.t_ns
        inside = np.ones(len(t), bool)
        if self.start_ns is not None:
            before = t < self.start_ns
            if before.any():
                acc.prime(int(t[before].max()))
            inside &= ~before
        if self.end_ns is not None:
            inside &= t < self.end_ns
        return b if inside.all() else b.select(inside)

    def finish(self, summary: ReplaySummary, estimator, acc: Accumulator) -> None:
        """The slice's own counts in ``summary``."""
        counts_now = (dict(estimator.counts), estimator.detector.alarms)
        # an open start counts from zero (what decoding counted before the first push is the slice's)
        zero = ({k: 0 for k in counts_now[0]}, 0)
        start = zero if self.start_ns is None or self._at_start is None else self._at_start
        end = self._at_end or counts_now
        summary.skipped = {k: end[0][k] - start[0].get(k, 0) for k in end[0]}
        summary.alarms = end[1] - start[1]
        lo = -(2**63) if self.start_ns is None else self.start_ns
        hi = 2**63 - 1 if self.end_ns is None else self.end_ns
        inside = [(t, f) for t, f in zip(summary.alarm_times_ns, summary.alarm_from_start) if lo <= t < hi]
        summary.alarm_times_ns, summary.alarm_from_start = [t for t, _ in inside], [f for _, f in inside]
        summary.samples = self.samples
        summary.input_messages = self.input_messages
        summary.estimated = acc.n
