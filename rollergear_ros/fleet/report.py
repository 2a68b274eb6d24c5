"""Drift over a fleet, and the fleet report: which gearboxes lose efficiency, since when, and why.

From the calibrate table (one row per gearbox and time window, :mod:`.run`): for each gearbox
and effect of the registry, the accepted coefficient per window (0 where it is not accepted) and
its 95 % interval.  The first window is the gearbox's baseline.  A window *moved* for an effect
when the effect is accepted there and its interval excludes the baseline's value; a **drift** is
an effect that moved in two consecutive windows (one window alone is a one-day outlier, which a
fleet of hundreds produces by chance), dated by the first of them.  Gearboxes are ranked by the
RMS loss torque their drifted effects add in the latest window.

The report (``DIR/report.md`` + PNGs): the ranking with one sentence per drifting gearbox
("gb03: drag_constant +0.081 N·m since 2026-01-05"), the drift of each over time, the
efficiency over the fleet (when ``fleet.parquet`` from ``fleet replay`` is there), and per
gearbox the VECTO loss map of its latest calibration (``DIR/maps/<gearbox>.vtlm``).  No rclpy import.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import math
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..base.atomic import save_figure, write_text
from ..core.effects import EFFECTS
from ..base.errors import RollergearError
from .run import CALIBRATE_TABLE, FLEET_TABLE, read_table

__all__ = ["Drift", "GearboxDrift", "drift", "write_fleet_report"]

PERSISTENCE = 2  #: consecutive moved windows that make a drift


@dataclass
class Drift:
    """One effect that drifted on one gearbox."""

    effect: str
    coefficient: str
    since_window: int
    since_ns: int
    baseline: float
    latest: float
    latest_ci95: tuple[float, float]
    latest_rms_nm: float


@dataclass
class GearboxDrift:
    """A gearbox's drift (empty ``drifts``: healthy) and its calibration windows."""

    gearbox_id: str
    windows: list[dict]
    drifts: list[Drift] = field(default_factory=list)

    @property
    def score_nm(self) -> float:
        """RMS loss torque the drifted effects add in the latest window (the ranking)."""
        return math.sqrt(sum(d.latest_rms_nm ** 2 for d in self.drifts))

    def sentence(self) -> str:
        if not self.drifts:
            return f"{self.gearbox_id}: no drift"
        parts = []
        for d in self.drifts:
            day = _dt.datetime.fromtimestamp(d.since_ns / 1e9, _dt.UTC).strftime("%Y-%m-%d")
            parts.append(f"{d.effect} {d.coefficient} {d.baseline:.3g} → {d.latest:.3g} "
                         f"(95 % {d.latest_ci95[0]:.3g}…{d.latest_ci95[1]:.3g}; adds {d.latest_rms_nm:.3g} N·m RMS) "
                         f"since {day}")
        return f"{self.gearbox_id}: " + "; ".join(parts)


def drift(rows: list[dict]) -> list[GearboxDrift]:
    """Drift of every gearbox in the calibrate table (see the module docstring), worst first."""
    by_gearbox: dict[str, list[dict]] = {}
    for r in rows:
        if r.get("status") == "ok":
            by_gearbox.setdefault(r["gearbox_id"], []).append(r)
    out = []
    for gid, windows in by_gearbox.items():
        windows.sort(key=lambda r: r["window"])
        g = GearboxDrift(gid, windows)
        for name, effect in EFFECTS.items():
            col = f"{name}.{effect.coefficient}"
            coef = np.array([float(w.get(col) or 0.0) for w in windows])
            lo = np.array([_num(w.get(f"{col}_lo")) for w in windows])
            hi = np.array([_num(w.get(f"{col}_hi")) for w in windows])
            base = coef[0]
            moved = np.isfinite(lo) & ((lo > base) | (hi < base))
            runs = [i for i in range(len(moved) - PERSISTENCE + 1) if moved[i:i + PERSISTENCE].all()]
            if runs:
                i, last = runs[0], len(windows) - 1
                g.drifts.append(Drift(name, effect.coefficient, windows[i]["window"], windows[i]["window_start_ns"],
                                      float(base), float(coef[last]), (float(lo[last]), float(hi[last])),
                                      float(windows[last].get(f"{name}.rms_nm") or 0.0)))
        out.append(g)
    return sorted(out, key=lambda g: (-g.score_nm, g.gearbox_id))


