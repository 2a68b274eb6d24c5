"""``rollergear model``: the loss model at torque and speed points, as a table or JSON."""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from ..base.errors import InputFileError, UsageError
from ..sources.paths import check_input_file
from .args import add_params_option, config_from_args, finite_float, oil_temperature_c

EXAMPLE = "rollergear model --torque 1 10 50 --speed 104.72 --params calibrated.yaml"


# ---------------------------------------------------------------------------------- model
def cmd_model(args: argparse.Namespace) -> int:
    from ..core.model import BREAKDOWN_KEYS
    from ..core.operating_points import evaluate_points, locked_points

    config = config_from_args(args)
    if args.csv:
        check_input_file("--csv", args.csv)
        torque, speed = _read_points_csv(Path(args.csv))
    else:
        if not args.torque or not args.speed:
            raise UsageError("give --torque and --speed values, or --csv FILE")
        tt, ww = np.meshgrid(np.asarray(args.torque, float), np.asarray(args.speed, float), indexing="ij")
        torque, speed = tt.ravel(), ww.ravel()
    res = evaluate_points(config, torque, speed, args.oil_temperature_c)

    def number(v: float) -> float | None:
        return None if math.isnan(v) else float(v)

    points = []
    for i in range(len(torque)):
        points.append({
            "torque_nm": float(torque[i]), "speed_rad_s": float(speed[i]),
            "loss_torque_nm": number(res.loss_torque_nm[i]), "loss_power_w": number(res.loss_power_w[i]),
            "efficiency": number(res.efficiency[i]),
            "breakdown_nm": {k: number(res.breakdown_nm[k][i]) for k in BREAKDOWN_KEYS},
            "model_nm": number(res.model_nm[i]),
            "effects_nm": {k: number(v[i]) for k, v in res.effects_nm.items()},
        })
    if args.json:
        json.dump({"points": points, "effects": list(res.effects_nm), "oil_temperature_c": args.oil_temperature_c,
                   "skipped": res.skipped}, sys.stdout, indent=1)
        sys.stdout.write("\n")
        return 0
    head = (f"{'T [N·m]':>10} {'ω [rad/s]':>10} {'T_loss [N·m]':>13} {'P_loss [W]':>11} {'η [%]':>8} "
            f"{'model [%]':>9}  dominant term")
    print(head)
    print("-" * len(head))
    locked = locked_points(config, res)
    for p, lock in zip(points, locked.tolist()):
        if p["loss_torque_nm"] is None:
            why = ("the file's laws in the load lock the drive here (back-driven, no output-side load balances "
                   "it: load_unbalanced)" if lock else
                   "outside the estimator's plausible range (estimator.max_abs_*)")
            print(f"{p['torque_nm']:>10.4g} {p['speed_rad_s']:>10.4g}  skipped: {why}")
            continue
        terms = {**p["breakdown_nm"], **p["effects_nm"]}
        dom = max(terms, key=lambda k: abs(terms[k]))
        total = abs(p["loss_torque_nm"])
        share = 100.0 * terms[dom] / max(total, 1e-300)
        model_share = 100.0 * p["model_nm"] / max(total, 1e-300)
        eta = "n/a" if p["efficiency"] is None else f"{100 * p['efficiency']:.3f}"
        print(f"{p['torque_nm']:>10.4g} {p['speed_rad_s']:>10.4g} {p['loss_torque_nm']:>13.5f} "
              f"{p['loss_power_w']:>11.4f} {eta:>8} {model_share:>9.1f}  {dom} ({share:.0f} %)")
    if res.effects_nm:
        print(f"accepted effects of the parameter file: {', '.join(res.effects_nm)} "
              "(model [%]: the paper's model's share of the loss)")
    noise = config.estimator.speed_noise_rad_s
    print("the loss's sign near standstill: " + (
        f"tanh(ω/{noise:g} rad/s), the file's speed noise" if isinstance(noise, float) and noise > 0 else
        "the plain sign of each point's speed (estimator.speed_noise_rad_s: auto is not learned from points)"))
    return 0


def _read_points_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """CSV with a header naming a torque column (``torque``/``torque_nm``/``T``) and a speed column."""
    if not path.exists():
        raise InputFileError(f"{path} does not exist")
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise InputFileError(f"{path} has no data rows")
    cols = {c.strip().lower(): c for c in rows[0]}
    tcol = next((cols[c] for c in ("torque_nm", "torque", "t") if c in cols), None)
    wcol = next((cols[c] for c in ("speed_rad_s", "speed", "omega", "w") if c in cols), None)
    if tcol is None or wcol is None:
        raise InputFileError(f"{path}: need columns torque_nm and speed_rad_s (found {', '.join(rows[0])})")
    try:
        t = np.array([float(r[tcol]) for r in rows])
        w = np.array([float(r[wcol]) for r in rows])
    except ValueError as exc:
        raise InputFileError(f"{path}: {exc}") from None
    bad = ~(np.isfinite(t) & np.isfinite(w))
    if bad.any():
        raise InputFileError(f"{path}: row(s) {', '.join(str(i + 2) for i in np.flatnonzero(bad)[:10])} are not finite")
    return t, w


def register(sub) -> None:
    p = add_params_option(sub.add_parser("model", help="evaluate the loss model at torque/speed points"))
    p.add_argument("--torque", type=finite_float, nargs="+", metavar="NM", help="drive torques [N·m] (signed)")
    p.add_argument("--speed", type=finite_float, nargs="+", metavar="RAD_S", help="drive speeds [rad/s] (signed)")
    p.add_argument("--csv", metavar="FILE", help="CSV with torque_nm, speed_rad_s columns")
    p.add_argument("--oil-temperature-c", type=oil_temperature_c, metavar="DEGC",
                   help="oil temperature, for an accepted effect that needs it (viscosity_temperature)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_model)
