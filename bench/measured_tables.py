#!/usr/bin/env python3
"""Every measured data set of ``../shared/realdata``, fed as a user feeds it, judged where it was not fitted.

* The three TRO2021 screw drives (a lead screw, an antibacklash lead screw, a 60:1 worm; the worm also with
  its payload given as the output torque): the steady runs exported as one CSV in recording order, every
  other speed level fitted (``calibrate`` with the default settings), the written file replayed on the
  levels between (``test/measured.py``).  Per set: the static map's error at the held-out runs -- each run's
  mean error, RMS over them -- of the written file beside no model and the least-squares lines through the
  fitted runs' means (Coulomb + viscous, and + offset); the worst held-out run; the held-out rows estimated.
  The published model is the authors' MATLAB identification (``id_1dof_static.m``), not run here: its
  PROVENANCE states about 0.10 mN·m for the worm.
* EMPS (a ball-screw drive with a published identification): calibrated on its estimation run, scored by
  the benchmark's own cross-test figure on the PULSES run (another trajectory) beside no model, the
  least-squares lines fitted on the estimation run and the published IDIM-LS model.

``--groups`` prints every held-out operating point of each set.  The suite's guard is
``test/calibration/test_testplans.py``.  Usage: ``python bench/measured_tables.py [--shared DIR] [--groups]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test"))


def tro_table(tmp: Path, groups: bool) -> None:
    from measured import judge, tro_set

    print("| set (one CSV, runs in recording order) | effects written | held-out static map [mN·m]: file / "
          "no model / least squares Coulomb + viscous / + offset | worst held-out run | held-out rows "
          "estimated (with a measured loss) | hand fit |")
    print("|---|---|---|---|---|---|")
    details = []
    for drive, payload in (("driveNo1", False), ("driveNo2", False), ("driveNo3", False), ("driveNo3", True)):
        s = tro_set(tmp, drive, payload)
        j = judge(s, tmp)
        refs = j.references
        speed, error = j.worst()
        hand = j.result.get("hand_fit") or {}
        estimated, rows = j.estimated
        print(f"| {s.name} | {_effects(j.result)} | {1e3 * j.file_rms:.3f} / {1e3 * j.given_rms:.3f} / "
              f"{1e3 * refs['least squares Coulomb + viscous']:.3f} / {1e3 * refs['least squares + offset']:.3f} | "
              f"{speed * 30 / np.pi:+.0f} rpm: {1e3 * error:+.3f} | {j.loss_estimated:,} of {rows:,} "
              f"({estimated:,}) | "
              f"{'written' if hand.get('written') else 'weighed, not written'} |", flush=True)
        details.append((s.name, j))
    if groups:
        for name, j in details:
            print(f"\n{name}: each held-out run (speed [rpm], mean error [mN·m], rows with a measured loss)")
            for speed, error, estimated, rows, _loss in j.run_errors:
                print(f"  {speed * 30 / np.pi:+8.1f}  {1e3 * error:+.4f}  {estimated}/{rows}")


def emps_table(emps: Path, tmp: Path) -> None:
    conv = emps / "converted"
    rg = tmp / "rg"
    rg.write_text(f"#!/bin/sh\nexec {sys.executable} -m rollergear_ros \"$@\"\n")
    rg.chmod(0o755)
    written, js = tmp / "emps.yaml", tmp / "emps.json"
    proc = subprocess.run([str(rg), "calibrate", str(conv / "emps_train.csv"), "--channels",
                           str(conv / "map_spin.yaml"), "--params", str(conv / "params.yaml"), "--out", str(written),
                           "--json"],
                          capture_output=True, text=True)
    js.write_text(proc.stdout)
    result = json.loads(proc.stdout)
    rows = [("written file", written, js), ("no model (the parameter file given)", conv / "params.yaml", None)]
    for label, offset in (("least squares Coulomb + viscous", False), ("least squares + offset", True)):
        rows.append((label, _emps_line(conv, tmp, offset), None))
    rows.append(("published IDIM-LS (Fc, Fv, offset)", conv / "params_published_idim.yaml", None))
    print("\n| EMPS (estimation run fitted) | cross-test run [%] (the benchmark's figure) | direct [%] |")
    print("|---|---|---|")
    for label, params, result_json in rows:
        work = tmp / label.split()[0]
        work.mkdir(exist_ok=True)
        if result_json is None:
            result_json = tmp / f"{work.name}.json"
            result_json.write_text(json.dumps({"effects": _file_effects(params)}))
        scored = subprocess.run([sys.executable, str(emps / "scripts" / "score_calibration.py"), str(rg), str(work),
                                 str(params), str(result_json)], capture_output=True, text=True)
        figures = json.loads(scored.stdout) if scored.returncode == 0 else {"cross": None, "direct": None}
        text = label + (f" ({_effects(result)})" if result_json == js else "")
        print(f"| {text} | {_pct(figures.get('cross'))} | {_pct(figures.get('direct'))} |", flush=True)


def _emps_line(conv: Path, tmp: Path, offset: bool) -> Path:
    """The least-squares line through the estimation run's friction force, written as a parameter file."""
    a = np.genfromtxt(conv / "emps_train.csv", delimiter=",", names=True)
    v, f = a["velocity_m_s"], a["friction_force_N"]
    moving = np.abs(v) > 1e-3
    cols = [np.sign(v[moving]), v[moving]] + ([np.ones(int(moving.sum()))] if offset else [])
    coef = [float(c) for c in np.linalg.lstsq(np.column_stack(cols), f[moving], rcond=None)[0]]
    path = tmp / f"emps_line_{offset}.yaml"
    text = (conv / "params.yaml").read_text().replace("adapt: true", "adapt: false")
    text = text.replace("drag_constant: {enabled: false, c_nm: 0.0}",
                        f"drag_constant: {{enabled: true, c_nm: {coef[0]!r}}}")
    text = text.replace("drag_speed: {enabled: false, c: 0.0, p: 1.0}",
                        f"drag_speed: {{enabled: true, c: {coef[1]!r}, p: 1.0}}")
    if offset:
        text = text.replace("torque_offset: {enabled: false, offset_nm: 0.0}",
                            f"torque_offset: {{enabled: true, offset_nm: {coef[2]!r}}}")
    path.write_text(text)
    return path


