"""An MCAP file's messages in log-time order, read linearly chunk by chunk (:func:`iter_log_time_order`):
each channel is in log-time order within a file, but channels interleave loosely across chunks, so what
may still be preceded by a message of the next chunk is held back (:func:`release_count`).  No rclpy."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .fastmcap import ReadState, iter_message_arrays


def release_count(t_sorted: np.ndarray, keys_sorted: np.ndarray, ignore_key: int | None = None) -> int:
    """How many messages of a log-time-sorted batch are safe to hand on before the next batch is read.

    Each channel is in log-time order within a file, but channels interleave loosely across chunk
    (and batch) boundaries, so a message newer than the oldest of the channels' latest messages may
    still be preceded by one in the next batch; those are held back.  ``ignore_key`` names a slow
    channel (e.g. a temperature) whose last message must not hold everything else back.
    """
    keep = keys_sorted != ignore_key if ignore_key is not None else slice(None)
    t, k = t_sorted[keep], keys_sorted[keep]
    if len(t) == 0:
        return len(t_sorted)
    uniq, inv = np.unique(k, return_inverse=True)
    lasts = np.full(len(uniq), np.iinfo(np.int64).min, dtype=np.int64)
    np.maximum.at(lasts, inv, t)
    return int(np.searchsorted(t_sorted, lasts.min(), side="right"))


def iter_log_time_order(path: str | Path, state: ReadState | None = None
                        ) -> Iterator[tuple[np.ndarray, np.ndarray, list[bytes]]]:
    """All messages of an MCAP file in log-time order (file order among equal times), chunk by chunk.

    Yields ``(log_time, channel_id, payloads)``; ``state.channels`` maps the ids to topics.  Reads
    linearly like :func:`iter_message_arrays` (so also unindexed or truncated files) and restores
    the order across chunk boundaries with :func:`release_count`.
    """
    state = state if state is not None else ReadState()
    carry_t = np.empty(0, dtype=np.int64)
    carry_c = np.empty(0, dtype=np.int64)
    carry_p: list[bytes] = []
    for arrays in iter_message_arrays(path, state):
        data = arrays.buf.tobytes()
        payloads = carry_p + [data[o:o + n] for o, n in zip(arrays.offset.tolist(), arrays.length.tolist())]
        t = np.concatenate([carry_t, arrays.log_time])
        c = np.concatenate([carry_c, arrays.channel.astype(np.int64)])
        order = np.argsort(t, kind="stable")
        t, c = t[order], c[order]
        payloads = [payloads[i] for i in order.tolist()]
        cut = release_count(t, c)
        yield t[:cut], c[:cut], payloads[:cut]
        carry_t, carry_c, carry_p = t[cut:], c[cut:], payloads[cut:]
    if len(carry_t):
        yield carry_t, carry_c, carry_p
