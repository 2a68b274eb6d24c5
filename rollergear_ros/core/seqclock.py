"""A sample clock rebuilt from the publishers' sequence numbers (``node.sample_clock: sequence``).

``std_msgs/Float64`` carries no stamp.  The live node otherwise times each input by its arrival or its
publisher's timestamp, and both jitter: a busy machine, a stalled executor taking its queues in a
burst.  Channel lags (``estimator.<channel>_lag_s``) read a channel at ``t + τ``, so that jitter
becomes torque and speed errors.  A rig's acquisition loop publishes every input once per period:
message ``k`` of a topic is sample ``k``.  :class:`SequenceClock` gives each message the time of its
slot on one grid, ``anchor + slot × period``:

- the first message of the stream is slot 0 at its reference time (the publisher's timestamp, else
  its arrival).  The publishers number their messages alike -- sample ``k`` is message ``k`` on every
  topic, as one acquisition loop's publishers do -- so a topic's first message takes the slot its
  number gives beside the topic timed first, where that topic's message of the slot was published
  less than :data:`PAUSE_S` from it; else the slot nearest its reference time, counted from the
  recent message of any topic whose reference time is nearest.  Whether the numbers were alike is
  seen afterwards: over a topic's first :data:`RATE_LEARN` messages, its publisher's timestamps and
  those of the messages it is paired with lie more than half a period apart, typically
  (:attr:`SequenceClock.step_problem`: said);
- each later message moves its topic on by as many slots as its publisher's sequence number moved
  (a message lost in delivery leaves its slot empty);
- a pause in publishing -- the publisher's timestamps further apart than the numbers allow by more
  than :data:`PAUSE_S` -- moves the topic to the slot nearest its reference time (never back: the
  times on a topic only grow); so does a publisher that started again (its numbers went back).

Delivery jitter, a stalled node and a catch-up burst therefore change no time, and the lags read
the channels as replay reads a recording whose log times are that grid.  Where the publishers'
timestamps say they publish at another rate than the clock's (a recording played faster, a wrong
``node.expected_rate_hz``), :attr:`SequenceClock.rate_problem` says so.  No rclpy import.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["PAUSE_S", "RATE_LEARN", "RATE_TOLERANCE", "RECENT", "SILENT_S", "ClockMerge", "SequenceClock"]

#: a publisher whose timestamps lie this much further apart than its numbers allow paused publishing;
#: shorter, it was held up (a reliable publisher waits while its subscriber stalls) and catches up
PAUSE_S = 10.0
RATE_LEARN = 64  #: the publishers' rate is the median of this many of a topic's first intervals
RATE_TOLERANCE = 0.02  #: ... and differs from the clock's beyond this share (said once)
RECENT = 64  #: a topic's latest messages a joining topic is placed against
#: a topic whose publisher's latest timestamp lies this far behind another's no longer holds the others
#: back (:class:`ClockMerge`: a publisher that stopped, not one whose messages are still on their way)
SILENT_S = 5.0


@dataclass
class _Topic:
    slot: int  #: the grid slot of the topic's last message
    sequence: int | None  #: its publisher's sequence number
    reference_ns: int  #: its reference time (publisher's timestamp, else arrival)
    intervals: list[float]  #: the first publisher intervals per number (rate check)
    #: joined beside the topic timed first: how far its first messages' timestamps lie from their partners'
    offsets: list[int] | None = None
    #: its latest messages' (reference time, slot)
    recent: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=RECENT))


class SequenceClock:
    """Times on one grid of ``period_s`` from the publishers' sequence numbers (module docstring)."""

    def __init__(self, period_s: float) -> None:
        if not period_s > 0:
            raise ValueError(f"the sequence clock needs a period > 0, got {period_s!r}")
        self.period_ns = int(round(period_s * 1e9))
        self._pause_ns = int(PAUSE_S * 1e9)
        self._anchor_ns: int | None = None
        self._topics: dict[str, _Topic] = {}
        #: what the publishers' timestamps say against the clock's rate (None: nothing to say)
        self.rate_problem: str | None = None
        self.pauses = 0  #: pauses and restarts the clock moved on at
        self.gap = 0  #: messages the last one's number says were lost just before it
        #: a topic joined by its number whose timestamps say it is out of step (None: nothing to say)
        self.step_problem: str | None = None

    def _slot_near(self, reference_ns: int) -> int:
        """The grid slot nearest ``reference_ns``, counted from the latest message whose reference time
        is nearest it (of any topic: a recording played faster publishes many per period of the grid)."""
        ref, slot = min((m for t in self._topics.values() for m in t.recent), key=lambda m: abs(m[0] - reference_ns))
        return slot + int(np.floor((reference_ns - ref) / self.period_ns + 0.5))

    def _join_slot(self, sequence: int | None, reference_ns: int) -> tuple[int, bool]:
        """A joining topic's first slot, and whether its number gave it: beside the topic timed first,
        whose message of that slot was published less than :data:`PAUSE_S` from it; else by its
        reference time."""
        first = next(iter(self._topics.values()))
        if sequence is not None and first.sequence is not None:
            slot = first.slot - first.sequence + sequence
            partner_ns = self._partner_ns(first, slot)
            if partner_ns is not None and abs(reference_ns - partner_ns) < self._pause_ns:
                return slot, True
        return self._slot_near(reference_ns), False

    @staticmethod
    def _partner_ns(topic: _Topic, slot: int) -> int | None:
        """The reference time of ``topic``'s recent message of ``slot`` (None: none kept)."""
        return next((ref for ref, s in topic.recent if s == slot), None)

    def _check_step(self, name: str, state: _Topic, slot: int, reference_ns: int) -> None:
        """A topic joined by its number: its first messages' timestamps against their partners'."""
        first_name, first = next(iter(self._topics.items()))
        partner_ns = self._partner_ns(first, slot)
        if partner_ns is None:
            return
        state.offsets.append(reference_ns - partner_ns)
        if len(state.offsets) == RATE_LEARN:
            typical_ns = float(np.median(state.offsets))
            if self.step_problem is None and abs(typical_ns) > 0.5 * self.period_ns:
                self.step_problem = (f"{name}'s publisher numbers its messages out of step with {first_name}'s: "
                                     f"its messages come {typical_ns * 1e-6:+.3g} ms from those they are paired "
                                     "with (the sequence clock needs publishers that number alike, as one loop's do)")

    def time_ns(self, topic: str, sequence: int | None, reference_ns: int) -> int:
        """The time of ``topic``'s message numbered ``sequence`` by its publisher (None: unknown; the
        reference time decides), whose publisher timestamp (else arrival) is ``reference_ns``."""
        if self._anchor_ns is None:
            self._anchor_ns = reference_ns
        self.gap = 0
        state = self._topics.get(topic)
        if state is None:
            slot, by_number = self._join_slot(sequence, reference_ns) if self._topics else (0, False)
            self._topics[topic] = state = _Topic(slot, sequence, reference_ns, [], [] if by_number else None)
            state.recent.append((reference_ns, slot))
            if by_number:
                self._check_step(topic, state, slot, reference_ns)
            return self._anchor_ns + slot * self.period_ns
        steps = sequence - state.sequence if sequence is not None and state.sequence is not None else 0
        self.gap = max(steps - 1, 0)
        elapsed = reference_ns - state.reference_ns
        if steps <= 0 or elapsed - steps * self.period_ns > self._pause_ns:
            # a restarted publisher, a pause (or no numbers at all): the slot of its reference time
            slot = max(state.slot + 1, self._slot_near(reference_ns))
            self.pauses += sequence is not None
        else:
            slot = state.slot + steps
            if len(state.intervals) < RATE_LEARN and elapsed > 0:
                state.intervals.append(elapsed / steps)
                if len(state.intervals) == RATE_LEARN:
                    self._check_rate(topic, state.intervals)
            if state.offsets is not None and len(state.offsets) < RATE_LEARN:
                self._check_step(topic, state, slot, reference_ns)
        state.slot, state.sequence, state.reference_ns = slot, sequence, reference_ns
        state.recent.append((reference_ns, slot))
        return self._anchor_ns + slot * self.period_ns

    def latest_ns(self) -> int | None:
        """The latest time given (None: none yet): where a reading off the grid (the oil temperature,
        at its own rate) is put, so that it holds from the samples taken with it on."""
        if not self._topics:
            return None
        return self._anchor_ns + max(t.slot for t in self._topics.values()) * self.period_ns

    def _check_rate(self, topic: str, intervals: list[float]) -> None:
        published_ns = float(np.median(intervals))
        if self.rate_problem is None and abs(published_ns / self.period_ns - 1.0) > RATE_TOLERANCE:
            self.rate_problem = (f"{topic} is published at {1e9 / published_ns:.4g} Hz, the sample clock runs at "
                                 f"{1e9 / self.period_ns:.4g} Hz (node.expected_rate_hz): its times are the "
                                 "publishers' numbers at the clock's rate")