def _file_effects(params: Path) -> list[dict]:
    """A parameter file's torque offset as ``calibrate --json`` states it (what the score script reads)."""
    sys.path.insert(0, str(ROOT))
    from rollergear_ros.core.params import load_config

    active = load_config(params).effects.active()
    if "torque_offset" not in active:
        return []
    return [{"name": "torque_offset", "params": {"b": active["torque_offset"]["b"]}}]


def _pct(value) -> str:
    return "—" if value is None else f"{value:.2f}"


def _effects(result: dict) -> str:
    return "; ".join(f"`{e['name']}` " + ", ".join(f"{k} = {v:.3g}" for k, v in e["params"].items())
                     for e in result["effects"]) or "none"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("ROLLERGEAR_SHARED", ROOT.parent / "shared")))
    ap.add_argument("--groups", action="store_true", help="print every held-out operating point of each set")
    args = ap.parse_args()
    os.environ["ROLLERGEAR_SHARED"] = str(args.shared)
    real = args.shared / "realdata"
    with tempfile.TemporaryDirectory(prefix="rollergear_measured_") as t:
        tmp = Path(t)
        if (real / "tro2021_screw_drives").exists():
            tro_table(tmp, args.groups)
        else:
            print(f"no TRO2021 screw drives at {real}: skipped")
        if (real / "emps" / "scripts" / "score_calibration.py").exists():
            emps_table(real / "emps", tmp)
        else:
            print(f"no EMPS benchmark at {real}: skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
