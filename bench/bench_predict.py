#!/usr/bin/env python3
"""``predict`` of 1 h at 1 kHz against ``replay`` without an output file on the same profile (#44: <= 1x).

The parameter file has a speed drag with the covariance calibrate writes of it (two parameters
propagated: two more evaluations of the model per sample), and a rerun of each, interleaved; the
best of --repeat each.
Usage: python bench/bench_predict.py [--minutes 60] [--rate 1000] [--keep DIR] [--repeat 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from common import long_bag

from rollergear_ros import predict
from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay

COVARIANCE = ('{"keys": ["effects.drag_speed.c", "effects.drag_speed.p"], '
              '"matrix": [[2e-11, -1.2e-8], [-1.2e-8, 7.4e-6]]}')


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--keep", type=Path, help="keep (and reuse) the recording in this folder")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        bag = long_bag(folder / f"rig_{args.minutes:g}min_{args.rate:g}hz.mcap", args.minutes, args.rate)
        config = load_config().with_values({"effects.drag_speed.enabled": True, "effects.drag_speed.c": 3e-4,
                                            "effects.drag_speed.p": 1.4, "calibration.covariance": COVARIANCE})
        best = {"predict": float("inf"), "replay": float("inf")}
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            p = predict(bag, config)
            best["predict"] = min(best["predict"], time.perf_counter() - t0)
            t0 = time.perf_counter()
            summary, _ = replay(bag, config, show_progress=False)
            best["replay"] = min(best["replay"], time.perf_counter() - t0)
        print(f"{p.samples:,} samples: predict {best['predict']:.2f} s (energy {p.energy_lost_j:,.0f} J, 95 % band "
              f"± {1.96 * p.energy_lost_sd_j:,.1f} J over {len(p.parameters)} parameters); replay without output "
              f"{best['replay']:.2f} s -> {best['predict'] / best['replay']:.2f}x (target <= 1x)")


if __name__ == "__main__":
    main()
