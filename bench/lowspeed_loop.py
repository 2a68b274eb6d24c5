#!/usr/bin/env python3
"""The loop near standstill: ``calibrate`` on the joints of test/calibration/test_lowspeed.py, friction computed
there from its own formulas (a Stribeck spin test; the LuGre ODE integrated by scipy), each written
as a CSV with a constant output torque and calibrated through the command line, as a user would.

Prints one Markdown row per case (what was put in, what was found with its 95 % interval, the
held-out error before and after) and, with ``--figures DIR``, copies each case's effect plot there.
Usage: python bench/lowspeed_loop.py [--figures docs/img]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT / "test" / "calibration"), str(ROOT / "test")]
from test_lowspeed import joint_csv, joint_velocity, lugre_friction, spin_test_csv  # noqa: E402


def calibrate(csv: Path, cmap: Path, params: Path, report: Path) -> dict:
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "calibrate", str(csv), "--channels", str(cmap),
                           "--params", str(params), "--json", "--report", str(report)],
                          capture_output=True, text=True, check=False)
    if proc.returncode not in (0, 1):
        raise SystemExit(proc.stderr)
    return json.loads(proc.stdout)


def row(case: str, put: str, result: dict, name: str) -> str:
    found = {e["name"]: e for e in result["effects"]}
    if name in found:
        e = found[name]
        text = ", ".join(f"{k} = {v:.3g} ({e['ci95'][k][0]:.3g}…{e['ci95'][k][1]:.3g})"
                         for k, v in e["params"].items() if k in e["ci95"])
    else:
        text = "not found"
    others = ", ".join(sorted(set(found) - {name})) or "—"
    b, a = result["error_before"]["rmse_nm"], result["error_after"]["rmse_nm"]
    return f"| {case} | {put} | `{name}`: {text} | {others} | {b:.4g} → {a:.4g} ({100 * (1 - a / b):.1f} % cut) |"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--figures", type=Path, help="copy the effects' plots here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="rollergear_lowspeed_") as tmp_name:
        tmp = Path(tmp_name)
        print("| joint | put in (its own formula) | found (95 %) | other effects | held-out RMSE [N·m] |")
        print("|---|---|---|---|---|")
        csv, cmap, params = spin_test_csv(tmp, stribeck=True)
        result = calibrate(csv, cmap, params, tmp / "stribeck")
        print(row("spin test, ±0.08…5 rad/s", "Coulomb 0.30 N·m + Stribeck excess 0.25 N·m at ω_s 0.15 rad/s "
                  "(δ 2) + viscous 0.01 N·m·s", result, "stribeck"))
        t, v = joint_velocity()
        csv, cmap, params = joint_csv(tmp, "lugre", lugre_friction(t, v, 30.0, 0.3, 0.01), t, v)
        result = calibrate(csv, cmap, params, tmp / "dahl")
        print(row("reversals after dwells at rest, ≤ 0.4 rad/s", "LuGre σ0 = 30 N·m/rad, Fc = 0.3 N·m "
                  "(presliding 0.01 rad), σ2 = 0.01 N·m·s", result, "dahl"))
        if args.figures:
            args.figures.mkdir(parents=True, exist_ok=True)
            for name in ("stribeck", "dahl"):
                png = tmp / name / f"effect_{name}.png"
                if png.exists():
                    shutil.copyfile(png, args.figures / png.name)


if __name__ == "__main__":
    main()
