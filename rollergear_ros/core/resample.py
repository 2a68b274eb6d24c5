"""Channels at another rate than the drive torque, onto its stamps (:class:`RateResampler`).

A rig whose drives and DAQ log on their own clocks records the motor torque at 1 kHz beside a
speed at 100 Hz and an output torque at 200 Hz.  Paired message by message, nine torque messages in
ten would find no partner.  Instead, a channel whose rate differs from the motor torque's is not
paired: each motor torque message takes the channel's value at its own stamp,

- linear between the channel's messages just before and just after (both within ``max_age``),
- or the last one before it, held (within ``max_age``; the channel stopped or is late),
- or none: a motor sample without its speed is skipped (``stale``), one without its output is
  estimated without a residual (the output reads NaN).

Which channels are resampled is told from the stream itself, live and offline alike: from a
channel's first message on, the motor torque's next :data:`DECIDE_TORQUE_MESSAGES` messages are
counted against the channel's own in the same span; at most :data:`SLOWER_AT_MOST` or at least
:data:`FASTER_AT_LEAST` of them is another rate, and a channel at the torque's rate whose stamps
lie further than the pairing tolerance from the torque's, nearly all of them (a DAQ on its own clock,
half a period apart), is resampled too; one in step is paired as before.  While a channel is being
told, the messages wait here (a few dozen sample periods).  The values are a pure function of the messages' stamps (the
publishers' timestamps where given), not of their arrival order, so the node and a replay of its
recording give the same samples; the resampled values are pushed into the pairing with the torque
message's own times, so they pair with it exactly.  No rclpy import.
"""

from __future__ import annotations

from bisect import bisect_left
from collections import deque
from typing import NamedTuple

import numpy as np

from .pairing import CHANNELS, OIL_TEMPERATURE, OUT_SPEED, OUT_TORQUE, SPEED, TORQUE
from .lostmarks import is_lost, is_placeholder, placeholder, placeholder_mask

RESAMPLED_CHANNELS = (SPEED, OUT_TORQUE, OUT_SPEED)
DECIDE_TORQUE_MESSAGES = 32  #: motor torque messages a channel's rate and step are told against
SLOWER_AT_MOST = 20  #: ... a channel with at most this many messages in their span is slower
FASTER_AT_LEAST = 48  #: ... with at least this many, faster
#: messages held while a channel's rate is told: beyond this (a motor torque that never comes) the
#: channels still being told are paired
MAX_WAITING_MESSAGES = 10_000

#: the speed of a motor sample whose resampled speed had no value within the age limit: a quiet NaN
#: whose payload reads "STAL"; the estimator skips the sample as ``stale``
STALE_BITS = 0x7FF8_0000_5354_414C
STALE_VALUE: float = placeholder(STALE_BITS)


def is_stale(value: float) -> bool:
    """Whether ``value`` is :data:`STALE_VALUE`, bit for bit."""
    return is_placeholder(value, STALE_BITS)


def stale_mask(values: np.ndarray) -> np.ndarray:
    """:func:`is_stale` of each element of a float64 array."""
    return placeholder_mask(values, STALE_BITS)


class Message(NamedTuple):
    """One input message as the pairing takes it (``source_ns``: the publisher's timestamp or None)."""

    channel: str
    t_ns: int
    value: float
    source_ns: int | None


def value_at(history: deque, stamp: int, max_age_ns: int) -> tuple[float, str]:
    """A resampled channel's value at ``stamp`` from its messages ``history`` (``(stamp, value)`` in
    time order) and how it was made: ``exact``, ``interpolated``, ``held`` or ``none`` (NaN).

    ``v = v0 + (v1 - v0)·(t - t0)/(t1 - t0)`` between the messages just before and just after, both
    within ``max_age_ns``; else the one before, within ``max_age_ns``."""
    k = bisect_left(history, (stamp,))
    after = history[k] if k < len(history) else None
    if after is not None and after[0] == stamp:
        return after[1], "exact"
    before = history[k - 1] if k > 0 else None
    if before is None or stamp - before[0] > max_age_ns:
        return float("nan"), "none"
    if after is not None and after[0] - stamp <= max_age_ns:
        t0, v0 = before
        t1, v1 = after
        return v0 + (v1 - v0) * ((stamp - t0) / (t1 - t0)), "interpolated"
    return before[1], "held"


