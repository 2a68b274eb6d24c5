"""Messages held back and handed to the chunked writer in log-time order (no rclpy)."""

from __future__ import annotations

import numpy as np

from .mcapwriter import ChunkedMcapWriter


class TimeOrderBuffer:
    """Holds messages back and hands them to a :class:`ChunkedMcapWriter` in log-time order.

    Streaming readers (Foxglove, ``ros2 bag play``) read a file front to back and want its messages
    in log-time order across topics; a replay produces each batch's estimates topic by topic, and a
    sample completes a little after its inputs arrived.  :meth:`release` writes what is older than a
    watermark (nothing later can be older than that), :meth:`release` with none writes the rest.
    Payloads stay numpy arrays throughout, grouped by size; only a message with a publish time of
    its own goes one by one.
    """

    def __init__(self, writer: ChunkedMcapWriter) -> None:
        self._writer = writer
        self._fixed: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (channel ids, log times, payload rows)
        self._single: list[tuple[int, int, bytes, int | None]] = []  # (channel id, log time, payload, publish time)

    def __len__(self) -> int:
        return sum(len(t) for _, t, _ in self._fixed) + len(self._single)

    def add_messages(self, channel_id: int | np.ndarray, log_time: np.ndarray, payload: np.ndarray) -> None:
        log_time = np.asarray(log_time, dtype=np.int64)
        ids = np.broadcast_to(np.asarray(channel_id, dtype=np.int64), log_time.shape).copy()
        if len(log_time):
            self._fixed.append((ids, log_time, payload))

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int | None = None) -> None:
        if publish_time is None:  # a one-row array: released with the others of its size in one call
            self._fixed.append((np.array([channel_id], dtype=np.int64), np.array([log_time], dtype=np.int64),
                                np.frombuffer(data, dtype=np.uint8)[None, :]))
        else:
            self._single.append((channel_id, log_time, data, publish_time))

    def release(self, up_to_ns: int | None = None) -> None:
        """Write, in log-time order (the order added among equal times), every message whose log
        time is at most ``up_to_ns`` (all of them when None); keep the rest."""
        if not self._fixed and not self._single:
            return
        groups: dict[int, list] = {}
        for ids, t, pl in self._fixed:
            groups.setdefault(pl.shape[1], []).append((ids, t, pl))
        merged = [tuple(np.concatenate(parts) for parts in zip(*items)) for items in groups.values()]
        single = self._single
        sizes = [len(t) for _, t, _ in merged] + [len(single)]
        source = np.repeat(np.arange(len(sizes), dtype=np.int64), sizes)
        source[len(source) - len(single):] = -1
        index = np.concatenate([np.arange(k, dtype=np.int64) for k in sizes])
        t_all = np.concatenate([t for _, t, _ in merged] + [np.array([m[1] for m in single], dtype=np.int64)])
        ids_all = np.concatenate([i for i, _, _ in merged] + [np.array([m[0] for m in single], dtype=np.int64)])
        order = np.argsort(t_all, kind="stable")
        t_sorted = t_all[order]
        n_out = len(order) if up_to_ns is None else int(t_sorted.searchsorted(np.int64(up_to_ns), side="right"))
        out = order[:n_out]
        src, idx, ids_out, t_out = source[out], index[out], ids_all[out], t_sorted[:n_out]
        # the runs between messages with a publish time of their own go to the writer in one call
        # each, whatever the interleaving of payload widths inside them (one call per run of one
        # width made a 1 kHz replay with a stamped estimate call the writer twice per sample)
        payloads = [pl for _, _, pl in merged]
        a = 0
        for cut in np.flatnonzero(src < 0).tolist() + [n_out]:
            if cut > a:
                if len(merged) == 1:
                    self._writer.add_messages(ids_out[a:cut], t_out[a:cut], payloads[0][idx[a:cut]])
                else:
                    self._writer.add_mixed(ids_out[a:cut], t_out[a:cut], src[a:cut], idx[a:cut], payloads)
            if cut < n_out:
                self._writer.add_message(*single[int(idx[cut])])
            a = cut + 1
        rest = order[n_out:]
        self._fixed = []
        for g, (ids, t, pl) in enumerate(merged):
            sel = np.sort(index[rest][source[rest] == g])
            if len(sel):
                self._fixed.append((ids[sel], t[sel], pl[sel]))
        self._single = [single[j] for j in np.sort(index[rest][source[rest] == -1]).tolist()]
