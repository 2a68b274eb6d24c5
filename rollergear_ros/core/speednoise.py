"""The speed reading's noise: given in the parameter file, or learned from the first samples (``auto``).

The estimator runs the loss torque's sign smoothly through 0 over the speed reading's noise σ
(``tanh(ω/σ)``) and measures a loss only where the direction is known (``|ω| ≥ 3σ``).  With
``estimator.speed_noise_rad_s: auto`` (the default) σ is learned from the speeds of the samples
estimated, in their order, by :func:`reading_noise` at :data:`CHECKPOINTS` samples and then kept:
before the first checkpoint the sign is the plain sign and no loss is measured (the direction is
not known until the noise is).  The node and replay step through the same samples, so they learn
the same σ at the same sample, bit for bit.

A drive turning slower than 3σ (a worm at 1 rpm whose controller reads 0…10 rpm as it sticks and slips)
still shows its direction over a run of readings: :class:`DirectionRun` knows it at a reading beyond σ
where none of the last :data:`RUN_SAMPLES` readings points the other way, :data:`RUN_BEYOND` of them are
beyond σ in this one and half of them within 3σ.
At rest (white noise) that happens once in 400 000 samples, as often as two readings in a row beyond
3σ in one direction.  It counts whole numbers, so the node's step and replay's arrays agree exactly.
No rclpy import.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["AUTO", "CHECKPOINTS", "RUN_BEYOND", "RUN_SAMPLES", "DirectionRun", "SpeedNoise", "reading_noise"]

AUTO = "auto"
#: σ is (re)computed after this many samples and kept after the last
CHECKPOINTS = (50, 200, 1000)
#: a run of this many readings, none the other way and this many beyond σ, tells the direction
RUN_SAMPLES, RUN_BEYOND = 16, 8


def reading_noise(x: np.ndarray, segment: np.ndarray | None = None) -> float:
    """A reading's noise (standard deviation) from its second differences within each segment (a
    recording; None: one): ``max(1.4826·MAD(Δ²x), RMS of the central 90 % of Δ²x)/√6`` -- a smooth
    signal's second differences are next to nothing, a ramp's are 0, ``var Δ²x = 6σ²`` for white
    noise; the median is robust to a few jumps, the RMS keeps a quantised reading's steps that the
    median misses.  NaN with fewer than 3 values."""
    x = np.asarray(x, dtype=float)
    if len(x) < 3:
        return math.nan
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    if segment is not None:
        seg = np.asarray(segment)
        d2 = d2[(seg[2:] == seg[1:-1]) & (seg[1:-1] == seg[:-2])]
    d2 = d2[np.isfinite(d2)]
    if not len(d2):
        return math.nan
    mad = 1.4826 * float(np.median(np.abs(d2 - np.median(d2))))
    a = np.abs(d2)
    central = d2[a <= np.quantile(a, 0.9)]
    rms = float(np.sqrt(np.mean(central * central))) if len(central) else 0.0
    return max(mad, rms) / math.sqrt(6.0)


class SpeedNoise:
    """σ of the speed reading as the estimator uses it: a fixed value, or learned (``auto``)."""

    def __init__(self, setting: float | str) -> None:
        self.auto = setting == AUTO
        self._speeds: list[float] = []
        self.value = 0.0 if self.auto else float(setting)  #: σ now (0 while learning: the plain sign)
        self.known = not self.auto  #: a σ is known (before: no loss is measured)
        #: each checkpoint as learned: the time of the sample that completed it, and σ from then on
        self.learned: list[tuple[int, float]] = []
        #: checkpoints still to apply by sample time (a time slice that did not see the samples)
        self.schedule: list[tuple[int, float]] = []

    @property
    def learning(self) -> bool:
        """More samples are taken (a checkpoint is still to come)."""
        return self.auto and not self.schedule and len(self._speeds) < CHECKPOINTS[-1] and not self._followed

    _followed = False  #: σ comes from another estimator's checkpoints (:meth:`follow`)

    @property
    def learned_from(self) -> int:
        """Samples σ was learned from (0: given, or not yet)."""
        return len(self._speeds) if self.auto and self.known else 0

    @property
    def min_measured_rad_s(self) -> float:
        """Below this |ω| the direction is not known: no loss is measured (3σ; ∞ while not known)."""
        return 3.0 * self.value if self.known else math.inf

    def until_checkpoint(self) -> int:
        """Samples until σ is computed again (0: never again)."""
        if not self.learning:
            return 0
        n = len(self._speeds)
        return next(c for c in CHECKPOINTS if c > n) - n

    def add(self, speeds, last_t_ns: int = 0) -> bool:
        """Take the speeds of samples just estimated (at most :meth:`until_checkpoint` of them; the last
        one at ``last_t_ns``); True when σ changed."""
        if not self.learning:
            return False
        self._speeds.extend(speeds)
        if len(self._speeds) not in CHECKPOINTS:
            return False
        sigma = reading_noise(np.array(self._speeds))
        self.value, self.known = (sigma if math.isfinite(sigma) else 0.0), True
        self.learned.append((int(last_t_ns), self.value))
        return True

    def follow(self, learned: list[tuple[int, float]]) -> None:
        """Apply another estimator's checkpoints by sample time instead of learning (a time slice of a
        recording: its samples after a checkpoint's time get that σ, as in the whole recording)."""
        if self.auto:
            self.schedule = list(learned)
            self._followed = True
            self.learned = list(learned)

    def next_change_ns(self) -> int | None:
        """The time after which σ changes next by the schedule (None: no more)."""
        return self.schedule[0][0] if self.schedule else None

    def reach(self, t_ns: int) -> bool:
        """Apply the scheduled checkpoints at or before ``t_ns`` (the sample about to be estimated is
        after them); True when σ changed."""
        changed = False
        while self.schedule and self.schedule[0][0] < t_ns:
            _, self.value = self.schedule.pop(0)
            self.known = changed = True
        return changed

    def take_over(self, previous: SpeedNoise) -> None:
        """Go on learning where ``previous`` (also ``auto``) stands (a parameter change at run time)."""
        if self.auto and previous.auto:
            self._speeds = list(previous._speeds)
            self.value, self.known = previous.value, previous.known
            self.learned, self.schedule, self._followed = list(previous.learned), list(previous.schedule), \
                previous._followed

    def describe(self) -> str:
        """``0.0021 rad/s (learned from the first 1,000 samples)`` or ``… (parameter file)``."""
        if not self.auto:
            return f"{self.value:.3g} rad/s (parameter file)"
        if not self.known:
            return "not learned yet (auto)"
        if self._followed:
            return f"{self.value:.3g} rad/s (auto: learned from the recording's first samples)"
        return f"{self.value:.3g} rad/s (auto: learned from the first {len(self._speeds):,} samples)"


