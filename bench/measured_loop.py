#!/usr/bin/env python3
"""``calibrate`` on data as measured data come, as Markdown tables.

1. The EMPS benchmark (a measured ball-screw drive with a published identification): for each way a
   user would run it -- the shared parameter file with the default settings, the torque
   reading's offset taken (``--assume torque_offset``), the published model written as effects
   as the starting file -- the written file scored by ``../shared/realdata/emps/scripts/
   score_calibration.py`` (the relative force error of the decimated force on the estimation run and
   on the PULSES cross-test run), the published figures beside (skipped without the shared data).
   The default takes the friction that differs by direction where the data tell it from the offset;
   the second row takes the offset as the user would with ``--assume torque_offset``.
2. The rigs of ``test/rigs.py`` (simulated from formulas of their own, written as a DAQ's CSV): a
   slow joint, a lagging output-torque channel, a drag appearing half-way, viscous friction that
   differs by direction, friction only under back-driving -- what was put in, what was found.

Usage: ``python bench/measured_loop.py [--shared DIR]``
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
    if (emps / "scripts" / "score_calibration.py").exists():
        emps_table(emps)
    else:
        print(f"no EMPS benchmark at {emps}: skipped")
    rigs_table()
    return 0


def emps_table(emps: Path) -> None:
    conv = emps / "converted"
    runs = [("default settings, the shared parameter file", ["--params", str(conv / "params.yaml")]),
            ("the same, the torque reading's offset taken (--assume torque_offset)",
             ["--params", str(conv / "params.yaml"), "--assume", "torque_offset"]),
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


def rigs_table() -> None:
    sys.path.insert(0, str(ROOT / "test"))
    from rigs import Joint, Rig, loaded_rig, params, slow_joint

    cases = [
        ("slow joint, ±0.01…0.1 rad/s, encoder noise 1e-4 rad/s, spin test", "Coulomb 0.5 N·m, viscous 2 N·m·s, "
         "offset 0.05 N·m", lambda tmp: slow_joint(tmp, Joint())),
        ("loaded rig 100 Hz, output torque 30 ms late", "drag 0.2 N·m, viscous 0.002 N·m·s",
         lambda tmp: loaded_rig(tmp, Rig(drag_nm=0.2, output_lag_s=0.03))[:2]),
        ("loaded rig, a drag appears at 70 s", "drag 0 → 0.15 N·m, viscous 0.002 N·m·s",
         lambda tmp: loaded_rig(tmp, Rig(drag_nm=0.15, step_at_s=70.0))[:2]),
        ("loaded rig, viscous friction differs by direction", "drag 0.1, viscous 0.0015 forward / 0.0025 reverse",
         lambda tmp: loaded_rig(tmp, Rig(drag_nm=0.1, viscous_nm_s=0.0015, viscous_reverse_nm_s=0.0025))[:2]),
        ("loaded rig, friction only under back-driving", "drag 0.1, 0.004·\\|T_load\\| while the output drives",
         lambda tmp: loaded_rig(tmp, Rig(drag_nm=0.1, viscous_nm_s=0.0, backdrive_share=0.004))[:2]),
    ]
    print()
    print("| rig (test/rigs.py) | put in | found | rig's nuisances, changes, readings | held-out RMSE [N·m] |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="rollergear_rigs_") as tmp:
        for k, (label, truth, make) in enumerate(cases):
            work = Path(tmp) / str(k)
            work.mkdir()
            csv, cmap = make(work)
            p = params(work / "p.yaml")
            proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "calibrate", str(csv), "--channels",
                                   str(cmap), "--params", str(p), "--json"], capture_output=True, text=True)
            r = json.loads(proc.stdout)
            found = "; ".join(f"`{e['name']}` " + ", ".join(f"{q} = {v:.4g}" for q, v in e["params"].items())
                              for e in r["effects"])
            said = [f"{x['channel']} lag {1e3 * x['lag_s']:.1f} ms" for x in r["nuisances"]["lags"] if x["applied"]]
            said += [f"change at {c['t_s']:.1f} s" for c in r["changes"]]
            said += [f"readings {' / '.join(a['effects'])}, taken {a['taken']}" for a in r["ambiguous"] if a["taken"]]
            said += [f"speed noise {r['nuisances']['speed_noise'].split(' (')[0]}"] if "joint" in label else []
            print(f"| {label} | {truth} | {found} | {'; '.join(said) or '—'} | "
                  f"{r['error_before']['rmse_nm']:.4g} → {r['error_after']['rmse_nm']:.4g} |")


if __name__ == "__main__":
    sys.exit(main())
