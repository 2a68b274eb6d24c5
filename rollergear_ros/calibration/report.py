"""The calibration report: Markdown with the before/after table, the accepted effects and PNG plots."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..base.atomic import save_figure, write_text
from ..core.effects import EFFECTS

if TYPE_CHECKING:
    from .outcome import CalibrationResult, FoundEffect
    from .samples import SampleData


#: the residual over time is drawn as at most this many points (block means, evenly thinned)
MAX_TIME_POINTS = 20_000
_AXES = {"speed": ("speed", "drive speed [rad/s]"), "torque": ("torque", "drive torque [N·m]"),
         "load": ("load", "output-side load referred to the input [N·m]"),
         "temperature": ("temperature", "oil temperature [°C]"),
         "speed_near_zero": ("speed", "drive speed [rad/s] (symmetric log scale: standstill in the middle)")}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path, plots: list[Path]) -> None:
    fig.tight_layout()
    try:
        save_figure(fig, path)
    finally:
        _pyplot().close(fig)
    plots.append(path)


def _residual_scatter(result: CalibrationResult, out_dir: Path, plots: list[Path]) -> None:
    """Residual before/after over speed, torque and (when the report can test it) oil temperature."""
    plt = _pyplot()
    b = result.blocks
    before, after = b.y, b.y - result.pred_after
    temperature_testable = any(EFFECTS[n].needs_temperature for n in b.testable if n in EFFECTS)
    for key, (attr, label) in _AXES.items():
        if key in ("speed_near_zero", "load"):  # an effect's axis, not an input of its own
            continue
        x = getattr(b, attr)
        if not np.isfinite(x).any() or (key == "temperature" and not temperature_testable):
            continue  # an untestable check gets no plot
        fig, ax = plt.subplots(1, 2, figsize=(11, 4), dpi=100, sharey=True)
        ax[0].scatter(x, before, s=4, alpha=0.5)
        ax[0].set_title("before: measured − model")
        ax[1].scatter(x, after, s=4, alpha=0.5, color="tab:green")
        ax[1].set_title("after: measured − (model + accepted effects)")
        for a in ax:
            a.axhline(0, color="k", lw=0.5)
            a.set_xlabel(label)
            a.grid(alpha=0.3)
        ax[0].set_ylabel(_residual_label(b))
        _save(fig, out_dir / f"residual_vs_{key}.png", plots)


def _residual_label(b) -> str:
    return "residual, table rows [N·m]" if b.steady_state else f"residual, {b.block_s:g} s block means [N·m]"


def effect_band(result: CalibrationResult, effect: FoundEffect) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An accepted effect's fitted contribution per block and its 95 % band: ``(fitted, low, high)`` [N·m].

    ``c·column`` at the fitted member, the band from the coefficient's 95 % interval as the report's
    table states it (from the joint fit with the other effects, widened over the member's range,
    see :func:`.calibrate.calibrate`).
    """
    spec = EFFECTS[effect.name]
    law = tuple(effect.params[k] for k in ("B", "C", "theta_ref")) if spec.oil_law else None
    column = result.blocks.column(effect.name, effect.params.get(spec.member) if spec.member else None,
                                  effect.params.get(spec.second_member) if spec.second_member else None, law)
    c_lo, c_hi = effect.ci95[spec.coefficient]
    a, b_ = c_lo * column, c_hi * column
    return effect.params[spec.coefficient] * column, np.minimum(a, b_), np.maximum(a, b_)


