#!/usr/bin/env python3
"""The loop on data this package did not make: ``shared/realdata`` (see each PROVENANCE.md).

For every VECTO generic loss map (``.vtlm``) and each gear of NREL ADVISOR's VW transaxle map
(a regression of measured efficiencies, SAE 820741), ``calibrate`` runs twice: with the paper's
ball-track model switched off (``estimator.paper_model: false``) and with it on.  Prints one
Markdown table row per case (found effects, held-out RMSE before -> after, adequacy).  The
package's own gearbox parameters do not describe these gearboxes -- the situation of a user whose
gearbox the paper's model is only part of.

Usage: python bench/realdata_loop.py [SHARED_DIR]   (default: ../shared beside the project)
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from rollergear_ros.calibration.calibrate import calibrate
from rollergear_ros.sources.channelmap import load_channel_map
from rollergear_ros.core.params import load_config
from rollergear_ros.calibration.samples import table_samples

ROOT = Path(__file__).resolve().parent.parent
ADVISOR_MAP = """format: steady_state
motor_torque: {column: input_torque_nm, unit: N*m}
motor_speed: {column: input_speed_rad_s, unit: rad/s}
output_torque: {column: output_torque_Nm, unit: N*m}
output_speed: {column: output_speed_rad_s, unit: rad/s}
"""


def advisor_tables(csv_path: Path, out_dir: Path) -> list[tuple[str, Path]]:
    """ADVISOR's output-side cells per gear as input-side tables (PROVENANCE.md's feed rule):
    ``ω_in = ω_out·ratio``; ``T_in = T_out/(ratio·η)`` driving, ``T_out·η/ratio`` overrunning."""
    data = np.genfromtxt(csv_path, delimiter=",", names=True)
    tables = []
    for gear in np.unique(data["gear"]):
        d = data[(data["gear"] == gear) & (data["efficiency"] > 0) & (data["output_speed_rad_s"] > 0)
                 & (data["output_torque_Nm"] != 0)]
        ratio, eta, t_out = d["overall_ratio"], d["efficiency"], d["output_torque_Nm"]
        t_in = np.where(t_out > 0, t_out / (ratio * eta), t_out * eta / ratio)
        path = out_dir / f"advisor_vw_gear{int(gear)}.csv"
        header = "input_torque_nm,input_speed_rad_s,output_torque_Nm,output_speed_rad_s"
        np.savetxt(path, np.column_stack([t_in, d["output_speed_rad_s"] * ratio, t_out, d["output_speed_rad_s"]]),
                   delimiter=",", header=header, comments="", fmt="%.10g")
        tables.append((f"ADVISOR VW transaxle, gear {int(gear)} (ratio {ratio[0]:g})", path))
    return tables


def params(tmp: Path, paper_model: bool) -> Path:
    p = tmp / f"params_{paper_model}.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    estimator: "
                 f"{{paper_model: {str(paper_model).lower()}, max_abs_torque_nm: 100000.0}}\n")
    return p


def row(label: str, path: Path, tmp: Path, cmap) -> list[str]:
    rows = []
    for paper_model in (False, True):
        config = load_config(params(tmp, paper_model))
        data = table_samples([path], config, cmap=cmap)
        res = calibrate(data, config)
        found = "; ".join(f"`{e.name}` " + ", ".join(f"{k} = {v:.4g}" for k, v in e.params.items()
                                                    if k in ("c", "p", "q")) for e in res.effects) or "—"
        found += "".join(f"; `{p.name.split('.')[1]}` {p.file:.3g} → {p.fitted:.3g}" for p in res.parameters)
        model = "off" if not paper_model else ("on → **off**" if not res.config.estimator.paper_model else "on")
        rows.append(f"| {label} | {model} | {len(data.t_ns)} | {res.verdict}{'' if res.written else ', not written'} | "
                    f"{found} | {res.error_before.rmse_nm:.3g} → {res.error_after.rmse_nm:.3g} "
                    f"({res.error_after.rel_rmse_pct:.2f} %) | {res.adequacy.statement} |")
    return rows


def main() -> int:
    shared = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared"
    real = shared / "realdata"
    print("| data | paper's model | rows | verdict | found (effects; model parameters file → fitted) | held-out RMSE "
          "[N·m] before → after (% of loss) | adequacy |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        for path in sorted((real / "vecto_generic_lossmaps").rglob("*.vtlm")):
            label = f"VECTO {path.parent.name.replace('_', ' ')}: {path.stem}"
            print("\n".join(row(label, path, tmp, None)), flush=True)
        (tmp / "advisor.yaml").write_text(ADVISOR_MAP)
        cmap = load_channel_map(tmp / "advisor.yaml")
        for label, path in advisor_tables(real / "advisor_vw_transaxle_effmap" / "tx_vw_eff_map_26_50_5_long.csv",
                                          tmp):
            print("\n".join(row(label, path, tmp, cmap)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
