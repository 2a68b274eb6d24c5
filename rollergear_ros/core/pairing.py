"""Pairing of header-less input messages into samples (:class:`SampleSynchronizer`).

The node pushes one message at a time, replay whole arrays (:meth:`SampleSynchronizer.push_many`,
vectorised where it can be, message by message where a rule needs it; the result is the same).
No rclpy import.

Pairing rule (inputs are header-less ``std_msgs/Float64``): every channel has a FIFO of ``(time,
value)``; *time* is the bag's log time offline and the publisher's source timestamp live (the receive
time when the middleware gives none).  Motor torque and motor speed are required; output torque and
output speed join the pairing once they have delivered a message.  Whenever every active channel has a
message queued, the heads form one sample if their times lie within ``sync_tolerance_s`` of each other;
otherwise the oldest head has no partner and is dropped (counted as ``unpaired`` for a motor channel) --
except, by stamps, a drive sample whose torque and speed pair: it is estimated with the output heads
within the tolerance and without those beyond it (a late or jittering output never costs the loss
estimate; no residual, ``output_missing``).  The tolerance must stay below half the sample period, so
sample k never pairs with k±1; ``sync_tolerance_s: 0`` (the default) takes 0.4 × the motor torque's
median message period (:func:`pairing_tolerance_s`), which also pairs topics that separate publishers or
recorders logged a fraction of a period apart.  An optional channel silent for longer than
``staleness_s`` no longer holds up the motor samples (they are estimated without a residual and counted
as ``output_missing``); a motor message whose partner has not come within ``staleness_s`` is dropped as
``unpaired`` (over a lossless arrival delivery both wait :data:`LOSSLESS_HOLD_S`: a late partner there
was held up, not lost).  During the first ``staleness_s`` of a stream, samples wait for the optional
channels to show up, so a log's first samples already carry their measured output.

Arrival pairing (``arrival=True``, for a live executor that gives no publisher timestamps, so
*time* is the callback time): messages are paired first-in first-out per channel even when their
callback times are further apart than the tolerance (the middleware may deliver topics slightly
out of order, and callback times spread under load); only when three consecutive pairs are more
than ``max(sync_tolerance_s, 2 ms)`` apart is the stream taken to be misaligned by a lost message,
and the oldest head is dropped (``unpaired``) to re-synchronise.  That leniency applies once the
stream is locked on (a pair within the tolerance).  Unlocked -- at the start, after a resync, and
after a gap longer than ``staleness_s`` with nothing queued (over a lossless delivery only when the
messages after it come at the sample rate, not in a stalled executor's catch-up burst:
:meth:`SampleSynchronizer._decide_gap`) -- a wide pair is dropped at once, so the
backlog of a topic whose subscription matched before its partner's (a node started while a bag
plays) is not paired with the wrong samples.  Below ~500 Hz a lost message mispairs two samples
before the resync.  Above it, neighbouring samples lie within 2 ms of each other, so a pairing one
sample off (a lost message; the start-up backlog of a node that joined a running stream, taken in
one burst while its subscriptions had matched a few samples apart) is found by its votes instead:
a pair in which a channel's offset from the motor torque is beyond 0.75 periods votes for a pairing
one sample off; when nearly all of the last 16 pairs do, the lagging heads are dropped
(:meth:`SampleSynchronizer._arrival_skewed`), while a publisher preempted between the messages of
some samples does not outvote the rest.
The offsets are those of the publishers' timestamps where the middleware gives them (``source_ns``;
the live node records them as its inputs' MCAP publish times, so replay sees them too): the order
of arrival pairs, the publisher's clock tells a skew, and neither depends on how much CPU the node
gets.  A skew is undone within ~30 samples of live data; a burst sent by a publisher catching up
carries no timing and keeps the pairing it was taken with.  Over best-effort delivery with the
publishers' sequence numbers (``arrival_sequenced``, the live node's default) every lost message
is pushed as a placeholder
(:data:`LOST_VALUE`) in its place: nothing is then missing, the lossless rules apply, and a pair
with a placeholder is taken first in, first out whatever its times.  By arrival, an optional channel
counts as silent once motor messages have kept coming for ``staleness_s`` without it, not when the
callback clock jumps: on a busy machine the node's own executor may stall inside a sample (all
its inputs then wait in the middleware's queues and arrive in a burst).  The node reports
``unpaired`` and ``lost`` counts in ``/diagnostics``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..base.interface import Channel
from .lostmarks import is_lost
from .oil import plausible_oil_temperature

# channel names (defined in .interface) bound as module globals once: the hot paths index by them
TORQUE, SPEED, OUT_TORQUE, OUT_SPEED, OIL_TEMPERATURE = Channel.ALL
CHANNELS: tuple[str, ...] = Channel.ALL
_REQUIRED = (TORQUE, SPEED)
_OPTIONAL = (OUT_TORQUE, OUT_SPEED)
_PAIRED = (TORQUE, SPEED, OUT_TORQUE, OUT_SPEED)  #: the channels that pair, in sample order

#: the arrival pairings: over best-effort delivery; over a reliable, keep-all one (nothing lost); and
#: over best-effort delivery whose losses are filled in from the publishers' sequence numbers
#: (:data:`LOST_VALUE` placeholders: nothing missing either)
ARRIVAL_PAIRINGS = ("arrival", "arrival_reliable", "arrival_sequenced")
LOSSLESS_PAIRINGS = ("arrival_reliable", "arrival_sequenced")
TEMPERATURE_HOLD_S = 5.0
#: arrival pairing over a lossless delivery: how long a motor message waits for its partner.  Nothing
#: is lost, so a partner that is late was delayed (one topic's delivery held up under load), not dropped
LOSSLESS_HOLD_S = 5.0
ARRIVAL_TOLERANCE_S = 0.002
AUTO_TOLERANCE_FRACTION = 0.4  #: automatic pairing tolerance as a fraction of the sample period
FALLBACK_PERIOD_S = 0.001  #: assumed sample period when it is unknown (1 kHz)
#: arrival pairing, skew detector: gain of the running mean of the sample period; offset from the
#: motor torque (fraction of the period) beyond which a pair votes for a pairing that many samples
#: off; the pairs whose votes count, and how many of them must agree (a publisher preempted between
#: the messages of some samples votes in those pairs only); shortest mean period it acts on (a burst
#: of queued messages, or a rate above 10 kHz, carries no timing information)
SKEW_GAIN = 1.0 / 16.0
SKEW_LIMIT = 0.75
SKEW_WINDOW = 16
SKEW_VOTES = 14
SKEW_MIN_PERIOD_NS = 100_000
#: over a lossless delivery, a pair whose messages arrived further apart than this many periods was held up
#: in delivery (one topic stalled), which says nothing about a skew
SKEW_MAX_OFFSET_PERIODS = 20
SKEW_HELD_UP_NS = 10_000_000  #: ... and never less than this (the arrival period may be a catch-up's)
#: over a lossless delivery a skew can only come from a start that is out of step (subscriptions
#: matched apart): the detector acts during the first this-many timed pairs of a stream only, so
#: that delivery jitter on a busy machine never costs a sample later on
LOSSLESS_SKEW_WINDOW = 500
#: over a lossless delivery, how many messages of one channel after a gap tell an executor stall (they
#: come in a burst) from a new stream (at its sample rate): :meth:`SampleSynchronizer._decide_gap`
STALL_BURST_MESSAGES = 4

#: reasons a sample is not estimated (or estimated without a residual); ``malformed`` and
#: ``duplicate`` count input messages that were never paired (not a Float64, a repeat)
SKIP_REASONS: tuple[str, ...] = ("unpaired", "non_finite", "implausible", "output_missing",
                                 "output_non_finite", "temperature_missing", "malformed", "duplicate", "lost",
                                 "stale", "out_of_order", "load_unbalanced")


def pairing_tolerance_s(sync_tolerance_s: float, sample_period_s: float | None) -> float:
    """The pairing tolerance: the configured one, or (configured 0) 0.4 x the sample period.

    Channels logged by separate publishers or recorders carry times that differ by a fraction of
    a period; 0.4 x the period accepts that and still never pairs sample k with k+-1.
    """
    if sync_tolerance_s > 0:
        return sync_tolerance_s
    period = sample_period_s if sample_period_s and sample_period_s > 0 else FALLBACK_PERIOD_S
    return AUTO_TOLERANCE_FRACTION * period


class SyncedSample(NamedTuple):
    """One paired input sample (NaN marks an optional value that is absent)."""

    t_ns: int
    torque_nm: float
    speed_rad_s: float
    out_torque_nm: float
    out_speed_rad_s: float
    temperature_c: float


class SampleSynchronizer:
    """Pairs header-less input channels by time (see the module docstring for the rule)."""

    def __init__(self, sync_tolerance_s: float, staleness_s: float,
                 temperature_hold_s: float = TEMPERATURE_HOLD_S, arrival: bool = False, lossless: bool = False,
                 sample_period_s: float | None = None) -> None:
        """``sample_period_s``: the stream's nominal sample period, when known (arrival pairing: the
        skew detector never takes less than half of it for the period, see :meth:`_arrival_skewed`)."""
        self.arrival = arrival
        self._period_floor_ns = 0.5 * sample_period_s * 1e9 if sample_period_s and sample_period_s > 0 else 0.0
        self.lossless = lossless  # arrival pairing over a delivery that loses nothing: no resync on wide pairs
        self._wide = 0  # consecutive pairs wider than the tolerance (arrival pairing)
        self._locked = False  # arrival pairing: the heads have paired within the tolerance
        # arrival pairing, skew detector: channels observed, their votes in the last pairs, timed pairs
        # since the stream (re)started, each channel's time in the previous pair, mean sample period (ns)
        self._skew_chans: tuple[str, ...] = ()
        self._skew_votes: deque[list[int]] = deque()  # the last SKEW_WINDOW pairs' votes, per channel
        self._timed_pairs = 0  # pairs observed with timing since the stream (re)started
        self._skew_last: list[int] = []  # each observed channel's time in the previous pair
        self._period_ns = 0.0
        self._last_pair_ns: int | None = None
        self._gap_ns: int | None = None  # lossless arrival pairing: a gap to be told stall or new stream
        self._gap_msgs: dict[str, int] = {}  # ... and each channel's messages since it
        self.tolerance_ns = int(round(sync_tolerance_s * 1e9))
        self.staleness_ns = int(round(staleness_s * 1e9))
        self._set_hold()
        self.temperature_hold_ns = int(round(temperature_hold_s * 1e9))
        self.queues: dict[str, deque] = {c: deque() for c in _REQUIRED + _OPTIONAL}
        self.active: dict[str, bool] = {TORQUE: True, SPEED: True, OUT_TORQUE: False, OUT_SPEED: False}
        self._active_channels: tuple[str, ...] = _REQUIRED  #: the channels in ``active``, cached
        self.latest_ns = -(2 ** 62)
        self.first_ns: int | None = None
        self.temperature: tuple[int, float] | None = None
        self.counts: dict[str, int] = {r: 0 for r in SKIP_REASONS}
        self.received: dict[str, int] = {c: 0 for c in CHANNELS}
        self.unpaired: dict[str, int] = {c: 0 for c in _REQUIRED}  #: motor messages without a partner, by channel

    def set_limits(self, sync_tolerance_s: float, staleness_s: float) -> None:
        """Change the pairing tolerance and the staleness limit; queued messages are kept."""
        self.tolerance_ns = int(round(sync_tolerance_s * 1e9))
        self.staleness_ns = int(round(staleness_s * 1e9))
        self._set_hold()

    def _set_hold(self) -> None:
        """How long a motor message waits for its partner: ``staleness_s``, or over a lossless
        arrival delivery at least :data:`LOSSLESS_HOLD_S`."""
        hold = max(self.staleness_ns, int(LOSSLESS_HOLD_S * 1e9)) if self.arrival and self.lossless else 0
        self.hold_ns = max(self.staleness_ns, hold)

    def _decide_gap(self, channel: str, t_ns: int) -> None:
        """Over a lossless arrival delivery, after a gap with nothing queued: is it a new stream or a stall.

        The executor of a node that stalled takes what the middleware queued meanwhile in one burst,
        far faster than the publisher sent it; a new stream arrives at its sample rate.  When one
        channel has delivered :data:`STALL_BURST_MESSAGES` messages since the gap, they decide: in
        less than half their nominal span (``(n - 1)`` sample periods), the gap was a stall and the
        stream and its pairing go on (a catch-up is no start out of step); otherwise it is a new stream.
        """
        n = self._gap_msgs[channel] = self._gap_msgs.get(channel, 0) + 1
        if n < STALL_BURST_MESSAGES:
            return
        period = 2.0 * self._period_floor_ns or self._period_ns or FALLBACK_PERIOD_S * 1e9
        if t_ns - self._gap_ns >= 0.5 * period * (n - 1):
            self._locked, self._timed_pairs = False, 0
        self._gap_ns = None

    def restart(self) -> None:
        """Begin a new stream: what is queued is dropped (motor messages as ``unpaired``) and the
        pairing starts unlocked, as after a clean end (a gap too long to fill with placeholders)."""
        for ch, qq in self.queues.items():
            if ch in _REQUIRED:
                self._unpaired(ch, len(qq))
            qq.clear()
        self._locked, self._timed_pairs, self._wide = False, 0, 0
        self._skew_chans, self._skew_last, self._gap_ns = (), [], None

    def _set_active(self, channel: str, active: bool) -> None:
        self.active[channel] = active
        self._active_channels = tuple(c for c in _PAIRED if self.active[c])

    def push(self, channel: str, t_ns: int, value: float, source_ns: int | None = None) -> Sequence[SyncedSample]:
        """Add one message; returns the samples it completes (usually zero or one).

        ``source_ns``: by arrival, the publisher's timestamp of the message (its source timestamp;
        ``None``: ``t_ns``), which the skew detector measures offsets with (:meth:`_arrival_skewed`)."""
        self.received[channel] += 1
        if channel == OIL_TEMPERATURE:  # held, never paired: it does not move the pairing clock
            self.temperature = (t_ns, value)
            return ()
        if self.first_ns is None:
            self.first_ns = t_ns
        if self._gap_ns is not None:
            self._decide_gap(channel, t_ns)
        if t_ns > self.latest_ns:
            if t_ns - self.latest_ns > self.staleness_ns and not any(self.queues.values()):
                # a new stream after a clean end (nothing half-paired): its topics may start out of
                # step.  A gap inside a sample is an executor stall, not a new stream.  Over a
                # lossless delivery the messages after the gap decide (_decide_gap)
                if self.arrival and self.lossless:
                    self._gap_ns, self._gap_msgs = t_ns, {}
                else:
                    self._locked, self._timed_pairs = False, 0
            self.latest_ns = t_ns
        q = self.queues
        q[channel].append((t_ns, value, t_ns if source_ns is None else source_ns))
        active = self.active
        if not active[channel]:
            self._set_active(channel, True)
        # fast exit (the node's hot path): an active channel has nothing queued, so no sample can
        # complete, and no queued motor message is older than the staleness limit, so nothing
        # expires and no optional channel is given up on (what _drain would conclude, cheaper)
        qt, qs = q[TORQUE], q[SPEED]
        if not qt or not qs or (active[OUT_TORQUE] and not q[OUT_TORQUE]) or (
                active[OUT_SPEED] and not q[OUT_SPEED]):
            if qt and qs:
                head = min(qt[0][0], qs[0][0])
            elif qt or qs:
                head = (qt or qs)[0][0]
            else:
                return ()
            if self.latest_ns - head <= self.hold_ns:
                return ()
        return self._drain()

    def flush(self) -> list[SyncedSample]:
        """At the end of a log: emit what can still be paired, count the rest as unpaired."""
        self.latest_ns += 2 * max(self.tolerance_ns, self.hold_ns) + 1
        out = self._drain()
        for ch in _REQUIRED:
            self._unpaired(ch, len(self.queues[ch]))
            self.queues[ch].clear()
        for ch in _OPTIONAL:
            self.queues[ch].clear()
        return out

    def push_many(self, codes: np.ndarray, t_ns: np.ndarray, values: np.ndarray,
                  source_ns: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """:meth:`push` for a batch of messages in arrival (file) order; ``codes`` index :data:`CHANNELS`
        (``source_ns``: the publishers' timestamps, by arrival).

        Returns the completed samples as arrays ``(t_ns, torque, speed, out_torque, out_speed,
        temperature)``.  When nothing is queued and every channel's k-th message lies within the
        tolerance of the others' k-th, the pairing is done with numpy; otherwise message by message.
        The result is the same either way (tested).
        """
        fast = None if self.arrival else self._pair_vectorised(codes, t_ns, values)
        if fast is not None:
            return fast
        out: list[SyncedSample] = []
        push = self.push
        sources = source_ns.tolist() if source_ns is not None else [None] * len(codes)
        for c, t, v, s in zip(codes.tolist(), t_ns.tolist(), values.tolist(), sources):
            out.extend(push(CHANNELS[c], t, v, s))
        return samples_to_arrays(out)

    def _pair_vectorised(self, codes: np.ndarray, t_ns: np.ndarray, values: np.ndarray):
        """The batch paired first-in first-out in one go, when that is exactly what pushing its
        messages one by one would give (every channel present, in step within the tolerance, in
        time order, the leftovers after every paired message); None when the streaming rule must decide."""
        present = self._vector_channels(codes)
        if present is None:
            return None
        held_queues = any(self.queues[c] for c in self.queues)
        if held_queues:
            # messages held from the previous batch (a sample cut by the batch boundary) go first
            held = [(t, CHANNELS.index(c), v) for c in self.queues for t, v, _ in self.queues[c]]
            held.sort(key=lambda h: h[0])
            codes = np.concatenate([np.array([h[1] for h in held], dtype=codes.dtype), codes])
            t_ns = np.concatenate([np.array([h[0] for h in held], dtype=np.int64), t_ns])
            values = np.concatenate([np.array([h[2] for h in held], dtype=float), values])
        idx = {c: np.flatnonzero(codes == k) for k, c in enumerate(CHANNELS)}
        n = min(len(idx[c]) for c in present)
        if n == 0 or any(len(idx[c]) - n > 1 for c in present):
            return None
        rows = {c: idx[c][:n] for c in present}
        times = np.stack([t_ns[rows[c]] for c in present])
        if np.any(times.max(axis=0) - times.min(axis=0) > self.tolerance_ns):
            return None
        # taken out of time order (one input's backlog before the others'): a message further than the
        # tolerance behind the latest one may be given up by the streaming rule -- let it decide
        arrived = t_ns[codes != CHANNELS.index(OIL_TEMPERATURE)]
        if np.any(np.maximum.accumulate(arrived) - arrived > self.tolerance_ns):
            return None
        # leftovers (a sample cut by the batch boundary) must come after every paired message
        left = np.sort(np.concatenate([idx[c][n:] for c in present] + [np.empty(0, dtype=np.int64)]))
        complete_at = np.stack([rows[c] for c in present]).max(axis=0)
        if len(left) and left[0] < complete_at.max():
            return None
        t = t_ns[rows[TORQUE]]
        cols = {c: values[rows[c]] if c in rows else np.full(n, np.nan) for c in (TORQUE, SPEED, OUT_TORQUE, OUT_SPEED)}
        temp = self._held_temperature(t, t_ns, values, idx[OIL_TEMPERATURE], complete_at)
        # bring the streaming state to where message-by-message pushing would leave it
        if held_queues:
            for c in self.queues:
                self.received[c] -= len(self.queues[c])
                self.queues[c].clear()
        non_temp = codes != CHANNELS.index(OIL_TEMPERATURE)
        if self.first_ns is None:
            self.first_ns = int(t_ns[np.flatnonzero(non_temp)[0]])
        self.latest_ns = max(self.latest_ns, int(t_ns[non_temp][:complete_at.max() + 1].max()))
        for c in present:
            self.received[c] += n
            if not self.active[c]:
                self._set_active(c, True)
        if OUT_TORQUE not in present and self.received[OUT_TORQUE]:
            self.counts["output_missing"] += n
        tpos = idx[OIL_TEMPERATURE]
        self.received[OIL_TEMPERATURE] += len(tpos)
        if len(tpos):
            self.temperature = (int(t_ns[tpos[-1]]), float(values[tpos[-1]]))
        for i in left.tolist():
            extra = self.push(CHANNELS[int(codes[i])], int(t_ns[i]), float(values[i]))
            assert not extra  # an incomplete set cannot complete on its own
        return (t, cols[TORQUE], cols[SPEED], cols[OUT_TORQUE], cols[OUT_SPEED], temp)

    def _vector_channels(self, codes: np.ndarray) -> list[str] | None:
        """The paired channels a batch (with what is queued) has, or None where the streaming rule
        decides: no motor torque or speed, an output channel falling silent, the start-up hold."""
        if len(codes) == 0:
            return None
        present = [c for c in (TORQUE, SPEED, OUT_TORQUE, OUT_SPEED)
                   if np.any(codes == CHANNELS.index(c)) or self.queues[c]]
        if TORQUE not in present or SPEED not in present:
            return None
        if any(self.active[c] and c not in present for c in _OPTIONAL):
            return None  # an output channel falls silent: the streaming rule decides
        outputs_known = (self.received[OUT_TORQUE] or OUT_TORQUE in present) and (
            self.received[OUT_SPEED] or OUT_SPEED in present)
        if not outputs_known and (self.first_ns is None or self.latest_ns - self.first_ns <= self.staleness_ns):
            return None  # start-up hold: the streaming rule decides
        return present

    def _held_temperature(self, t: np.ndarray, t_ns: np.ndarray, values: np.ndarray, tpos: np.ndarray,
                          complete_at: np.ndarray) -> np.ndarray:
        """Zero-order hold of the temperature: for each sample (time ``t``, completed at message
        ``complete_at``) the last one received before, within the hold time; NaN without one."""
        n = len(t)
        temp = np.full(n, np.nan)
        k = np.searchsorted(tpos, complete_at) - 1
        have = k >= 0
        temp_t = np.where(have, t_ns[tpos[np.maximum(k, 0)]] if len(tpos) else 0, 0)
        temp_v = np.where(have, values[tpos[np.maximum(k, 0)]] if len(tpos) else np.nan, np.nan)
        if self.temperature is not None:
            temp_t = np.where(have, temp_t, self.temperature[0])
            temp_v = np.where(have, temp_v, self.temperature[1])
            have = np.ones(n, bool)
        ok = have & (t - temp_t <= self.temperature_hold_ns)
        temp[ok] = temp_v[ok]
        return plausible_oil_temperature(temp)

    def _drain(self) -> list[SyncedSample]:
        out: list[SyncedSample] = []
        q = self.queues
        tol = self.tolerance_ns
        while True:
            if not (q[TORQUE] and q[SPEED]):
                self._expire_required()
                return out
            t_req = max(q[TORQUE][0][0], q[SPEED][0][0])
            if (self.latest_ns - self.first_ns <= self.staleness_ns
                    and not (self.received[OUT_TORQUE] and self.received[OUT_SPEED])):
                return out  # start-up: give the optional channels a chance to appear
            # optional channels that are active but silent: do not hold the motor samples up.  By
            # arrival, silence is measured by the motor messages that came since, not by the clock:
            # a stall of the node's own executor inside a sample is no silence of its inputs; and
            # over a lossless delivery an output is waited for as long as a motor partner (its
            # delivery may be held up, e.g. by a repair of the reliable protocol)
            chans = self._active_channels
            if len(chans) > 2 and (max(q[TORQUE][-1][0], q[SPEED][-1][0]) if self.arrival
                                   else self.latest_ns) - t_req > self.hold_ns:
                for ch in _OPTIONAL:
                    if self.active[ch] and not q[ch]:
                        self._set_active(ch, False)
                chans = self._active_channels
            if any(not q[c] for c in chans):
                return out
            times = [q[c][0][0] for c in chans]
            if self.arrival and any(is_lost(q[c][0][1]) for c in chans):
                # a lost message's placeholder pairs in its place: its time (that of the message
                # after it) says nothing about the pairing, so neither tolerance nor skew applies
                out.append(self._sample(times[0], {c: q[c].popleft()[1] for c in chans}))
                continue
            wide = max(times) - min(times) > tol
            if self.arrival:
                wide = self._arrival_wide(wide)
            if not wide:
                if self.arrival and self._arrival_skewed(chans, [q[c][0][2] for c in chans]):
                    continue
                vals = {c: q[c].popleft()[1] for c in chans}
                t = times[0]
                out.append(self._sample(t, vals))
                continue
            oldest = chans[times.index(min(times))]
            if not self.arrival and oldest in _REQUIRED and abs(times[0] - times[1]) <= tol:
                # a whole drive sample whose output heads lie beyond the tolerance after it (a late or
                # jittering output): estimated without them (no residual: ``output_missing``), never lost
                first = min(times[0], times[1])
                vals = {c: q[c].popleft()[1] for c, t in zip(chans, times) if t - first <= tol}
                out.append(self._sample(times[0], vals))
                continue
            q[oldest].popleft()
            if oldest in _REQUIRED:
                self._unpaired(oldest)

    def _arrival_wide(self, wide: bool) -> bool:
        """Arrival pairing: whether a pair whose times are ``wide`` apart is taken as misaligned.

        Locked on (after a pair within the tolerance), up to two consecutive wide pairs are
        delivery jitter; the third means a lost message: the oldest head is dropped and the stream
        is unlocked.  Unlocked (at the start of a stream, after a gap, after a resync), every wide
        pair is misaligned: a subscription that matched before its partner's delivers a backlog that
        has no partner, and it is dropped until the heads pair within the tolerance.  Over a
        lossless delivery (``lossless``: reliable, keep all, each topic in order) no message is
        missing, so a wide pair is never a loss: it is a stall of the executor inside a sample, and
        first-in first-out is the pairing (a misaligned start is still undone by the skew detector).
        """
        if not wide:
            self._locked, self._wide = True, 0
            return False
        if self.lossless:
            return False
        if not self._locked:
            return True
        self._wide += 1
        if self._wide < 3:
            return False
        self._locked, self._wide = False, 0
        return True

    def _arrival_skewed(self, chans: tuple[str, ...], times: list[int]) -> bool:
        """Arrival pairing: whether the heads pair each sample with a neighbour's message; if so,
        the lagging heads are dropped (``unpaired``) and True returned.

        ``times``: the heads' publisher timestamps (their source timestamps, which the node records
        as each input's MCAP publish time; the arrival times where there are none).  The
        publisher's clock says when a sample's messages were sent whatever CPU share the node has;
        arrival times spread by a node preempted while it takes a backlog look like a skew, and a
        head dropped for it pairs every later sample with its neighbour's.

        A skew of one sample keeps every pair within the 2 ms of jitter allowed above ~500 Hz (a
        node that joined a running stream, or a lost message), so it is told by votes: in each pair,
        each channel votes its offset from the motor torque in whole mean sample periods where it lies
        beyond ``SKEW_LIMIT`` of one, else 0, and the votes of the last ``SKEW_WINDOW`` pairs count.
        Messages of one sample are sent together (no votes); a pairing k samples off votes k in every
        pair; a publisher preempted between the messages of some samples -- a busy machine -- votes
        in those pairs only, and moderate offsets not at all.  A pair that
        came less than half the nominal sample period after the previous one (when it is known;
        else ``SKEW_MIN_PERIOD_NS``) was sent in a catch-up and is not observed.  When ``SKEW_VOTES``
        of a channel's votes agree on a side, its offset is the smallest of them, and the channels that
        lag the most advanced one drop that many heads at once (:meth:`_drop_heads`); channels published
        at independent phases settle at an offset within ±0.25 periods after
        one such drop.  A
        pair whose late messages came in a burst (each within ``SKEW_MIN_PERIOD_NS`` of its
        channel's previous one) while the earlier ones did not -- one topic's delivery held up and
        released while the others kept coming -- carries no timing and is not observed.  Over a
        lossless delivery (nothing is ever missing) it acts only during the first
        :data:`LOSSLESS_SKEW_WINDOW` timed pairs of a stream, where a start out of step is undone.
        """
        if self._held_up_burst(times):
            self._last_pair_ns = times[0]
            return False
        t0 = times[0]
        last, self._last_pair_ns = self._last_pair_ns, t0
        # a node catching up takes its queued samples faster than they were sent: such a burst carries
        # no timing (where one topic's queue is longer, one sample's messages are taken far apart)
        if last is not None and 0 <= t0 - last < max(self._period_floor_ns, SKEW_MIN_PERIOD_NS):
            return False
        period = self._period_ns
        if last is not None and 0 < t0 - last <= self.staleness_ns:
            period = self._period_ns = period + SKEW_GAIN * ((t0 - last) - period) if period else float(t0 - last)
        # an offset counts at most one period: a stall between two callbacks is not a skew; and over a
        # lossless delivery a pair whose messages arrived many periods apart was held up, not skewed
        if self.lossless and max(times) - min(times) > max(SKEW_MAX_OFFSET_PERIODS * period, SKEW_HELD_UP_NS):
            return False
        # a pair's vote per channel: its offset from the motor torque in whole periods where it lies
        # beyond SKEW_LIMIT of one, else 0 (and 0 while the period is unknown); the last SKEW_WINDOW pairs'
        untimed = period < SKEW_MIN_PERIOD_NS
        beyond = SKEW_LIMIT * period
        votes = [0 if untimed or abs(t - t0) <= beyond else round((t - t0) / period) for t in times]
        window = self._skew_votes
        if chans is not self._skew_chans:
            self._skew_chans = chans
            window.clear()
        if len(window) == SKEW_WINDOW:
            window.popleft()
        window.append(votes)
        if untimed:
            return False
        self._timed_pairs += 1
        if len(window) < SKEW_WINDOW or not any(votes) or (self.lossless and self._timed_pairs > LOSSLESS_SKEW_WINDOW):
            return False  # (a skew votes in this pair too: a pair without votes needs no count)
        offsets = [_consistent_offset([w[i] for w in window]) for i in range(len(times))]
        lead = max(offsets)
        if all(n == lead for n in offsets):
            return False
        self._drop_heads(chans, [lead - n for n in offsets])
        return True

    def _held_up_burst(self, times: list[int]) -> bool:
        """Whether this pair's late messages came in a burst (each within ``SKEW_MIN_PERIOD_NS`` of
        its channel's previous one) while the earlier ones did not: no timing in it."""
        prev, self._skew_last = self._skew_last, times
        if len(prev) != len(times):
            return False
        burst = [0 <= t - p < SKEW_MIN_PERIOD_NS for t, p in zip(times, prev)]
        return any(burst) and not all(burst) and (min(t for t, b in zip(times, burst) if b)
                                                  > max(t for t, b in zip(times, burst) if not b))

    def _drop_heads(self, chans: tuple[str, ...], lags: list[int]) -> None:
        """Drop ``lags[i]`` heads of channel ``chans[i]`` (``unpaired`` for the motor's): the channels
        that lag the most advanced one by that many samples; then observe the new pairing afresh."""
        for ch, lag in zip(chans, lags):
            q = self.queues[ch]
            for _ in range(min(lag, len(q))):
                q.popleft()
                if ch in _REQUIRED:
                    self._unpaired(ch)
        self._skew_chans, self._skew_last = (), []

    def _expire_required(self) -> None:
        """Drop motor messages whose partner has not come within the staleness limit (the
        longer hold of a lossless delivery)."""
        limit = self.latest_ns - self.hold_ns
        for ch in _REQUIRED:
            qq = self.queues[ch]
            while qq and qq[0][0] < limit:
                qq.popleft()
                self._unpaired(ch)

    def _unpaired(self, channel: str, n: int = 1) -> None:
        """``n`` messages of motor ``channel`` dropped without a partner: counted, in total and by channel."""
        self.counts["unpaired"] += n
        self.unpaired[channel] += n

    def _sample(self, t_ns: int, vals: dict[str, float]) -> SyncedSample:
        if OUT_TORQUE not in vals and self.received[OUT_TORQUE]:
            self.counts["output_missing"] += 1
        temp = math.nan
        if self.temperature is not None and t_ns - self.temperature[0] <= self.temperature_hold_ns:
            temp = plausible_oil_temperature(self.temperature[1])
        return SyncedSample(t_ns, vals[TORQUE], vals[SPEED], vals.get(OUT_TORQUE, math.nan),
                            vals.get(OUT_SPEED, math.nan), temp)


def _consistent_offset(votes: list[int]) -> int:
    """A channel's offset in whole samples when at least :data:`SKEW_VOTES` of its ``votes`` (one a
    pair) say it is off to the same side: the smallest of them; else 0."""
    ahead = [v for v in votes if v > 0]
    behind = [v for v in votes if v < 0]
    if len(ahead) >= SKEW_VOTES:
        return min(ahead)
    if len(behind) >= SKEW_VOTES:
        return max(behind)
    return 0


def samples_to_arrays(samples: list[SyncedSample]) -> tuple[np.ndarray, ...]:
    """``(t_ns, torque, speed, out_torque, out_speed, temperature)`` arrays of paired samples."""
    if not samples:
        z = np.empty(0)
        return np.empty(0, dtype=np.int64), z, z, z, z, z
    arr = np.array([s[1:] for s in samples], dtype=float)
    return (np.array([s[0] for s in samples], dtype=np.int64), arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3],
            arr[:, 4])
