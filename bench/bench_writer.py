#!/usr/bin/env python3
"""Messages added one by one, as the node's recorder adds them, against the ``mcap`` library's writer.

Per sample: five Float64 messages (12 bytes, publish times of their own) and every tenth sample a
60-byte one, into a durable :class:`~rollergear_ros.recordings.mcapwriter.ChunkedMcapWriter` with the
node's 256 KB chunks; the baseline, in the same run, is ``mcap.writer.Writer`` adding the same
messages to chunks of the same size (zstd both).  Best of ``--repeat``.

Usage: python bench/bench_writer.py [--samples 200000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from common import best_of
from mcap.writer import CompressionType, Writer

from rollergear_ros.recordings.mcapwriter import ChunkedMcapWriter

CHUNK_BYTES = 256 * 1024  #: the node's recording chunks


def messages(samples: int):
    """(channel index, log time, publish time, payload) of the messages, in the order added."""
    narrow, wide = bytes(12), bytes(60)
    for k in range(samples):
        t = 10**18 + k * 1_000_000
        for c in range(5):
            yield c, t, t - 5_000, narrow
        if k % 10 == 0:
            yield 5, t, t, wide


def ours(path: Path, batch: list) -> None:
    path.unlink(missing_ok=True)  # a durable recording never overwrites a file
    w = ChunkedMcapWriter(path, chunk_size=CHUNK_BYTES, durable=True)
    sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    ids = [w.register_channel(f"/c{i}", "cdr", sid) for i in range(6)]
    add = w.add_message
    for c, t, p, data in batch:
        add(ids[c], t, data, p)
    w.close()


def library(path: Path, batch: list) -> None:
    with path.open("wb") as fh:
        w = Writer(fh, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="bench")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        ids = [w.register_channel(f"/c{i}", "cdr", sid) for i in range(6)]
        add = w.add_message
        for c, t, p, data in batch:
            add(ids[c], t, data, p)
        w.finish()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    batch = list(messages(args.samples))
    work = Path(tempfile.mkdtemp(prefix="rollergear_bench_writer_"))
    t_ours = best_of(lambda: ours(work / "ours.mcap", batch), args.repeat)
    t_lib = best_of(lambda: library(work / "mcap.mcap", batch), args.repeat)
    n = len(batch)
    print(f"mcap library writer       : {n:,} messages in {t_lib:6.2f} s = {t_lib / n * 1e6:5.2f} µs each")
    print(f"ChunkedMcapWriter (durable): {n:,} messages in {t_ours:6.2f} s = {t_ours / n * 1e6:5.2f} µs each "
          f"-> {t_ours / t_lib:.2f}x the library's time (target <= 1x)")


if __name__ == "__main__":
    main()