def _num(v) -> float:
    return math.nan if v is None else float(v)


def write_fleet_report(out_dir: Path) -> Path:
    """``DIR/report.md`` with PNGs and per-gearbox maps, from the tables in ``out_dir``."""
    import matplotlib

    matplotlib.use("Agg")

    cal_rows = read_table(out_dir / CALIBRATE_TABLE)
    replay_rows = read_table(out_dir / FLEET_TABLE)
    gearboxes = drift(cal_rows)
    lines = ["# Fleet report\n"]
    failed = [r for r in cal_rows + replay_rows if r.get("status") != "ok"]
    lines.append(f"{len(gearboxes)} gearboxes, {len({r['gearbox_id'] for r in replay_rows})} replayed "
                 f"({len(replay_rows)} recordings), {len(cal_rows)} calibration windows; {len(failed)} failed.\n")
    drifting = [g for g in gearboxes if g.drifts]
    lines.append("## Drifting gearboxes, worst first\n")
    if drifting:
        lines += ["| rank | gearbox | added loss (RMS, latest window) | what and since when |", "|---|---|---|---|"]
        lines += [f"| {i} | {g.gearbox_id} | {g.score_nm:.3g} N·m | {g.sentence().split(': ', 1)[1]} |"
                  for i, g in enumerate(drifting, 1)]
    else:
        lines.append("None: no gearbox's effects moved beyond their 95 % intervals in two consecutive windows.")
    lines.append(f"\nHealthy: {', '.join(g.gearbox_id for g in gearboxes if not g.drifts) or 'none'}.\n")
    if drifting:
        _drift_figure(drifting, out_dir / "drift.png")
        lines.append("![drift](drift.png)\n")
    if replay_rows:
        lines += _efficiency_lines(replay_rows, out_dir)
    lines += ["## Per gearbox\n", "| gearbox | windows | latest verdict | latest held-out RMSE [N·m] | map |",
              "|---|---|---|---|---|"]
    for g in sorted(gearboxes, key=lambda g: g.gearbox_id):
        latest = g.windows[-1]
        map_path = _write_map(out_dir, g.gearbox_id, latest.get("calibrated_yaml") or "")
        lines.append(f"| {g.gearbox_id} | {len(g.windows)} | {latest.get('verdict')} | "
                     f"{_num(latest.get('error_after_rmse_nm')):.3g} | {map_path or 'not written'} |")
    warned = [r for r in cal_rows if r.get("warning")]
    if warned:
        lines += ["\n## Warnings\n"] + [f"- {r.get('gearbox_id')}, window {r.get('window')}: {r.get('warning')}"
                                        for r in warned]
    if failed:
        lines += ["\n## Failed\n"] + [f"- {r.get('recording') or r.get('gearbox_id')}: {r.get('reason')}"
                                      for r in failed]
    report = out_dir / "report.md"
    write_text(report, "\n".join(lines) + "\n")
    return report


