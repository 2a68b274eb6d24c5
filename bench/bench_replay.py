#!/usr/bin/env python3
"""Replay throughput on a 1-hour 1 kHz recording, against raw MCAP iteration in the same run.

Generates the recording (motor + output torque and speed, oil temperature at 10 Hz: 14.4 M
messages for an hour) unless --bag is given, then times:
  1. raw iteration with the ``mcap`` reader (no decoding), file order;
  2. raw iteration with ``rosbags``' AnyReader (no deserialisation);
  3. decoding message by message with ``mcap-ros2-support`` (on a slice, extrapolated);
  4. ``rollergear replay`` without an output file (what a fleet task does; #13's per-core target);
  5. ``rollergear replay`` (decode + pair + estimate + write the output MCAP), also against 2.
With ``--memory``: replay (no output file) with the ``dahl`` effect on (a state stepped every sample)
against the same replay with a memoryless ``drag_constant``, adaptation off and on, interleaved,
the best of two each (#29: >= 0.7x).
With ``--without-c``: everything as a build without a C compiler runs it (numpy lays out and finds
the MCAP records instead of ``recordings/_records.c``).
Usage: python bench/bench_replay.py [--minutes 60] [--rate 1000] [--keep DIR] [--memory] [--without-c]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from common import long_bag

from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay


def crc_cost(bag: Path) -> float:
    """Seconds the reader spends verifying chunk CRCs (zlib.crc32 over each decompressed chunk)."""
    import struct
    import zlib

    from rollergear_ros.recordings.records import OP_CHUNK
    from rollergear_ros.recordings.fastmcap import chunk_records

    total = 0.0
    with bag.open("rb") as fh:
        fh.seek(8)
        while True:
            head = fh.read(9)
            if len(head) < 9:
                break
            op, ln = head[0], struct.unpack("<Q", head[1:])[0]
            if op != OP_CHUNK:
                fh.seek(ln, 1)
                continue
            data = chunk_records(fh.read(ln))
            t0 = time.perf_counter()
            zlib.crc32(data)
            total += time.perf_counter() - t0
    return total


#: ``--memory``: the effect each replay has on (the memoryless twin is the baseline)
EFFECT_ON = {
    "drag_constant": {"effects.drag_constant.enabled": True, "effects.drag_constant.c_nm": 0.05},
    "dahl": {"effects.dahl.enabled": True, "effects.dahl.c_nm": 0.05, "effects.dahl.presliding_rad": 0.01},
}


def memory_cost(bag: Path, config) -> None:
    """Replay with ``dahl`` against replay with ``drag_constant``, adaptation off and on."""
    for adapt in (False, True):
        best = {}
        for _ in range(2):
            for name, values in EFFECT_ON.items():
                cfg = config.with_values({**values, "estimator.adapt": adapt})
                t0 = time.perf_counter()
                replay(bag, cfg, show_progress=False)
                best[name] = min(best.get(name, float("inf")), time.perf_counter() - t0)
        print(f"replay, adaptation {'on ' if adapt else 'off'}: dahl {best['dahl']:.2f} s, drag_constant "
              f"{best['drag_constant']:.2f} s -> {best['drag_constant'] / best['dahl']:.2f}x (target >= 0.7x)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--bag", type=Path, help="use this recording instead of generating one")
    ap.add_argument("--keep", type=Path, help="directory for the generated files (default: a temp dir)")
    ap.add_argument("--memory", action="store_true", help="only: replay with the dahl effect against drag_constant")
    ap.add_argument("--without-c", action="store_true",
                    help="as a build without a C compiler: numpy lays out and finds the records")
    args = ap.parse_args()
    if args.without_c:
        from rollergear_ros.recordings import fastmcap, layout

        fastmcap._native_scan = layout._native_records = None
    work = args.keep or Path(tempfile.mkdtemp(prefix="rollergear_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    config = load_config()
    bag = args.bag or long_bag(work / f"rig_{args.minutes:g}min_{args.rate:g}hz.mcap", args.minutes, args.rate)
    if args.memory:
        memory_cost(bag, config)
        return

    from mcap.reader import make_reader

    t0 = time.perf_counter()
    n_raw = 0
    with bag.open("rb") as fh:
        for _ in make_reader(fh).iter_messages(log_time_order=False):
            n_raw += 1
    t_raw = time.perf_counter() - t0
    print(f"raw mcap iteration           : {n_raw:,} messages in {t_raw:6.1f} s = {n_raw / t_raw / 1e3:7.0f} k msg/s")

    from rosbags.highlevel import AnyReader

    t0 = time.perf_counter()
    n_rb = 0
    with AnyReader([bag]) as reader:
        for _ in reader.messages():  # raw bytes, no deserialisation
            n_rb += 1
    t_rb = time.perf_counter() - t0
    print(f"raw rosbags iteration        : {n_rb:,} messages in {t_rb:6.1f} s = {n_rb / t_rb / 1e3:7.0f} k msg/s")

    from mcap_ros2.decoder import DecoderFactory

    limit = min(n_raw, 1_000_000)
    t0 = time.perf_counter()
    n_dec = 0
    with bag.open("rb") as fh:
        for _ in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(log_time_order=False):
            n_dec += 1
            if n_dec >= limit:
                break
    t_dec = (time.perf_counter() - t0) * n_raw / n_dec
    print(f"mcap-ros2-support decode     : {n_dec / (t_dec * n_dec / n_raw) / 1e3:7.0f} k msg/s "
          f"(measured on {n_dec:,}, extrapolated to {t_dec:.1f} s)")

    t0 = time.perf_counter()
    bare, _ = replay(bag, config, show_progress=False)  # what a fleet task does: no output file
    t_bare = time.perf_counter() - t0
    print(f"replay without output (fleet): {bare.input_messages:,} messages in {t_bare:6.1f} s = "
          f"{bare.input_messages / t_bare / 1e3:7.0f} k msg/s = {t_rb / t_bare:.2f}x raw rosbags (target >= 1 M msg/s)")

    out = work / "hour_estimates.mcap"
    t0 = time.perf_counter()
    summary, _ = replay(bag, config, out_mcap=out, show_progress=False)
    t_rep = time.perf_counter() - t0
    print(
        f"rollergear replay            : {summary.estimated:,} samples, {summary.input_messages:,} messages in "
        f"{t_rep:6.1f} s = {summary.input_messages / t_rep / 1e3:7.0f} k msg/s; "
        f"output {out.stat().st_size / 1e6:.0f} MB"
    )
    t_crc = crc_cost(bag)
    print(f"chunk CRC verification       : {t_crc:6.2f} s of the replay's {t_rep:.1f} s ({100 * t_crc / t_rep:.1f} %)")
    print(f"replay rate / raw iteration rate   : {t_raw / t_rep:.2f}x  (target >= 0.5x)")
    print(f"replay (--out) / raw rosbags rate  : {t_rb / t_rep:.2f}x  (target >= 4x)")
    print(f"replay speed-up over ros2 decoding : {t_dec / t_rep:.2f}x  (target >= 5x)")


if __name__ == "__main__":
    main()
