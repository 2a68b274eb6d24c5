#!/usr/bin/env python3
"""calibrate on 1 hour of 1 kHz data (3.6 M samples) and the cost of one RLS update.

Usage: python bench/bench_calibrate.py [--minutes 60] [--keep DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from common import long_bag

from rollergear_ros.calibration.calibrate import calibrate, load_samples
from rollergear_ros.core.effects import EffectInputs
from rollergear_ros.core.adaptation import RecursiveLeastSquares, regressor_plan, regressors
from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.params import load_config


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--keep", type=Path)
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="rollergear_bench_"))
    bag = long_bag(work / f"rig_drag_{args.minutes:g}min_{args.rate:g}hz.mcap", args.minutes, args.rate,
                   ["drag_speed:c=3e-4,p=1.4", "drag_constant:c=0.04"])
    config = load_config()
    t0 = time.perf_counter()
    data = load_samples([bag], config)
    t_load = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = calibrate(data, config)
    t_cal = time.perf_counter() - t0
    print(f"samples: {len(data.t_ns):,}; reading + pairing + model: {t_load:.1f} s; analysis: {t_cal:.1f} s; "
          f"total {t_load + t_cal:.1f} s (target <= 20 s)")
    print(f"verdict {result.verdict}: " + ", ".join(
        f"{e.name} {e.params}" for e in result.effects)
        + f"; held-out RMSE {result.error_before.rmse_nm:.4g} -> {result.error_after.rmse_nm:.4g} N·m")

    cal = config.with_values({"effects.drag_speed.enabled": True, "effects.drag_speed.c": 3e-4,
                              "effects.drag_speed.p": 1.4, "effects.drag_constant.enabled": True,
                              "effects.drag_constant.c_nm": 0.04, "effects.torque_offset.enabled": True})
    est = Estimator(cal)
    names = est.adaptive
    rls = RecursiveLeastSquares([0.0] * len(names), 0.9995)
    plan = regressor_plan(names, cal)
    phis = [regressors(plan, EffectInputs(10.0 + i % 50, 100.0 + i % 200, 10.0, 1.0)) for i in range(20000)]
    t0 = time.perf_counter()
    for phi in phis:
        rls.update(phi, 0.1)
    t_rls = (time.perf_counter() - t0) / len(phis)
    print(f"RLS update ({len(names)} coefficients: {', '.join(names)}): {t_rls * 1e6:.1f} µs (target <= 20 µs)")


if __name__ == "__main__":
    main()