def _drift_figure(drifting: list, path: Path) -> None:
    """Each drifting gearbox's accepted coefficients per window with their 95 % band."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(drifting), 1, figsize=(8, 2.6 * len(drifting)), dpi=100, squeeze=False)
    for ax, g in zip(axes[:, 0], drifting):
        days = [_day(w["window_start_ns"]) for w in g.windows]
        for d in g.drifts:
            col = f"{d.effect}.{d.coefficient}"
            coef = [float(w.get(col) or 0.0) for w in g.windows]
            lo = [_num(w.get(f"{col}_lo")) for w in g.windows]
            hi = [_num(w.get(f"{col}_hi")) for w in g.windows]
            ax.plot(days, coef, "o-", label=f"{d.effect} {d.coefficient}")
            ax.fill_between(days, np.nan_to_num(lo, nan=0.0), np.nan_to_num(hi, nan=0.0), alpha=0.2)
            ax.axvline(_day(d.since_ns), color="tab:red", ls="--", lw=0.8)
        ax.set_title(f"{g.gearbox_id}: accepted coefficient per window (95 % band); red: drift starts")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.autofmt_xdate()
    fig.tight_layout()
    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)


def _efficiency_lines(replay_rows: list[dict], out_dir: Path) -> list[str]:
    """The fleet's efficiency per recording (measured when the recordings have output torque, else
    estimated) as a histogram and one line; nothing without a finite one."""
    import matplotlib.pyplot as plt

    ok = [r for r in replay_rows if r.get("status") == "ok"]
    measured = np.array([_num(r.get("efficiency_measured")) for r in ok])
    kind = "measured" if np.isfinite(measured).any() else "estimated"
    eta = measured if kind == "measured" else np.array([_num(r.get("efficiency_energy")) for r in ok])
    eta = eta[np.isfinite(eta)]
    if not eta.size:
        return []
    fig, ax = plt.subplots(figsize=(7, 3.5), dpi=100)
    ax.hist(100 * eta, bins=min(30, max(5, eta.size // 2)), color="tab:blue", alpha=0.8)
    ax.set_xlabel(f"{kind} efficiency of a recording (energy out / energy in) [%]")
    ax.set_ylabel("recordings")
    ax.set_title(f"Efficiency over the fleet ({eta.size} recordings)")
    fig.tight_layout()
    try:
        save_figure(fig, out_dir / "efficiency.png")
    finally:
        plt.close(fig)
    spread = ""
    if kind == "measured":
        u = np.array([_num(r.get("efficiency_measured_uncertainty")) for r in ok
                      if np.isfinite(_num(r.get("efficiency_measured")))])
        if np.isfinite(u).any() and np.nanmax(u) > 0:
            spread = ("; each recording's standard uncertainty from the sensors' accuracy "
                      f"{100 * np.nanmedian(u):.2f} % (median)")
    return [f"{kind.capitalize()} efficiency over the fleet: {100 * eta.mean():.2f} % (recordings from "
            f"{100 * eta.min():.2f} to {100 * eta.max():.2f} %{spread}).\n\n![efficiency](efficiency.png)\n"]


def _day(t_ns: int):
    return _dt.datetime.fromtimestamp(t_ns / 1e9, _dt.UTC)


#: characters a gearbox id keeps in a file name
_SAFE_NAME = re.compile(r"[A-Za-z0-9._-]")


def safe_file_name(gearbox_id: str) -> str:
    """A gearbox id as a file name inside the output folder: an id of letters, digits, ``.``, ``_``
    and ``-`` (not starting with a dot) as it is; any other -- a path (``../x``, ``/etc/x``), a
    control character, an empty id -- with those characters replaced by ``_`` and ``~`` plus a hash
    of the whole id appended (``~`` is in no id kept as it is: two ids never map to one name)."""
    if gearbox_id and len(gearbox_id) <= 100 and not gearbox_id.startswith(".") \
            and all(_SAFE_NAME.fullmatch(c) for c in gearbox_id):
        return gearbox_id
    kept = "".join(c if _SAFE_NAME.fullmatch(c) else "_" for c in gearbox_id[:100]).lstrip(".")
    return f"{kept}~{hashlib.sha256(gearbox_id.encode('utf-8', 'surrogatepass')).hexdigest()[:12]}"


def _write_map(out_dir: Path, gearbox_id: str, calibrated_yaml: str) -> str | None:
    """The VECTO map of a gearbox's latest calibration, for its energy manager."""
    from ..outputs.lossmap import build_map, grid, map_comments, write_vtlm
    from ..core.params import load_config

    if not calibrated_yaml:
        return None
    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as fh:
        fh.write(calibrated_yaml)
    params = Path(fh.name)
    try:
        config = load_config(params)
        m = config.map
        speeds = grid(m.speed_min_rpm, m.last_speed_rpm(config.gearbox), m.speed_step_rpm)
        torques = grid(*m.torques_nm(config.gearbox))
        loss_map = build_map(config, speeds, torques)
    except RollergearError:
        return None  # e.g. an accepted viscosity effect: a map needs an oil temperature
    finally:
        params.unlink(missing_ok=True)
    name = f"{safe_file_name(gearbox_id)}.vtlm"
    path = out_dir / "maps" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    comments = map_comments(config, None, None, False) + [f"# gearbox {gearbox_id!r} (fleet calibration)"]
    write_vtlm(loss_map, path, comments)
    return f"maps/{name}"