def _effect_curves(result: CalibrationResult, out_dir: Path, plots: list[Path]) -> None:
    """Per accepted effect: its fitted contribution over the variable it depends on, with its 95 %
    band, over the blocks' partial residual (the residual minus the other accepted effects)."""
    plt = _pyplot()
    b = result.blocks
    for effect in result.effects:
        if EFFECTS[effect.name].plotted_against == "angle_since_reversal":
            _memory_curve(result, effect, out_dir, plots)
            continue
        attr, label = _AXES[EFFECTS[effect.name].plotted_against]
        x = getattr(b, attr)
        ok = np.isfinite(x)
        if not ok.any():
            continue
        fitted, lo, hi = effect_band(result, effect)
        partial = b.y - result.pred_after + fitted
        fig, ax = plt.subplots(figsize=(7, 4.5), dpi=100)
        spec = EFFECTS[effect.name]
        if spec.needs_temperature and spec.plotted_against != "temperature" and np.isfinite(b.temperature[ok]).any():
            # a drag that follows the oil: each block coloured by its oil temperature
            dots = ax.scatter(x[ok], partial[ok], s=5, alpha=0.6, c=b.temperature[ok], cmap="coolwarm",
                              label="residual minus the other accepted effects")
            fig.colorbar(dots, ax=ax, label="oil temperature [°C]")
        else:
            ax.scatter(x[ok], partial[ok], s=4, alpha=0.35, color="0.5",
                       label="residual minus the other accepted effects")
        ax.vlines(x[ok], lo[ok], hi[ok], color="tab:red", alpha=0.25, lw=2,
                  label="95 % interval of the coefficient, per block")
        ax.scatter(x[ok], fitted[ok], s=2, color="k" if spec.needs_temperature else "tab:red",
                   label="fitted contribution")
        params = ", ".join(f"{k} = {v:.3g}" for k, v in effect.params.items())
        formula = EFFECTS[effect.name].formula().split(" (")[0].replace("``", "")
        ax.set_title(f"{effect.name}: {formula}\n{params}", fontsize=9)
        ax.set_xlabel(label)
        if spec.plotted_against == "speed_near_zero":
            scale = effect.params.get(spec.member, 0.1) if spec.member else 0.1
            ax.set_xscale("symlog", linthresh=max(scale / 5.0, 1e-4))
        ax.set_ylabel("contribution to the measured loss [N·m]")
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        _save(fig, out_dir / f"effect_{effect.name}.png", plots)


