"""The paper's sensitivity study (Figs. 6–11) as PNG and CSV (the loss map: :mod:`outputs.lossmap`).

Pure numpy/matplotlib over :class:`~core.model.LossModel`; no rclpy.
"""

from __future__ import annotations

import csv
import io
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..base.atomic import save_figure, write_text
from ..base.interface import RPM_PER_RAD_S
from ..core.model import LossModel
from ..core.params import Config, GearboxParams, validate

SPEED_1000_RPM = 1000.0 / RPM_PER_RAD_S  # rad/s


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def sensitivity_curves(config: Config, torque_nm: np.ndarray | None = None) -> dict[str, dict[str, np.ndarray]]:
    """Efficiency/loss curves of Figs. 6–11 at 1000 rpm, T = 0…100 N·m.

    Returns ``{study: {label: efficiency array}}`` plus ``"torque"`` and ``"loss_fig7"``.
    Variants keep every other parameter; the track-radius study keeps ``dm2/dm1``.
    """
    t = np.linspace(0.0, 100.0, 1001) if torque_nm is None else np.asarray(torque_nm, float)
    w = np.full_like(t, SPEED_1000_RPM)
    g = config.gearbox
    est = config.estimator

    def eta(p: GearboxParams) -> np.ndarray:
        validate({**config.to_flat(), **{f"gearbox.{k}": v for k, v in p.__dict__.items()}})
        return LossModel(p, est.min_torque_for_efficiency_nm, 0.0).evaluate(t, w, breakdown=False).efficiency

    base = LossModel(g, est.min_torque_for_efficiency_nm, 0.0).evaluate(t, w, breakdown=False)
    out: dict[str, dict[str, np.ndarray]] = {
        "torque": {"T": t},
        "fig6": {"default": base.efficiency},
        "fig7": {"default": base.loss_magnitude_nm},
        "fig8": {f"dw = {d:g} mm": eta(replace(g, dw_m=d * 1e-3)) for d in (1, 3, 6, 9)},
        "fig9": {f"r = {r:g} mm": eta(replace(g, dm1_m=2 * r * 1e-3, dm2_m=2 * r * 1e-3 * g.dm2_m / g.dm1_m))
                 for r in (10, 50, 100, 150)},
        "fig10": {f"eta0 = {v:g} Pa s": eta(replace(g, eta0_pa_s=v)) for v in (0.1, 0.3, 0.6, 1.0)},
    }
    out["fig11"] = out["fig10"]
    return out


_TITLES = {
    "fig6": "Fig. 6 – efficiency vs drive torque (1000 rpm)",
    "fig7": "Fig. 7 – friction (loss) torque vs drive torque (1000 rpm)",
    "fig8": "Fig. 8 – ball diameter d_w",
    "fig9": "Fig. 9 – track radius d_m1/2 (d_m2/d_m1 kept)",
    "fig10": "Fig. 10 – oil viscosity eta0",
    "fig11": "Fig. 11 – oil viscosity eta0 (zoom)",
}


def write_figures(config: Config, out_dir: Path) -> list[Path]:
    """Write ``fig06.png`` … ``fig11.png`` and ``figures.csv`` (the plotted numbers) to ``out_dir``."""
    plt = _plt()
    out_dir.mkdir(parents=True, exist_ok=True)
    curves = sensitivity_curves(config)
    t = curves["torque"]["T"]
    paths: list[Path] = []
    for key in ("fig6", "fig7", "fig8", "fig9", "fig10", "fig11"):
        fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
        for label, y in curves[key].items():
            ax.plot(t, y if key == "fig7" else 100.0 * y, label=label)
        ax.set_xlabel("drive motor torque T [N·m]")
        ax.set_ylabel("loss torque [N·m]" if key == "fig7" else "efficiency [%]")
        ax.set_title(_TITLES[key])
        if key == "fig11":
            lo = min(np.nanmin(100 * y[t >= 20]) for y in curves[key].values())
            hi = max(np.nanmax(100 * y[t >= 20]) for y in curves[key].values())
            ax.set_xlim(20, 100)
            ax.set_ylim(lo - 0.02, hi + 0.02)
        ax.grid(True, alpha=0.3)
        if len(curves[key]) > 1:
            ax.legend()
        fig.tight_layout()
        path = out_dir / f"fig{int(key[3:]):02d}.png"
        try:
            save_figure(fig, path)
        finally:
            plt.close(fig)
        paths.append(path)
    csv_path = out_dir / "figures.csv"
    buf = io.StringIO(newline="")
    wr = csv.writer(buf)
    cols = [(k, lab) for k in ("fig6", "fig7", "fig8", "fig9", "fig10") for lab in curves[k]]
    wr.writerow(["torque_nm"] + [f"{k}:{lab}" for k, lab in cols])
    for i in range(len(t)):
        wr.writerow([f"{t[i]:.6g}"] + [f"{curves[k][lab][i]:.8g}" for k, lab in cols])
    write_text(csv_path, buf.getvalue())
    paths.append(csv_path)
    return paths
