#!/usr/bin/env python3
"""Verdicts and held-out error reductions of ``calibrate`` for every effect of the vocabulary.

Each case simulates a recording with effects drawn from physically plausible ranges (the same
draws as test/calibration/test_calibrate.py), runs the analysis without telling it what was simulated, and
prints one Markdown table row.  Usage: python bench/closing_the_loop.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parent.parent / "test" / d) for d in ("calibration", "")]
from test_calibrate import CASES, OILS, datasheet_oil, draw_effect  # noqa: E402

from rollergear_ros.calibration.calibrate import calibrate, load_samples  # noqa: E402
from rollergear_ros.core.params import load_config  # noqa: E402
from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate, write_rig_bag  # noqa: E402


def run(tmp: Path, effects, profile: str, seed: int, **kw):
    config = load_config()
    opts = SimulationOptions(profile=profile, rate_hz=100.0, seed=seed, effects=effects, **kw)
    path = tmp / f"case_{seed}_{profile}.mcap"
    write_rig_bag(simulate(config, opts), opts, path)
    return calibrate(load_samples([path], config), config)


def fmt_truth(effects) -> str:
    return "; ".join((f"{e.name} " + ", ".join(f"{k}={v:.3g}" for k, v in e.params.items()
                                             if k not in ("theta_ref", "scale"))).strip() for e in effects) or "none"


def fmt_found(res) -> str:
    parts = [f"{e.name} " + ", ".join(f"{k}={v:.3g}" for k, v in e.params.items()
                                         if k != "theta_ref") for e in res.effects]
    parts += [f"the other reading: {' + '.join(e for e in a.effects if e not in a.taken.split(' + '))}"
              if a.taken else f"cannot tell apart {' / '.join(a.effects)}" for a in res.ambiguous]
    return "; ".join(parts) or "—"


def main() -> None:
    tmp = Path(tempfile.mkdtemp())
    print("| simulated (undeclared) | profile | verdict | found | held-out RMSE before → after [N·m] | reduction |")
    print("|---|---|---|---|---|---|")
    rows = []
    for names in CASES:
        seed = sum(map(ord, "+".join(names)))
        rng = np.random.default_rng(seed)
        effects = [draw_effect(n, rng) for n in names]
        profile = "warmup" if "viscosity_temperature" in names else "bidirectional_map"
        rows.append((effects, profile, run(tmp, effects, profile, seed)))
    for eff in ("drag_constant:c=0.08", "torque_offset:b=0.08"):
        e = [DeclaredEffect.parse(eff)]
        rows.append((e, "rig_map (forward only)", run(tmp, e, "rig_map", 5)))
    rows.append(([], "bidirectional_map, AR(1) 0.9 noise, 10 ms lag", run(tmp, [], "bidirectional_map", 77,
                                                                          noise_ar1=0.9, output_lag_s=0.01)))
    # real oils' viscosity laws (ASTM D341 through their data-sheet ν40, ν100: not the Vogel law fitted)
    if OILS.exists():
        for product in ("Mobilgear 600 XP 220", "Mobil SHC 630", "Shell Omala S4 WE 220"):
            nu = datasheet_oil(product)
            label = [DeclaredEffect("viscosity_temperature", {})]
            label[0].name = f"{product}: ν40={nu[0]:g}, ν100={nu[1]:g} mm²/s"
            rows.append((label, "warmup", run(tmp, [], "warmup", 11, oil_nu40_nu100_mm2_s=nu)))
    for effects, profile, res in rows:
        b, a = res.error_before.rmse_nm, res.error_after.rmse_nm
        print(f"| {fmt_truth(effects)} | {profile} | {res.verdict} | {fmt_found(res)} | {b:.4f} → {a:.4f} | "
              f"{100 * (1 - a / b):.0f} % |")


if __name__ == "__main__":
    main()
