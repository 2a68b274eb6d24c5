"""A paired channel whose whole stream is shifted against the drive torque's (:class:`ChannelSpans`).

Pairing by stamps joins each drive sample with the other channels' messages of the same stamp.  A
logger whose clock is off by more than a sample period (a DAQ started with another time base, a
channel re-stamped on export) still pairs -- every stamp finds a partner on a regular grid -- but with
another moment of the gearbox's: the measured efficiency and the residual are then of no sample at
all, and nothing else says so.  Such a channel begins and ends the same span after (or before) the
drive torque; a channel that was only started or stopped apart from the others does not do both alike.
The node's skew detector tells it from arrival votes (:mod:`core.pairing`); replay from the streams'
ends, here.  No rclpy import.
"""

from __future__ import annotations

import numpy as np

from ..core.pairing import CHANNELS, OUT_SPEED, OUT_TORQUE, SPEED, TORQUE

__all__ = ["ChannelSpans"]

_CHECKED = (SPEED, OUT_TORQUE, OUT_SPEED)  #: the channels compared with the drive torque


class ChannelSpans:
    """Each paired channel's first and last stamp, from the batches replay reads."""

    def __init__(self) -> None:
        self.first: dict[str, int] = {}
        self.last: dict[str, int] = {}

    def add(self, codes: np.ndarray, t_ns: np.ndarray) -> None:
        for channel in (TORQUE, *_CHECKED):
            t = t_ns[codes == CHANNELS.index(channel)]
            if len(t):
                lo, hi = int(t.min()), int(t.max())
                self.first[channel] = min(self.first.get(channel, lo), lo)
                self.last[channel] = max(self.last.get(channel, hi), hi)

    def shifted(self, period_s: float | None) -> dict[str, float]:
        """Channel -> its shift against the drive torque in s, where its first and its last stamp are
        both more than a sample period after (or before) the torque's, by the same span within a period."""
        period_ns = (period_s or 0.0) * 1e9
        if TORQUE not in self.first or period_ns <= 0:
            return {}
        out = {}
        for channel in _CHECKED:
            if channel not in self.first:
                continue
            start = self.first[channel] - self.first[TORQUE]
            end = self.last[channel] - self.last[TORQUE]
            if min(abs(start), abs(end)) > period_ns and start * end > 0 and abs(start - end) <= period_ns:
                out[channel] = 0.5 * (start + end) * 1e-9
        return out

    def text(self, period_s: float | None) -> str:
        """One line for the channels :meth:`shifted` finds ('' when none)."""
        shifted = self.shifted(period_s)
        if not shifted:
            return ""
        what = "; ".join(f"{c.replace('_', ' ')} {abs(s):.4g} s {'after' if s > 0 else 'before'}"
                         for c, s in shifted.items())
        return (f"a channel's whole stream is shifted against the drive torque's -- {what} it, at both ends: "
                "each drive sample is paired with that channel's reading of another moment (its measured "
                "output and residual belong to no sample); a logger on another clock? Shift its stamps, or "
                "give estimator.<channel>_lag_s where the shift is a lag within ±1 s")