def _memory_curve(result: CalibrationResult, effect: FoundEffect, out_dir: Path, plots: list[Path]) -> None:
    """An effect with memory, per sample: its fitted contribution over the angle turned since the last
    reversal, over the samples' residual minus the other accepted effects (those at their block means:
    they follow speed and torque, which a block barely changes; the memory changes within one)."""
    b = result.blocks
    spec = EFFECTS[effect.name]
    if b.t_s is None or result.after_residual is None:
        return
    phi = b.angle_since_reversal(3.0 * b.sign_width_rad_s)
    scale = effect.params.get(spec.member, 0.01) if spec.member else 0.01
    near = np.isfinite(phi) & (phi > 0) & (phi <= 30.0 * scale)  # the turn after a reversal
    if not near.any():
        return
    states = b.states(effect.name, effect.params)
    fitted = effect.params[spec.coefficient] * spec.column(b.x._replace(state={effect.name: states}), effect.params)
    block_fitted = effect_band(result, effect)[0]
    partial = result.after_residual + np.repeat(block_fitted, b.count)
    keep = np.flatnonzero(near)[:: max(1, int(np.count_nonzero(near)) // MAX_TIME_POINTS)]
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=100)
    ax.scatter(phi[keep], partial[keep], s=4, alpha=0.35, color="0.5",
               label="residual minus the other accepted effects, per sample")
    ax.scatter(phi[keep], fitted[keep], s=2, color="tab:red", label="fitted contribution")
    c_lo, c_hi = effect.ci95[spec.coefficient]
    if spec.member and spec.member in effect.ci95:
        for end in effect.ci95[spec.member]:
            ax.axvline(end, color="tab:red", lw=0.8, ls=":")
        ax.axvline(scale, color="tab:red", lw=0.8, label=f"{spec.member} (dotted: its 95 % interval)")
    params = ", ".join(f"{k} = {v:.3g}" for k, v in effect.params.items())
    ax.set_title(f"{effect.name}: the friction after each reversal (c in [{c_lo:.3g}, {c_hi:.3g}] at 95 %)\n{params}",
                 fontsize=9)
    ax.set_xscale("log")
    ax.set_xlabel("angle turned since the last reversal [rad]")
    ax.set_ylabel("contribution to the measured loss [N·m]")
    ax.axhline(0, color="k", lw=0.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, out_dir / f"effect_{effect.name}.png", plots)


def _residual_over_time(result: CalibrationResult, data: SampleData, out_dir: Path, plots: list[Path]) -> None:
    """Residual before and after over the recordings' time (block means); not for tables (no time)."""
    b = result.blocks
    if b.steady_state:
        return
    plt = _pyplot()
    t0 = data.t_ns[b.start]
    t_s = (t0 - t0.min()) * 1e-9
    keep = np.arange(0, len(t_s), max(1, len(t_s) // MAX_TIME_POINTS))
    fig, ax = plt.subplots(2, 1, figsize=(11, 5), dpi=100, sharex=True, sharey=True)
    ax[0].plot(t_s[keep], b.y[keep], ".", ms=2, alpha=0.6)
    ax[0].set_title("before: measured − model")
    ax[1].plot(t_s[keep], (b.y - result.pred_after)[keep], ".", ms=2, alpha=0.6, color="tab:green")
    ax[1].set_title("after: measured − (model + accepted effects), held-out predictions")
    for a in ax:
        a.axhline(0, color="k", lw=0.5)
        a.set_ylabel("[N·m]")
        a.grid(alpha=0.3)
    ax[1].set_xlabel("time since the first sample [s]" + (" (recordings one after another)"
                                                            if len(np.unique(data.bag_id)) > 1 else ""))
    fig.suptitle(_residual_label(b), fontsize=10)
    _save(fig, out_dir / "residual_over_time.png", plots)


def _residual_structure(result: CalibrationResult, out_dir: Path, plots: list[Path]) -> None:
    """The residual left (held out) against each input, as partial residuals: its block means and
    its mean per quantile bin of speed, torque and oil temperature, and per direction and power
    flow -- the trace to follow when the vocabulary has no answer (:func:`.calibrate.residual_structure`)."""
    if not result.structure or not result.structure["explained_share"]:
        return
    plt = _pyplot()
    b = result.blocks
    r = b.y - result.pred_after
    shares = result.structure["explained_share"]
    inputs = {"speed": (np.abs(b.speed), "|drive speed| [rad/s]"), "torque": (np.abs(b.torque), "|drive torque| [N·m]"),
              "temperature": (b.temperature, "oil temperature [°C]"),
              "direction": (np.sign(b.speed), "direction (−1 reverse, +1 forward)"),
              "power flow": (np.sign(b.speed * b.torque), "power flow (−1 overrun, +1 driving)")}
    names = [n for n in inputs if n in shares]
    fig, axes = plt.subplots(1, len(names), figsize=(3.4 * len(names), 3.6), dpi=100, sharey=True, squeeze=False)
    for ax, name in zip(axes[0], names):
        x, label = inputs[name]
        ok = np.isfinite(x)
        ax.scatter(x[ok], r[ok], s=3, alpha=0.3, color="0.5")
        if name in ("direction", "power flow"):
            keys = np.unique(x[ok])
            means = [np.average(r[ok][x[ok] == k], weights=b.count[ok][x[ok] == k]) for k in keys]
        else:
            edges = np.unique(np.quantile(x[ok], np.linspace(0, 1, 9)))
            label_of = np.digitize(x[ok], edges[1:-1])
            keys = [float(np.mean(x[ok][label_of == k])) for k in np.unique(label_of)]
            means = [np.average(r[ok][label_of == k], weights=b.count[ok][label_of == k]) for k in np.unique(label_of)]
        ax.plot(keys, means, "o-", color="tab:red", label="mean per bin")
        ax.set_title(f"{name}: {100 * shares[name]:.0f} % of the variance", fontsize=9)
        ax.set_xlabel(label)
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("residual left, held out [N·m]")
    axes[0][0].legend(fontsize=8)
    fig.suptitle(result.structure["statement"], fontsize=10)
    _save(fig, out_dir / "residual_structure.png", plots)


def _measured_vs_estimated(result: CalibrationResult, out_dir: Path, plots: list[Path]) -> None:
    plt = _pyplot()
    b = result.blocks
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
    _save(fig, out_dir / "measured_vs_estimated.png", plots)


#: the files :func:`write_report` writes in its folder (glob patterns)
REPORT_FILES = ("report.md", "result.json", "residual_*.png", "effect_*.png", "measured_vs_estimated.png")


def write_report(result: CalibrationResult, data: SampleData, out_dir: Path, sources: Sequence[str]) -> Path:
    """Markdown report with PNG plots: residual before/after over the inputs and over time, each
    accepted effect's curve with its 95 % band, measured against estimated loss."""
    out_dir.mkdir(parents=True, exist_ok=True)
    assert result.blocks is not None and result.pred_after is not None
    plots: list[Path] = []
    _residual_scatter(result, out_dir, plots)
    _residual_over_time(result, data, out_dir, plots)
    _effect_curves(result, out_dir, plots)
    _measured_vs_estimated(result, out_dir, plots)
    _residual_structure(result, out_dir, plots)
    lines = [*_summary_lines(result, sources), *_effect_lines(result), *_not_accepted_lines(result),
             "\n## Selection log\n", *(f"- {entry}" for entry in result.log),
             "\n## Plots\n", *(f"![{p.stem}]({p.name})" for p in plots),
             "\nMethod: see the docstring of `rollergear_ros/calibration/calibrate.py` and "
             "docs/closing-the-loop.md."]
    report = out_dir / "report.md"
    write_text(out_dir / "result.json", json.dumps(result.to_json(), indent=1))
    write_text(report, "\n".join(lines) + "\n")  # last: a report.md is one whose plots are all there
    return report


def _summary_lines(result: CalibrationResult, sources: Sequence[str]) -> list[str]:
    """The report's head: what was used, the verdict, the held-out error, the parameters changed."""
    b = result.blocks
    eb, ea = result.error_before, result.error_after
    before = ("the parameter file as given (" + ", ".join(result.from_file) + ", not refitted)"
              if result.from_file else "the model of the parameter file")
    return [
        "# Calibration report\n",
        f"{'Tables' if b.steady_state else 'Recordings'}: {', '.join(map(str, sources))}  ",
        (f"Rows used: {result.samples:,} (steady-state operating points)  " if b.steady_state else
         f"Samples used: {result.samples:,} (those with a measured loss: output torque present, the direction "
         f"known -- beyond 3 × the speed reading's noise from standstill)  "),
        *([f"Speed reading's noise: {result.speed_noise}  "] if result.speed_noise else []),
        *([f"Fitted: {result.stretch}  "] if result.changes or "window" in result.stretch else []),
        f"Verdict: **{result.verdict.replace('_', ' ')}**  ",
        "Practical minimum effect size (RMS contribution): "
        f"{result.minimum.text if result.minimum else result.delta_nm}; RMS measured loss "
        f"{np.sqrt(np.average(b.measured**2, weights=b.count)):.4g} N·m\n",
        "## Error on held-out data\n",
        result.holdout + ".\n",
        "| | RMSE [N·m] | MAE [N·m] | max \\|error\\| [N·m] | RMSE / RMS measured loss |",
        "|---|---|---|---|---|",
        *(f"| {label} | {e.rmse_nm:.4g} | {e.mae_nm:.4g} | {e.max_abs_nm:.4g} | {e.rel_rmse_pct:.2f} % |"
          for label, e in ((f"before: {before}", eb), ("after: what the calibrated file writes", ea))),
        f"\nReduction of held-out RMSE: {100 * (1 - ea.rmse_nm / eb.rmse_nm) if eb.rmse_nm else 0:.1f} %. "
        f"Per sample (sensor noise included): RMSE {result.sample_level['before'].rmse_nm:.4g} → "
        f"{result.sample_level['after'].rmse_nm:.4g} N·m.\n",
        *([f"**Model adequacy:** {result.adequacy.statement}.\n"] if result.adequacy else []),
        *([f"**Residual left:** {result.structure['statement']} (see residual_structure.png).\n"]
          if result.structure else []),
        *(f"**Rig:** {line}.\n" for line in _rig_lines(result)),
        *(f"**Note:** {n}.\n" for n in result.notes),
        "## The model's own parameters changed\n",
        *([f"- {p.sentence()}" for p in result.parameters] or ["None."]),
    ]


def _rig_lines(result: CalibrationResult) -> list[str]:
    """The rig's nuisances: each channel's lag that matters, the inertia, what is periodic in the angle."""
    lines = [lag.sentence() for lag in result.lags if lag.applied or lag.why_not]
    if result.inertia is not None and result.inertia["ci95"][0] * result.inertia["ci95"][1] > 0:
        lines.append(result.inertia["text"])
    for p in (result.structure or {}).get("periodic", []):
        if p["share"] >= 0.05:
            lines.append(f"the residual left over the {p['over']}: {p['text']}")
    return lines


def _effect_lines(result: CalibrationResult) -> list[str]:
    """The accepted effects' table, and the effects the data cannot tell apart."""
    lines = ["\n## Accepted effects\n"]
    if result.effects:
        lines += ["| effect | parameters | 95 % intervals | RMS contribution [N·m] (95 %) |", "|---|---|---|---|"]
        for e in result.effects:
            pr = ", ".join(f"{k} = {v:.4g}" for k, v in e.params.items())
            ci = ", ".join(f"{k} ∈ [{lo:.4g}, {hi:.4g}]" for k, (lo, hi) in e.ci95.items())
            lo, hi = e.rms_contribution_ci95_nm
            lines.append(f"| {e.name} | {pr} | {ci} | {e.rms_contribution_nm:.4g} ({lo:.4g}–{hi:.4g}) |")
        notes = [e.bound_note() for e in result.effects if e.bound_note()]
        lines += ["", *(f"- {n}." for n in notes)] if notes else []
    else:
        lines.append("None.")
    if result.ambiguous:
        lines.append("\n## What the data cannot tell apart\n")
        for a in result.ambiguous:
            if a.taken is not None:
                readings = "; ".join(f"{' + '.join(r['effects'])}: held-out RMSE {r['heldout_rmse_nm']:.4g} N·m"
                                     + (" (written)" if r["written"] else "") for r in a.readings)
                lines.append(f"- Two readings of one part of the loss, {' / '.join(a.effects)} ({readings}). Taken "
                             f"as **{a.taken}**, {reading_choice(a)}. To tell them apart record {a.needs}.")
                continue
            lo, hi = a.rms_contribution_nm
            lines.append(
                f"- {' / '.join(a.effects)}: an effect of RMS {lo:.3g}–{hi:.3g} N·m is there, but these "
                f"columns are the same on this data. To separate them record {a.needs}."
                + (f" Taken as **{a.assumed}**, as the user assumed (`--assume`): accepted and written."
                   if a.assumed else " Kept in the fit, not written: `--assume` one of them to write it.")
            )
    return lines


def reading_choice(a) -> str:
    """Why the reading written was taken (two readings of one part of the loss, :mod:`.forward`)."""
    if a.assumed:
        return "as the user assumed (--assume)"
    best = min(a.readings, key=lambda r: r["heldout_rmse_nm"], default=None)
    if best is not None and not best["written"]:
        return (f"the established reading: the data favour {' + '.join(best['effects'])} (held-out RMSE "
                f"{best['heldout_rmse_nm']:.4g} N·m), but neither reading leaves only the noise, so this recording "
                "cannot prove which it is")
    return "the reading with fewer terms where both fit alike"


def _not_accepted_lines(result: CalibrationResult) -> list[str]:
    """Every candidate's decision: held-out numbers and the reasons, or why the data cannot test it."""
    lines = ["\n## Every candidate\n",
             "| candidate | decision | held-out RMSE with / without [N·m] | \\|z\\| | RMS contribution (95 %) [N·m] | "
             "why |", "|---|---|---|---|---|---|"]
    for d in result.decisions:
        decision = ("kept from the file" if d.step == 0 else f"accepted (step {d.step})") if d.accepted else \
            ("not testable" if d.name in result.unavailable else "not accepted")
        errors = (f"{d.heldout_rmse_nm:.4g} / {d.heldout_without_nm:.4g}" if np.isfinite(d.heldout_rmse_nm) else "—")
        z = f"{d.z:.1f}" if np.isfinite(d.z) else "—"
        lo, hi = d.rms_contribution_ci95_nm
        rms = f"{lo:.3g}–{hi:.3g}" if np.isfinite(lo) and np.isfinite(hi) else "—"
        why = "; ".join(d.reasons) or d.note or ""
        lines.append(f"| {d.name} | {decision} | {errors} | {z} | {rms} | {why.replace('|', '/')} |")
    return lines
