"""The measured loss map of a rig run: what the gearbox lost at each operating point it visited, with
its uncertainty, beside the model's -- in VECTO's format for energy managers.

A replay of the recording sums each operating-point cell's energy balance (:mod:`core.measured`;
the cell of a sample is the ``map.*`` grid's node nearest its input speed and torque).  A cell with
at least ``min_samples`` samples becomes a row: the input speed and torque of its node and the
measured loss as an input-referred torque -- the energy lost over the input's angle turned, so the
energy-weighted mean of the cell's loss torque -- with its standard uncertainty from ``sensors.*``.

Written: ``<name>.vtlm`` (forward rotation) and ``<name>_reverse.vtlm`` (reverse rotation, rows
``(|n|, −T)`` as :func:`.lossmap.build_map` writes a reverse map), VECTO's three columns with the
rows VECTO accepts -- a cell whose measured loss is negative (the sensors' error at a tiny loss) or
that would fold VECTO's triangulation is left out and listed in the comments -- and ``<name>.csv``,
every cell with its samples, measured and model loss and efficiency and their uncertainties.
No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ..base.atomic import write_text
from ..core.measured import EnergyBalance
from ..core.params import Config
from .lossmap import VECTO_HEADER, reverse_path

__all__ = ["MeasuredCell", "measured_cells", "write_measured_map"]

#: a cell with fewer samples is not a row
MIN_SAMPLES = 100


@dataclass(frozen=True)
class MeasuredCell:
    """One operating point of the measured map (speeds and torques signed, as the samples were)."""

    speed_rpm: float
    torque_nm: float
    samples: int
    seconds: float
    loss_nm: float
    loss_uncertainty_nm: float
    model_loss_nm: float
    efficiency: float
    efficiency_uncertainty: float
    model_efficiency: float

    @property
    def reverse(self) -> bool:
        return self.speed_rpm < 0

    def vecto_row(self) -> tuple[float, float, float]:
        """``(n, T, loss)`` as VECTO reads it: reverse rotation mirrored (``|n|``, ``−T``)."""
        sign = -1.0 if self.reverse else 1.0
        return sign * self.speed_rpm, sign * self.torque_nm, self.loss_nm


def measured_cells(cells: list[tuple[float, float, EnergyBalance, float]], config: Config,
                   min_samples: int = MIN_SAMPLES) -> list[MeasuredCell]:
    """The cells of a replay's summary (:attr:`~replay.summary.ReplaySummary.measured_cells`) with at
    least ``min_samples`` samples, as map rows."""
    sensors = config.sensors
    return [MeasuredCell(rpm, torque, b.samples, b.seconds, b.loss_nm, b.loss_uncertainty_nm(sensors),
                         b.model_loss_nm, b.efficiency, u, b.model_efficiency)
            for rpm, torque, b, u in cells if b.samples >= min_samples and b.angle_rad > 0]


def _vecto_rows(cells: list[MeasuredCell]) -> tuple[list[tuple[float, float, float]], list[str]]:
    """The rows VECTO accepts, and why each other cell was left out."""
    rows, left_out = [], []
    for c in sorted(cells, key=lambda c: c.vecto_row()[:2]):
        n, t, loss = c.vecto_row()
        if not (loss >= 0):
            left_out.append(f"{n:g} rpm, {t:g} N*m: measured loss {loss:.4g} ± {c.loss_uncertainty_nm:.2g} N*m "
                            "is negative (VECTO takes losses >= 0)")
            continue
        if rows and rows[-1][0] == n and t - loss <= rows[-1][1] - rows[-1][2]:
            left_out.append(f"{n:g} rpm, {t:g} N*m: T_in - T_loss would not rise over the one before (VECTO's "
                            "triangulation would fold)")
            continue
        rows.append((n, t, loss))
    return rows, left_out


def write_measured_map(cells: list[MeasuredCell], path: Path, comments: list[str]) -> list[Path]:
    """Write ``path`` (forward), its reverse map when there are reverse cells, and ``path``'s CSV;
    returns the files written.  A map with fewer than four rows is not written (VECTO needs four);
    the CSV always is."""
    written = []
    for reverse, target in ((False, path), (True, reverse_path(path))):
        rows, left_out = _vecto_rows([c for c in cells if c.reverse == reverse])
        if len(rows) < 4:
            continue
        lines = [*comments, f"# {len(rows)} measured operating points ({'reverse' if reverse else 'forward'} "
                 "rotation); the uncertainties are in the CSV beside this file"]
        lines += [f"# left out: {why}" for why in left_out]
        lines += [",".join(VECTO_HEADER)] + [f"{n:.6g},{t:.6g},{loss:.6g}" for n, t, loss in rows]
        write_text(target, "\n".join(lines) + "\n")
        written.append(target)
    csv = path.with_suffix(".csv")
    header = ("speed_rpm,torque_nm,samples,seconds,measured_loss_nm,measured_loss_uncertainty_nm,model_loss_nm,"
              "measured_efficiency,measured_efficiency_uncertainty,model_efficiency")
    body = [",".join(_num(v) for v in (c.speed_rpm, c.torque_nm, c.samples, c.seconds, c.loss_nm,
                                       c.loss_uncertainty_nm, c.model_loss_nm, c.efficiency,
                                       c.efficiency_uncertainty, c.model_efficiency)) for c in cells]
    write_text(csv, "\n".join([header, *body]) + "\n")
    written.append(csv)
    return written


def _num(v) -> str:
    if isinstance(v, int):
        return str(v)
    return "nan" if not math.isfinite(v) else f"{v:.8g}"
