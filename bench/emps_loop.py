#!/usr/bin/env python3
"""The EMPS benchmark (a measured ball-screw drive with a published identification) through
``calibrate``, each written file scored by the benchmark's own figure, as Markdown table rows.

For each way a user would run it -- the shared parameter file with the default settings, the
friction that differs by direction taken (``--assume drag_direction``), the published model written
as effects as the starting file -- the written file is scored by ``../shared/realdata/emps/scripts/
score_calibration.py`` (the relative force error of the decimated force on the estimation run and on
the PULSES cross-test run); the published figures are printed beside.  Usage:
``python bench/emps_loop.py [--shared DIR]`` (skips without the shared data).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PUBLISHED = [("published IDIM-LS, symmetric (Fc, Fv, offset)", 4.08, 5.98),
             ("published IDIM-LS, asymmetric (Fc±, Fv±)", 3.11, 5.40)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("ROLLERGEAR_SHARED", ROOT.parent / "shared")))
    args = ap.parse_args()
    emps = args.shared / "realdata" / "emps"
    if not (emps / "scripts" / "score_calibration.py").exists():
        print(f"no EMPS benchmark at {emps}: skipped")
        return 0
    conv = emps / "converted"
    runs = [("default settings, the shared parameter file", ["--params", str(conv / "params.yaml")]),
            ("the same, friction that differs by direction taken", ["--params", str(conv / "params.yaml"),
                                                                     "--assume", "drag_direction"]),
            ("from the published model written as effects", ["--params", str(conv / "params_published_idim.yaml")])]
    print("| run | effects written | held-out RMSE [N] before → after | direct [%] | cross-test [%] |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="rollergear_emps_") as tmp:
        tmp = Path(tmp)
        rg = tmp / "rg"
        rg.write_text(f"#!/bin/sh\nexec {sys.executable} -m rollergear_ros \"$@\"\n")
        rg.chmod(0o755)
        for k, (label, extra) in enumerate(runs):
            out, js = tmp / f"cal{k}.yaml", tmp / f"cal{k}.json"
            proc = subprocess.run([str(rg), "calibrate", str(conv / "emps_train.csv"), "--channels",
                                   str(conv / "map_spin.yaml"), *extra, "--out", str(out), "--json"],
                                  capture_output=True, text=True)
            js.write_text(proc.stdout)
            result = json.loads(proc.stdout)
            if not result["written"]:
                print(f"| {label} | not written: {result['notes'][-1]} | | | |")
                continue
            work = tmp / f"work{k}"
            work.mkdir()
            score = json.loads(subprocess.run([sys.executable, str(emps / "scripts" / "score_calibration.py"), str(rg),
                                               str(work), str(out), str(js)], capture_output=True, text=True,
                                              check=True).stdout)
            effects = "; ".join(f"`{e['name']}` " + ", ".join(f"{p} = {v:.4g}" for p, v in e["params"].items())
                                for e in result["effects"])
            eb, ea = result["error_before"]["rmse_nm"], result["error_after"]["rmse_nm"]
            print(f"| {label} | {effects} | {eb:.4g} → {ea:.4g} | {score['direct']:.2f} | {score['cross']:.2f} |")
    for label, direct, cross in PUBLISHED:
        print(f"| {label} | (EMPS_Description.pdf) | | {direct:.2f} | {cross:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