#: a reading's flags packed into one integer, a field of 5 bits each (a window of 16 counts up to 16, so
#: the sum of a window's codes is the count of each flag): below 0, above 0, beyond −σ, beyond +σ, within 3σ
_NEG, _POS, _BNEG, _BPOS, _WITHIN = 1, 1 << 5, 1 << 10, 1 << 15, 1 << 20
_FIELD = 31


class DirectionRun:
    """The direction a run of speed readings shows of a drive turning slower than one reading can tell:
    +1 or −1 at a reading beyond σ where, of the last :data:`RUN_SAMPLES` readings (this one included),
    none is of the other sign, at least :data:`RUN_BEYOND` are beyond σ of this one and at least half are
    within 3σ (a run whose readings are mostly beyond 3σ is told by them one by one; a reading near 0
    inside it is a glitch, not a drive that slowed); 0 elsewhere -- also at the readings of 0 while the
    drive sticks, where its torque holds it rather than turns it, and which a reversal may begin with.
    Each reading is flagged against the σ of its own time, so a σ learned later does not change what
    was known; :meth:`step` (one sample) and :meth:`many` (an array) count the same flags and give the
    same directions.  A reading's flags are one packed integer and a window's counts the sum of its
    readings' (:data:`_NEG` …), kept running over a ring of the last readings: a step is a few integer
    operations, a batch one cumulative sum."""

    def __init__(self) -> None:
        self._ring = [0] * (RUN_SAMPLES - 1)  #: the last RUN_SAMPLES − 1 readings' codes, oldest at _next
        self._next = 0
        self._held = 0  #: readings in the ring (up to RUN_SAMPLES − 1)
        self._total = 0  #: the sum of the ring's codes

    def _codes(self) -> list[int]:
        """The held readings' codes, oldest first."""
        if self._held < RUN_SAMPLES - 1:
            return self._ring[:self._held]
        return self._ring[self._next:] + self._ring[:self._next]

    def _hold(self, codes: list[int]) -> None:
        """Hold these readings' codes (oldest first; the last RUN_SAMPLES − 1 of them)."""
        codes = codes[-(RUN_SAMPLES - 1):]
        self._held = len(codes)
        self._ring = codes + [0] * (RUN_SAMPLES - 1 - len(codes))
        self._next = self._held % (RUN_SAMPLES - 1)
        self._total = sum(codes)

    def many(self, speed: np.ndarray, sigma: float, known: bool = True) -> np.ndarray:
        """The direction at each of ``speed``'s readings, following the readings before them; ``known``:
        σ is known (else nothing is: the readings are kept for later)."""
        w = np.asarray(speed, dtype=float)
        n, h = len(w), self._held
        code = (np.where(w < 0, _NEG, 0) + np.where(w > 0, _POS, 0) + np.where(w < -sigma, _BNEG, 0)
                + np.where(w > sigma, _BPOS, 0) + np.where(np.abs(w) < 3.0 * sigma, _WITHIN, 0)).astype(np.int64)
        every = np.concatenate([np.array(self._codes(), dtype=np.int64), code])
        self._hold(every[-(RUN_SAMPLES - 1):].tolist())
        out = np.zeros(n, dtype=np.int64)
        if not known or n == 0:
            return out
        end = np.arange(h, h + n) + 1  # each reading's window: the RUN_SAMPLES readings up to it
        c = np.concatenate([[0], np.cumsum(every)])
        total = c[end] - c[np.maximum(end - RUN_SAMPLES, 0)]
        slow = (end >= RUN_SAMPLES) & (2 * ((total >> 20) & _FIELD) >= RUN_SAMPLES)
        out[slow & (w > sigma) & ((total & _FIELD) == 0) & (((total >> 15) & _FIELD) >= RUN_BEYOND)] = 1
        out[slow & (w < -sigma) & (((total >> 5) & _FIELD) == 0) & (((total >> 10) & _FIELD) >= RUN_BEYOND)] = -1
        return out

    def step(self, speed: float, sigma: float, known: bool = True) -> int:
        """:meth:`many` of one reading."""
        w = float(speed)
        if w > 0:
            code = _POS + _BPOS if w > sigma else _POS
        elif w < 0:
            code = _NEG + _BNEG if w < -sigma else _NEG
        else:
            code = 0
        if -3.0 * sigma < w < 3.0 * sigma:
            code += _WITHIN
        total = self._total + code
        direction = 0
        if known and self._held == RUN_SAMPLES - 1 and 2 * ((total >> 20) & _FIELD) >= RUN_SAMPLES:
            if w > sigma and not total & _FIELD and (total >> 15) & _FIELD >= RUN_BEYOND:
                direction = 1
            elif w < -sigma and not (total >> 5) & _FIELD and (total >> 10) & _FIELD >= RUN_BEYOND:
                direction = -1
        i = self._next
        self._total = total - self._ring[i]  # the oldest leaves (0 while the ring fills)
        self._ring[i] = code
        self._next = i + 1 if i < RUN_SAMPLES - 2 else 0
        if self._held < RUN_SAMPLES - 1:
            self._held += 1
        return direction

    def take_over(self, previous: DirectionRun) -> None:
        """Go on from ``previous``'s readings (a parameter change at run time)."""
        self._hold(previous._codes())