class RateResampler:
    """Channels at another rate than the motor torque, resampled onto its stamps (module docstring)."""

    def __init__(self, max_age_s: float, tolerance_ns: int) -> None:
        """``max_age_s``: how far a value may lie from a motor stamp (0: nothing is resampled);
        ``tolerance_ns``: the pairing tolerance (a channel at the torque's rate whose stamps nearly all lie
        further from the torque's is resampled too)."""
        self.max_age_ns = int(round(max_age_s * 1e9))
        self.tolerance_ns = tolerance_ns
        self._recent_torque: deque[int] = deque(maxlen=4 * DECIDE_TORQUE_MESSAGES)  # stamps, while telling
        #: each resampled-or-not channel: None (no message yet), "deciding", "paired" or "resampled"
        self.mode: dict[str, str | None] = dict.fromkeys(RESAMPLED_CHANNELS, None if self.max_age_ns > 0 else "paired")
        self.messages: dict[str, int] = dict.fromkeys((TORQUE, *RESAMPLED_CHANNELS), 0)  #: received
        #: samples per channel and kind (exact / interpolated / held / none) of the resampled channels
        self.made: dict[str, dict[str, int]] = {}
        self._deciding: dict[str, list] = {}  # channel -> [its stamps, motor torque messages counted]
        self._waiting: list[Message] = []  # all messages while a channel's rate is being told
        self._history: dict[str, deque] = {}  # resampled channel -> recent (stamp, value)
        self._pending: deque[Message] = deque()  # motor torque messages waiting for their values
        self._latest_torque = -(2 ** 62)
        self._newest = -(2 ** 62)  # the oldest of the resampled channels' newest stamps

    @property
    def passthrough(self) -> bool:
        """Whether messages go on as they are (nothing resampled, nothing being told, nothing held)."""
        return not (self._deciding or self._history or self._waiting or self._pending)

    def direct(self, channel: str) -> bool:
        """Whether a message of ``channel`` goes to the pairing as it is, now (what :meth:`push` would
        return at once: a channel paired as before, the temperature, the motor torque where nothing
        is resampled), so that the node's hot path need not come through here."""
        if self._deciding or self._waiting:
            return False
        mode = self.mode.get(channel, "")
        if mode == "paired" or channel == OIL_TEMPERATURE:
            return True
        return channel == TORQUE and not self._history and not self._pending

    @property
    def resampled(self) -> tuple[str, ...]:
        """The channels resampled onto the motor torque's stamps."""
        return tuple(c for c in RESAMPLED_CHANNELS if self.mode[c] == "resampled")

    def needs(self, codes: np.ndarray) -> bool:
        """Whether a batch of messages (``codes`` index :data:`~.pairing.CHANNELS`) must come through
        here: something is resampled or being told, or the batch brings a channel's first message."""
        if self.max_age_ns <= 0:
            return False
        if not self.passthrough:
            return True
        return any(self.mode[c] is None and bool(np.any(codes == CHANNELS.index(c))) for c in RESAMPLED_CHANNELS)

    def push(self, message: Message) -> list[Message]:
        """One input message; returns the messages for the pairing it completes (in order)."""
        channel = message.channel
        if self.max_age_ns <= 0 or channel == OIL_TEMPERATURE:
            return [message]
        if channel in self.mode:
            self.messages[channel] += 1
            if self.mode[channel] is None:
                self.mode[channel] = "deciding"
                self._deciding[channel] = [[], 0]
        elif channel == TORQUE:
            self.messages[TORQUE] += 1
        if not self._deciding:
            return self._route(message)
        self._waiting.append(message)
        self._tell(message)
        if not self._deciding:  # told: what waited goes on
            return self._route_waiting()
        if len(self._waiting) < MAX_WAITING_MESSAGES:
            return []
        for channel in list(self._deciding):  # a motor torque that does not come: paired as they are
            self._decide(channel, "paired")
        return self._route_waiting()

    def flush(self) -> list[Message]:
        """At the end of a stream: tell what is still being told by what came, and give every waiting
        motor torque message its values."""
        for channel, (stamps, n_torque) in list(self._deciding.items()):
            self._decide(channel, "resampled" if n_torque and self._other_rate(len(stamps), n_torque) else "paired")
        out = self._route_waiting()
        self._latest_torque = 2 ** 62
        out.extend(self._release())
        return out

    def _route_waiting(self) -> list[Message]:
        """The messages that waited while channels were told, in their order."""
        waiting, self._waiting = self._waiting, []
        out: list[Message] = []
        for m in waiting:
            out.extend(self._route(m))
        return out

    # ------------------------------------------------------------------ telling a channel's rate
    @staticmethod
    def _stamp(message: Message) -> int:
        return message.t_ns if message.source_ns is None else message.source_ns

    @staticmethod
    def _other_rate(n_channel: int, n_torque: int) -> bool:
        """Whether ``n_channel`` messages in the span of ``n_torque`` motor torque messages is another rate."""
        scale = n_torque / DECIDE_TORQUE_MESSAGES
        return n_channel <= SLOWER_AT_MOST * scale or n_channel >= FASTER_AT_LEAST * scale

    def _tell(self, message: Message) -> None:
        stamp = self._stamp(message)
        if message.channel in self._deciding:
            self._deciding[message.channel][0].append(stamp)
            return
        if message.channel != TORQUE:
            return
        self._recent_torque.append(stamp)
        for channel, state in list(self._deciding.items()):
            stamps, _ = state
            if stamps and stamp >= stamps[0]:
                state[1] += 1
                if state[1] == DECIDE_TORQUE_MESSAGES:
                    mine = [s for s in stamps if s <= stamp]
                    self._decide(channel, "resampled" if self._other_rate(len(mine), DECIDE_TORQUE_MESSAGES)
                                 or not self._in_step(mine) else "paired")

    def _in_step(self, stamps: list[int]) -> bool:
        """Whether a channel's ``stamps`` are in step with the motor torque's: at least an eighth of those
        after the first motor torque stamp seen lie within the pairing tolerance of one.

        Out of step is a channel on a clock of its own (a DAQ half a period apart: none of its stamps
        near one); a publisher preempted between the messages of some samples on a busy machine stamps
        those late, never nearly all.  A stamp before the first motor torque seen has no neighbour on
        one side (that torque message may have gone by before the channel's first) and is not judged."""
        torque = sorted(self._recent_torque)
        judged = [s for s in stamps if torque and s >= torque[0]]
        near = 0
        for s in judged:
            k = bisect_left(torque, s)
            if any(0 <= j < len(torque) and abs(torque[j] - s) <= self.tolerance_ns for j in (k - 1, k)):
                near += 1
        return 8 * near >= len(judged)

    def _decide(self, channel: str, mode: str) -> None:
        del self._deciding[channel]
        self.mode[channel] = mode
        if mode == "resampled":
            self._history[channel] = deque()
            self._newest = -(2 ** 62)
            self.made[channel] = dict.fromkeys(("exact", "interpolated", "held", "none"), 0)

    # ------------------------------------------------------------------ resampling
    def _route(self, message: Message) -> list[Message]:
        channel = message.channel
        if not self._history:
            return [message]
        if channel == TORQUE:
            stamp = message.t_ns if message.source_ns is None else message.source_ns
            pending = self._pending
            pending.append(message)
            if stamp > self._latest_torque:
                self._latest_torque = stamp
            head = pending[0]
            head_stamp = head.t_ns if head.source_ns is None else head.source_ns
            if head_stamp > self._newest and head_stamp + self.max_age_ns >= self._latest_torque:
                return []  # (the usual case: it waits for the slower channel's next message)
            return self._release()
        if channel in self._history:
            if not is_lost(message.value):  # a lost message's neighbours give its stamp's value
                history = self._history[channel]
                stamp = message.t_ns if message.source_ns is None else message.source_ns
                if history and stamp <= history[-1][0]:  # out of time order or repeated: the first is kept
                    return []
                history.append((stamp, message.value))
                self._newest = min(h[-1][0] if h else -(2 ** 62) for h in self._history.values())
            return self._release()
        return [message]

    def _release(self) -> list[Message]:
        """The waiting motor torque messages whose values are known, each followed by its channels'."""
        out: list[Message] = []
        pending, max_age, histories, made = self._pending, self.max_age_ns, self._history, self.made
        while pending:
            head = pending[0]
            stamp = head.t_ns if head.source_ns is None else head.source_ns
            if stamp > self._newest and stamp + max_age >= self._latest_torque:
                break  # a value just after it may still come
            pending.popleft()
            out.append(head)
            for channel, history in histories.items():
                value, kind = value_at(history, stamp, max_age)
                made[channel][kind] += 1
                if kind == "none" and channel == SPEED:
                    value = STALE_VALUE
                out.append(Message(channel, head.t_ns, value, head.source_ns))
        if out:
            self._trim()
        return out

    def _trim(self) -> None:
        """Forget the messages no waiting or later motor stamp can need (one before it is kept)."""
        floor = self._stamp(self._pending[0]) if self._pending else self._latest_torque
        for history in self._history.values():
            while len(history) > 1 and history[1][0] <= floor:
                history.popleft()

    # ------------------------------------------------------------------ reporting
    def describe(self) -> str | None:
        """One line on the resampled channels (None: none is)."""
        parts = []
        for channel in self.resampled:
            made = self.made[channel]
            total = sum(made.values())
            if not total:
                continue
            ratio = self.messages[channel] / max(self.messages[TORQUE], 1)
            held, none = made["held"], made["none"]
            parts.append(f"{channel} ({ratio:.3g}x the torque's rate): {100 * held / total:.2f} % of samples from a "
                         f"held value, {none:,} without one")
        if not parts:
            return None
        return (f"channels at another rate, interpolated onto the drive torque's stamps (values at most "
                f"{self.max_age_ns * 1e-9:g} s old): " + "; ".join(parts))
