"""The calibration report: Markdown with the before/after table, the accepted effects and PNG plots."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .blocks import MIN_TEMPERATURE_SPAN_C

if TYPE_CHECKING:
    from .calibrate import CalibrationResult
    from .samples import SampleData


def write_report(result: CalibrationResult, data: SampleData, out_dir: Path, sources: Sequence[str]) -> Path:
    """Markdown report with PNG plots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    b = result.blocks
    assert b is not None and result.pred_after is not None
    before = b.y
    after = b.y - result.pred_after
    plots = []
    for key, x, label in (
        ("speed", b.speed, "drive speed [rad/s]"),
        ("torque", b.torque, "drive torque [N·m]"),
        ("temperature", b.temperature, "oil temperature [°C]"),
    ):
        if not np.isfinite(x).any():
            continue
        fig, ax = plt.subplots(1, 2, figsize=(11, 4), dpi=100, sharey=True)
        ax[0].scatter(x, before, s=4, alpha=0.5)
        ax[0].set_title("before: measured − model")
        ax[1].scatter(x, after, s=4, alpha=0.5, color="tab:green")
        ax[1].set_title("after: measured − (model + accepted effects)")
        for a in ax:
            a.axhline(0, color="k", lw=0.5)
            a.set_xlabel(label)
            a.grid(alpha=0.3)
        ax[0].set_ylabel(f"residual, {b.block_s:g} s block means [N·m]")
        fig.tight_layout()
        p = out_dir / f"residual_vs_{key}.png"
        fig.savefig(p)
        plt.close(fig)
        plots.append(p)
    fig, ax = plt.subplots(figsize=(6, 5), dpi=100)
    model_mean = b.measured - b.y
    ax.scatter(b.measured, model_mean, s=4, alpha=0.5, label="model")
    ax.scatter(b.measured, model_mean + result.pred_after, s=4, alpha=0.5, label="model + accepted effects")
    lim = [float(np.min(b.measured)), float(np.max(b.measured))]
    ax.plot(lim, lim, "k--", lw=0.8)
    ax.set_xlabel("measured loss [N·m]")
    ax.set_ylabel("estimated loss [N·m]")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    p = out_dir / "measured_vs_estimated.png"
    fig.savefig(p)
    plt.close(fig)
    plots.append(p)

    eb, ea = result.error_before, result.error_after
    lines = [
        "# Calibration report\n",
        f"{'Tables' if b.steady_state else 'Recordings'}: {', '.join(map(str, sources))}  ",
        (f"Rows used: {result.samples:,} (steady-state operating points)  " if b.steady_state else
         f"Samples used: {result.samples:,} (|ω| ≥ 2 rad/s, measured output torque present)  "),
        f"Verdict: **{result.verdict.replace('_', ' ')}**  ",
        f"Practical minimum effect size δ = {result.delta_nm:.4g} N·m (RMS contribution); "
        f"RMS measured loss {np.sqrt(np.average(b.measured**2, weights=b.count)):.4g} N·m\n",
        "## Error on held-out data\n",
        result.holdout + ".\n",
        "| | RMSE [N·m] | MAE [N·m] | max \\|error\\| [N·m] | RMSE / RMS measured loss |",
        "|---|---|---|---|---|",
        *(f"| {label} | {e.rmse_nm:.4g} | {e.mae_nm:.4g} | {e.max_abs_nm:.4g} | {e.rel_rmse_pct:.2f} % |"
          for label, e in (("before (model)", eb), ("after (model + accepted effects)", ea))),
        f"\nReduction of held-out RMSE: {100 * (1 - ea.rmse_nm / eb.rmse_nm) if eb.rmse_nm else 0:.1f} %. "
        f"Per sample (sensor noise included): RMSE {result.sample_level['before'].rmse_nm:.4g} → "
        f"{result.sample_level['after'].rmse_nm:.4g} N·m.\n",
        *([f"**Model adequacy:** {result.adequacy.statement}.\n"] if result.adequacy else []),
        "## Accepted effects\n",
    ]
    if result.effects:
        lines += ["| effect | parameters | 95 % intervals | RMS contribution [N·m] (95 %) |", "|---|---|---|---|"]
        for e in result.effects:
            pr = ", ".join(f"{k} = {v:.4g}" for k, v in e.params.items())
            ci = ", ".join(f"{k} ∈ [{lo:.4g}, {hi:.4g}]" for k, (lo, hi) in e.ci95.items())
            lo, hi = e.rms_contribution_ci95_nm
            lines.append(f"| {e.name} | {pr} | {ci} | {e.rms_contribution_nm:.4g} ({lo:.4g}–{hi:.4g}) |")
    else:
        lines.append("None.")
    if result.ambiguous:
        lines.append("\n## Effects the data cannot tell apart\n")
        for a in result.ambiguous:
            lo, hi = a.rms_contribution_nm
            lines.append(
                f"- {' / '.join(a.effects)}: an effect of RMS {lo:.3g}–{hi:.3g} N·m is there, but these "
                f"columns are the same on this data. To separate them record {a.needs}."
            )
    lines.append("\n## Groups not accepted (upper 95 % bound of their RMS contribution)\n")
    for r in result.rejected:
        lines.append(
            f"- {r.name}: ≤ {r.upper_rms_nm:.3g} N·m"
            + (" (ambiguous, see above)" if r.ambiguous else "")
            + (f" — {r.reason}" if r.reason else "")
        )
    for u in result.unavailable:
        lines.append(
            f"- {u}: not testable on this data (needs an oil temperature that varies by "
            f"≥ {MIN_TEMPERATURE_SPAN_C:g} °C)"
        )
    lines.append("\n## Selection log\n")
    lines += [f"- {entry}" for entry in result.log]
    lines.append("\n## Plots\n")
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    lines.append("\nMethod: see the docstring of `rollergear_ros/calibrate.py` and docs/closing-the-loop.md.")
    report = out_dir / "report.md"
    report.write_text("\n".join(lines) + "\n")
    (out_dir / "result.json").write_text(json.dumps(result.to_json(), indent=1))
    return report