class ClockMerge:
    """The messages of several topics, timed by the sequence clock, given out in time order.

    Delivery takes one topic's backlog faster than another's (a stalled node catching up): a topic's
    messages can come seconds of the grid ahead of the others'.  Paired by their times, as replay pairs
    a recording in log-time order, they must be handed on in time order: a message is held until every
    topic has one at or after its time -- except a topic whose publisher's latest timestamp lies more
    than :data:`SILENT_S` behind the newest (it stopped publishing; it holds nothing back).  Equal times
    keep their arrival order."""

    def __init__(self, silent_s: float = SILENT_S) -> None:
        self._silent_ns = int(silent_s * 1e9)
        self._held: list[tuple[int, int, Any]] = []  # a heap of (time, arrival number, item)
        self._arrivals = 0
        self._latest_ns: dict[Hashable, int] = {}  #: topic -> its latest time on the grid
        self._reference_ns: dict[Hashable, int] = {}  #: topic -> its publisher's latest timestamp

    def push(self, topic: Hashable, t_ns: int, reference_ns: int, item: Any) -> list[Any]:
        """Hold ``item`` (``topic``'s message at ``t_ns`` on the grid, its publisher's timestamp
        ``reference_ns``); returns the items no topic can still come before, in time order."""
        heapq.heappush(self._held, (t_ns, self._arrivals, item))
        self._arrivals += 1
        self._latest_ns[topic] = t_ns  # a topic's times on the grid only grow
        self._reference_ns[topic] = max(reference_ns, self._reference_ns.get(topic, reference_ns))
        newest = max(self._reference_ns.values())
        upto = min(t for c, t in self._latest_ns.items() if newest - self._reference_ns[c] <= self._silent_ns)
        out = []
        while self._held and self._held[0][0] <= upto:
            out.append(heapq.heappop(self._held)[2])
        return out

    def drain(self) -> list[Any]:
        """Everything still held, in time order (the stream ends)."""
        out = [entry[2] for entry in sorted(self._held)]
        self._held = []
        return out

    def __len__(self) -> int:
        return len(self._held)

