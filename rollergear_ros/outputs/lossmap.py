"""The loss map for energy managers: VECTO transmission loss map (``.vtlm``) and its picture.

The map holds the calibrated model (:func:`core.operating_points.evaluate_points`: the paper's
model plus the accepted effects, as the estimator evaluates them) on a speed × torque grid, in
the layout VECTO reads (``TransmissionLossMapReader``): one header line ``Input Speed [rpm],
Input Torque [Nm], Torque Loss [Nm]``, ``#`` comment lines, one row per grid point.  VECTO's
rules, which :func:`build_map` enforces and :func:`vtlm_problems` checks:

* speeds ≥ 0 (VECTO rejects negative input speeds: reverse rotation is a separate map, whose
  rows give ``|n|`` and the torque relative to that direction, see :func:`build_map`);
* torque loss ≥ 0 (a magnitude, input-referred), both torque signs (driving and overrun);
* at least four rows, at least two speeds and two torques (VECTO triangulates the points);
* over input torque at each speed the output-side torque ``T_in − T_loss`` rises strictly,
  otherwise VECTO's triangulation in (speed, ``T_in − T_loss``) folds over.

No rclpy import.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..base.atomic import save_figure, write_text
from ..base.errors import UsageError
from ..base.interface import RPM_PER_RAD_S, package_version
from ..core.operating_points import PointLosses, evaluate_points, locked_points
from ..core.params import Config, grid_axis_problem, grid_cells_problem, grid_points
from ..sources.tables import MIN_ROWS

__all__ = ["VECTO_HEADER", "LossMap", "build_map", "coverage_warning", "efficiency_levels", "grid", "map_comments",
           "plot_map", "reverse_path", "vtlm_problems", "write_vtlm"]

VECTO_HEADER = ("Input Speed [rpm]", "Input Torque [Nm]", "Torque Loss [Nm]")


@dataclass
class LossMap:
    """The calibrated model on a grid: arrays ``[speed, torque]`` (speed-major, both ascending)."""

    speeds_rpm: np.ndarray  #: ≥ 0
    torques_nm: np.ndarray  #: positive: drives in the map's direction of rotation
    loss_nm: np.ndarray  #: input-referred torque loss magnitude
    efficiency: np.ndarray  #: NaN where undefined (below the efficiency thresholds)
    model_nm: np.ndarray  #: the paper's model alone
    reverse: bool = False  #: the rows describe reverse rotation
    points: PointLosses | None = None
    temperature_c: float | None = None  #: the oil temperature it was evaluated at (None: none given)

    def rows(self) -> np.ndarray:
        """``(speed_rpm, torque_nm, loss_nm)`` per grid point, speed-major."""
        s, t = np.meshgrid(self.speeds_rpm, self.torques_nm, indexing="ij")
        return np.column_stack([s.ravel(), t.ravel(), self.loss_nm.ravel()])


def grid(start: float, stop: float, step: float) -> np.ndarray:
    """Inclusive ``start..stop`` in ``step`` increments (rounded to kill float drift)."""
    if step <= 0 or not all(map(math.isfinite, (start, stop, step))) or stop < start:
        raise UsageError(f"bad grid {start}:{stop}:{step} (need finite start <= stop and step > 0)")
    problem = grid_axis_problem(start, stop, step)
    if problem:
        raise UsageError(problem)
    n = int(grid_points(start, stop, step))
    return np.round(start + step * np.arange(n), 9)


def build_map(config: Config, speeds_rpm: Sequence[float], torques_nm: Sequence[float],
              temperature_c: float | None = None, reverse: bool = False) -> LossMap:
    """Evaluate the calibrated model on the grid; refuses grids VECTO would not accept.

    ``reverse``: the map of reverse rotation -- a row ``(n, T)`` holds the loss at input speed
    ``−n`` with torque ``−T`` (``T > 0`` drives in the reverse direction), so that VECTO's
    rules (``n ≥ 0``) hold for it too.
    """
    speeds = np.asarray(speeds_rpm, float)
    torques = np.asarray(torques_nm, float)
    problem = grid_cells_problem(len(speeds), len(torques))
    if problem:
        raise UsageError(problem)
    if (speeds < 0).any():
        raise UsageError("VECTO loss maps have input speeds >= 0: give the speed grid from 0 up "
                         "(--both-directions writes reverse rotation to a second file)")
    if len(np.unique(speeds)) < 2 or len(np.unique(torques)) < 2:
        raise UsageError(f"a loss map needs at least two speeds and two torques (got {len(speeds)} x {len(torques)})")
    if not (torques.min() < 0 < torques.max()):
        raise UsageError("a VECTO loss map needs both torque signs (driving and overrun): "
                         f"the torque grid is {torques.min():g} … {torques.max():g} N·m")
    s, t = np.meshgrid(speeds, torques, indexing="ij")
    sign = -1.0 if reverse else 1.0
    points = plausible_points(config, sign * t.ravel(), sign * s.ravel() / RPM_PER_RAD_S, temperature_c, "grid")
    shape = s.shape
    return LossMap(speeds, torques, points.loss_magnitude_nm.reshape(shape), points.efficiency.reshape(shape),
                   points.model_nm.reshape(shape), reverse, points, temperature_c)


def plausible_points(config: Config, torque_nm, speed_rad_s, temperature_c: float | None, what: str) -> PointLosses:
    """:func:`~core.operating_points.evaluate_points`, refusing points the estimator skips as
    implausible, or where the file's laws in the load lock a back-driven drive (``load_unbalanced``;
    ``what`` -- the grid, the table -- names them in the error)."""
    points = evaluate_points(config, torque_nm, speed_rad_s, temperature_c)
    locked = locked_points(config, points)
    if locked.any():
        i = int(np.flatnonzero(locked)[0])
        raise UsageError(f"the parameter file's laws in the load lock the drive at {int(locked.sum())} points of the "
                         f"{what} (back-driven, no output-side load balances the drive torque; the first at "
                         f"T = {float(np.asarray(torque_nm)[i]):g} N·m, w = {float(np.asarray(speed_rad_s)[i]):g} "
                         "rad/s): lower their coefficient or exponent, or the grid's torques")
    if np.isnan(points.loss_magnitude_nm).any():
        est = config.estimator
        raise UsageError(f"the {what} leaves the estimator's plausible range (|T| <= {est.max_abs_torque_nm:g} N·m, "
                         f"|w| <= {est.max_abs_speed_rad_s:g} rad/s): estimator.max_abs_*")
    return points


def calibration_lines(params_path: str | Path | None) -> list[str]:
    """What calibrate wrote at the head of a parameter file (``Written by …``, ``verdict: …``; empty: none)."""
    if params_path is None or not Path(params_path).exists():
        return []
    return [ln[1:].strip() for ln in Path(params_path).read_text(encoding="utf-8").splitlines()[:3]
            if ln.startswith("# Written by `rollergear calibrate`") or ln.startswith("# verdict:")]


def accepted_effects_text(config: Config) -> str | None:
    """The accepted physical effects with their parameters (``drag_speed c=0.0003 p=1.4; …``), None: none."""
    from ..core.effects import EFFECTS

    physical = {n: p for n, p in config.effects.active().items() if EFFECTS[n].physical}
    return "; ".join(f"{n} " + " ".join(f"{k}={v:.6g}" for k, v in p.items()) for n, p in physical.items()) or None


def reverse_path(path: Path) -> Path:
    """Where the reverse-rotation map of ``path`` goes: ``lossmap.vtlm`` -> ``lossmap_reverse.vtlm``."""
    return path.with_name(f"{path.stem}_reverse{path.suffix}")


def map_comments(config: Config, params_path: Path | None, temperature_c: float | None, reverse: bool) -> list[str]:
    """The ``#`` lines of a written map: ratio, parameter source, calibration, temperature, date."""
    from ..core.effects import EFFECTS

    lines = [f"rollergear_ros {package_version()}: roller gearing gearbox loss map (input-referred torque loss)",
             f"ratio (input/output speed) {config.gearbox.ratio_effective:.6g}",
             f"parameters: {params_path if params_path else 'built-in defaults'}"]
    lines += [f"calibration: {h}" for h in calibration_lines(params_path)]
    lines.append("accepted effects: " + (accepted_effects_text(config) or "none (the paper's model only)"))
    sensor = [n for n in config.effects.active() if not EFFECTS[n].physical]
    if sensor:
        lines.append(f"not applied (torque-sensor errors of the rig): {' '.join(sensor)}")
    if temperature_c is not None:
        lines.append(f"oil temperature {temperature_c:g} degC")
    if reverse:
        lines.append("REVERSE rotation: Input Speed is |n| of the reverse direction; Input Torque > 0 drives in it")
    lines.append("written " + _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"))
    # VECTO cuts a cell at '#' and splits at ','; keep the comments free of both
    return ["# " + ln.replace(",", ";").replace("#", "No.") for ln in lines]


def write_vtlm(loss_map: LossMap, path: Path, comments: Sequence[str] = ()) -> None:
    """Write the map atomically (a reader never sees half a file): comments, header, rows."""
    lines = list(comments) + [",".join(VECTO_HEADER)]
    lines += [f"{s:.6g},{t:.6g},{loss:.6g}" for s, t, loss in loss_map.rows()]
    write_text(path, "\n".join(lines) + "\n")


def vtlm_problems(loss_map: LossMap) -> list[str]:
    """What VECTO would reject or mis-read in this map (empty: none)."""
    problems = []
    rows = loss_map.rows()
    if len(rows) < MIN_ROWS:
        problems.append(f"{len(rows)} rows; VECTO needs at least {MIN_ROWS}")
    if (rows[:, 0] < 0).any():
        problems.append("negative input speeds")
    if not (rows[:, 2] >= 0).all():
        problems.append("negative or undefined torque loss")
    out = loss_map.torques_nm[None, :] - loss_map.loss_nm
    folded = np.flatnonzero((np.diff(out, axis=1) <= 0).any(axis=1))
    if folded.size:
        problems.append("T_in - T_loss does not rise with T_in at "
                        + ", ".join(f"{loss_map.speeds_rpm[i]:g}" for i in folded[:5]) + " rpm (the loss grows "
                        "faster than the torque: refine the torque grid or check the parameters)")
    return problems


def coverage_warning(loss_map: LossMap, torque_nm: np.ndarray, speed_rad_s: np.ndarray, source: str) -> str | None:
    """A warning when the recording ``source`` visited operating points outside the map (None: covered).

    The forward map covers ``0 ≤ n ≤ n_max`` and ``T_min ≤ T ≤ T_max``; samples in reverse
    rotation count against the reverse map's grid (the same grid, mirrored).
    """
    torque = np.asarray(torque_nm, float)
    speed_rpm = np.asarray(speed_rad_s, float) * RPM_PER_RAD_S
    if not len(torque):
        return None
    sign = np.where(speed_rpm < 0, -1.0, 1.0)
    n, t = speed_rpm * sign, torque * sign
    outside = ((n > loss_map.speeds_rpm.max()) | (n < loss_map.speeds_rpm.min())
               | (t < loss_map.torques_nm.min()) | (t > loss_map.torques_nm.max()))
    if not outside.any():
        return None
    share = 100.0 * np.count_nonzero(outside) / len(torque)
    speeds, torques = loss_map.speeds_rpm, loss_map.torques_nm
    return (f"{source}: {share:.1f} % of the samples lie outside the map (visited |n| up to "
            f"{np.abs(speed_rpm).max():.0f} rpm, T {torque.min():.4g} … {torque.max():.4g} N·m; the map covers "
            f"{speeds.min():g} … {speeds.max():g} rpm, {torques.min():g} … {torques.max():g} N·m)")


def efficiency_levels(eta_pct: np.ndarray, bands: int = 12) -> np.ndarray:
    """Contour levels [%] that resolve the range the gearbox lives in: from its 5th percentile to its
    highest efficiency in at most ``bands`` round steps (0.01 … 5 %); what lies below shows as one
    band (``extend="min"``), so a few poor points near zero torque do not flatten 98–100 % into one."""
    lo, hi = float(np.percentile(eta_pct, 5)), float(np.max(eta_pct))
    step = next((st for st in (0.01, 0.02, 0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0) if (hi - lo) / st <= bands), 10.0)
    first, last = math.floor(lo / step) * step, math.ceil(hi / step) * step
    return np.round(np.arange(first, max(last, first + step) + step / 2, step), 4)


def plot_map(loss_map: LossMap, png_path: Path, min_torque_nm: float) -> None:
    """Two panels: efficiency contours (round levels; the undefined band |T| < ``min_torque_nm``
    hatched) and the loss torque the map file holds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n, t = loss_map.speeds_rpm, loss_map.torques_nm
    eta = loss_map.efficiency * 100.0
    fig, (ax_eta, ax_loss) = plt.subplots(1, 2, figsize=(12, 5), dpi=110)
    direction = "reverse rotation" if loss_map.reverse else "forward rotation"
    finite = eta[np.isfinite(eta)]
    if finite.size and len(n) > 1 and len(t) > 1:
        levels = efficiency_levels(finite)
        cs = ax_eta.contourf(n, t, eta.T, levels=levels, cmap="viridis", extend="min")
        ax_eta.contour(n, t, eta.T, levels=levels, colors="k", linewidths=0.4)
        fig.colorbar(cs, ax=ax_eta, label="efficiency [%]")
    ax_eta.axhspan(-min_torque_nm, min_torque_nm, facecolor="none", hatch="///", edgecolor="0.5", linewidth=0)
    ax_eta.text(n.min(), min_torque_nm, f" efficiency undefined: |T| < {min_torque_nm:g} N·m", va="bottom",
                fontsize=8, color="0.3")
    ax_eta.set_title(f"efficiency – {direction}")
    cl = ax_loss.contourf(n, t, loss_map.loss_nm.T, levels=12, cmap="magma")
    fig.colorbar(cl, ax=ax_loss, label="torque loss [N·m] (the map file's column)")
    ax_loss.set_title(f"torque loss – {direction}")
    for ax in (ax_eta, ax_loss):
        ax.set_xlabel("input speed [rpm]")
        ax.set_ylabel("input torque [N·m]")
        ax.axhline(0.0, color="w", linewidth=0.8)
        ax.text(0.98, 0.97, "driving (motoring)", transform=ax.transAxes, ha="right", va="top", fontsize=8,
                color="w", bbox={"facecolor": "0.2", "alpha": 0.5, "linewidth": 0})
        ax.text(0.98, 0.03, "overrun (regenerating)", transform=ax.transAxes, ha="right", va="bottom", fontsize=8,
                color="w", bbox={"facecolor": "0.2", "alpha": 0.5, "linewidth": 0})
    fig.tight_layout()
    try:
        save_figure(fig, png_path)
    finally:
        plt.close(fig)
