"""Independent readers for tests: rosbags (AnyReader) and mcap + mcap-ros2-support."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def read_rosbags(path: Path) -> dict[str, tuple[np.ndarray, list]]:
    """Topic -> (log times ns, messages) with the rosbags library."""
    from rosbags.highlevel import AnyReader

    out: dict[str, tuple[list, list]] = {}
    with AnyReader([Path(path)]) as reader:
        for con, t, raw in reader.messages():
            msg = reader.deserialize(raw, con.msgtype)
            ts, ms = out.setdefault(con.topic, ([], []))
            ts.append(t)
            ms.append(msg)
    return {k: (np.array(v[0], dtype=np.int64), v[1]) for k, v in out.items()}


def read_mcap_ros2(path: Path) -> dict[str, tuple[np.ndarray, list]]:
    """Topic -> (log times ns, decoded messages) with mcap + mcap-ros2-support, in log-time order."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, tuple[list, list]] = {}
    with Path(path).open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            ts, ms = out.setdefault(channel.topic, ([], []))
            ts.append(message.log_time)
            ms.append(decoded)
    return {k: (np.array(v[0], dtype=np.int64), v[1]) for k, v in out.items()}


def float_series(messages: dict, topic: str) -> tuple[np.ndarray, np.ndarray]:
    t, ms = messages[topic]
    v = np.array([m.data for m in ms], dtype=float)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]
