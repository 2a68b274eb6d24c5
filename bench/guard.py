#!/usr/bin/env python3
"""Same-run guard against large slowdowns (CI runs it through ``scripts/bench-guard``).

Each figure is a ratio of two timings taken in this run on this machine, so a slower or busier
machine moves both; a guard fails only below **half** of its target, which load cannot reach, but a
slowdown like replay's 20x (one writer call per sample) does.

1. ``replay --out`` on a 2-minute 1 kHz recording against raw ``mcap`` iteration of the same file
   (README target: replay >= 0.5x the raw iteration rate; fails below 0.25x).
2. ``calibrate`` on 5 minutes against its own reading of the same file (reading, pairing and the
   model: ``load_samples``; target: the analysis takes <= 3x the reading; fails above 6x).

Usage: python bench/guard.py [--keep DIR]   (exit status 1 when a guard fails)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from common import long_bag

from rollergear_ros.calibration.calibrate import calibrate, load_samples
from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay

REPLAY_TARGET = 0.5  #: replay rate / raw iteration rate
CALIBRATE_TARGET = 3.0  #: analysis time / reading time


def raw_iteration_s(bag: Path) -> tuple[int, float]:
    from mcap.reader import make_reader

    t0 = time.perf_counter()
    n = 0
    with bag.open("rb") as fh:
        for _ in make_reader(fh).iter_messages(log_time_order=False):
            n += 1
    return n, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, help="folder for the generated recordings (default: a temp folder)")
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="rollergear_guard_"))
    config = load_config()
    failed = []

    bag = long_bag(work / "guard_replay_2min.mcap", 2.0, 1000.0)
    n_raw, t_raw = raw_iteration_s(bag)
    t0 = time.perf_counter()
    summary, _ = replay(bag, config, out_mcap=work / "guard_replay_out.mcap", show_progress=False)
    t_replay = time.perf_counter() - t0
    ratio = t_raw / t_replay
    ok = ratio >= REPLAY_TARGET / 2
    failed += [] if ok else ["replay"]
    print(f"replay --out, 2 min at 1 kHz: {summary.input_messages:,} messages in {t_replay:.2f} s; raw mcap "
          f"iteration {n_raw:,} in {t_raw:.2f} s -> {ratio:.2f}x (target >= {REPLAY_TARGET}x, fails below "
          f"{REPLAY_TARGET / 2}x): {'ok' if ok else 'FAILED'}")

    bag = long_bag(work / "guard_calibrate_5min.mcap", 5.0, 1000.0, ["drag_speed:c=3e-4,p=1.4", "drag_constant:c=0.04"])
    t0 = time.perf_counter()
    data = load_samples([bag], config)
    t_read = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = calibrate(data, config)
    t_cal = time.perf_counter() - t0
    ratio = t_cal / t_read
    ok = ratio <= CALIBRATE_TARGET * 2
    failed += [] if ok else ["calibrate"]
    print(f"calibrate, 5 min at 1 kHz ({result.verdict}): analysis {t_cal:.2f} s, its reading {t_read:.2f} s -> "
          f"{ratio:.2f}x (target <= {CALIBRATE_TARGET}x, fails above {CALIBRATE_TARGET * 2}x): "
          f"{'ok' if ok else 'FAILED'}")
    if failed:
        print(f"bench guard: {', '.join(failed)} slower than half its target", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
