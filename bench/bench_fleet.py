#!/usr/bin/env python3
# ruff: noqa: E402 - the thread limits must be set before numpy is imported
"""Fleet replay on a Dask LocalCluster against the same recordings replayed one after another.

Baseline measured in the same run: ``replay`` of each recording in this process, one after the
other.  Then ``rollergear fleet replay`` on a ``LocalCluster`` of ``--workers`` processes (its
start-up not counted; a fresh output folder each time), and the scheduler's overhead per
recording: trivial tasks submitted and gathered the same way, per task.  Last, one recording
replayed in time slices on the cluster (``--slices`` tasks) against its replay in this process.

Usage: python bench/bench_fleet.py [--recordings 16] [--minutes 10] [--workers 2] [--slices 4] [--keep DIR]
"""

from __future__ import annotations

import os

# the replay gains nothing from OpenBLAS threads (measured: 3.34 s with them on 2 cores at 194 % CPU,
# 3.18 s without at 99 %); Dask's workers run with one thread each, so the baseline does too
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from common import long_bag

from rollergear_ros.fleet.cluster import dask_client
from rollergear_ros.fleet.logs import discover
from rollergear_ros.fleet.run import FleetRun, run_replay
from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay


def _nothing(i: int) -> int:
    return i


def _warm() -> None:
    """Import what a replay task needs (a worker's one-time start-up, not counted per recording)."""
    import rollergear_ros.sources.importer  # noqa: F401
    import rollergear_ros.replay.run  # noqa: F401


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--recordings", type=int, default=16)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--slices", type=int, default=4)
    ap.add_argument("--keep", type=Path)
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="rollergear_bench_"))
    one = long_bag(work / f"rig_{args.minutes:g}min_{args.rate:g}hz.mcap", args.minutes, args.rate,
                   ["drag_constant:c=0.05"])
    logs = work / "fleet"
    for i in range(args.recordings):
        dst = logs / f"gb{i % 4:02d}" / f"log{i:03d}.mcap"
        if not dst.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(one, dst)
    recs = discover([str(logs)])
    config = load_config()
    samples = 0
    t0 = time.perf_counter()
    for r in recs:
        s, _ = replay(r.path, config, show_progress=False)
        samples += s.samples
    sequential = time.perf_counter() - t0
    print(f"{len(recs)} recordings x {args.minutes:g} min at {args.rate:g} Hz ({samples:,} samples): one after another "
          f"in one process {sequential:.2f} s = {samples / sequential / 1e3:.0f} k samples/s")
    with dask_client(workers=args.workers) as client:
        client.run(_warm)  # workers warm: imports done once per worker process
        out = work / "out"
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.perf_counter()
        rows, ran = run_replay(recs, out, FleetRun(client, config))
        fleet = time.perf_counter() - t0
        assert ran == len(recs) and all(r["status"] == "ok" for r in rows)
        n = 200
        t0 = time.perf_counter()
        client.gather(client.map(_nothing, range(n), pure=False))
        overhead = (time.perf_counter() - t0) / n
        (long,) = discover([str(one)])
        t0 = time.perf_counter()
        whole, _ = replay(one, config, show_progress=False)
        alone = time.perf_counter() - t0
        out = work / "out_sliced"
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.perf_counter()
        rows, _ = run_replay([long], out, FleetRun(client, config), slice_messages=-(-long.messages // args.slices))
        sliced = time.perf_counter() - t0
        assert rows[0]["status"] == "ok" and rows[0]["slices"] == args.slices and rows[0]["samples"] == whole.samples
    print(f"fleet replay on a LocalCluster of {args.workers} worker processes: {fleet:.2f} s = "
          f"{samples / fleet / 1e3:.0f} k samples/s -> {sequential / fleet:.2f}x one after another; "
          f"scheduler overhead {1e3 * overhead:.1f} ms per task ({n} trivial tasks)")
    print(f"one recording ({whole.samples:,} samples): replay in this process {alone:.2f} s; fleet replay in "
          f"{args.slices} time slices {sliced:.2f} s -> {alone / sliced:.2f}x")


if __name__ == "__main__":
    main()
