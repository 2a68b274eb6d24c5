#!/usr/bin/env python3
"""Model throughput: vectorised samples/s and per-sample µs, against numpy baselines in the same run.

Usage: python bench/bench_model.py [--samples N]
"""

from __future__ import annotations

import argparse

import numpy as np

from common import best_of

from rollergear_ros.core.model import LossModel
from rollergear_ros.core.params import load_config


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=3_600_000, help="array length (1 h at 1 kHz)")
    args = ap.parse_args()
    n = args.samples
    rng = np.random.default_rng(0)
    torque = rng.uniform(-100, 100, n)
    speed = rng.uniform(-300, 300, n)
    lm = LossModel(load_config().gearbox)

    t_base = best_of(lambda: np.abs(torque) ** 0.47)
    t_loss = best_of(lambda: lm.loss_magnitude(torque, speed))
    t_full = best_of(lambda: lm.evaluate(torque, speed, breakdown=False))
    t_bd = best_of(lambda: lm.evaluate(torque, speed, breakdown=True), repeat=3)

    k = 200_000
    ts, ws = torque[:k].tolist(), speed[:k].tolist()

    def per_sample():
        f = lm.loss_magnitude_scalar
        e = lm.efficiency_scalar
        for t, w in zip(ts, ws):
            e(t, w, f(t, w))

    t_ps = best_of(per_sample, repeat=3)

    def baseline_scalar():
        for t in ts:
            abs(t) ** 0.47

    t_ps_base = best_of(baseline_scalar, repeat=3)
    print(f"samples: {n:,}")
    print(f"numpy baseline |T|**0.47          : {n / t_base / 1e6:8.1f} M samples/s")
    print(f"model loss magnitude (vectorised) : {n / t_loss / 1e6:8.1f} M samples/s "
          f"({t_loss / t_base:.1f}x the baseline's time)")
    print(f"model + signed loss + power + eff.: {n / t_full / 1e6:8.1f} M samples/s")
    print(f"  ... with per-term breakdown     : {n / t_bd / 1e6:8.1f} M samples/s")
    print(f"per-sample path (loss + eff.)     : {t_ps / k * 1e6:8.2f} µs/sample "
          f"(python-float baseline abs(t)**0.47: {t_ps_base / k * 1e6:.2f} µs)")
    ok = n / t_full >= 10e6 and t_ps / k <= 20e-6
    print("targets (>= 10 M samples/s vectorised, <= 20 µs per sample):", "met" if ok else "NOT met")


if __name__ == "__main__":
    main()
