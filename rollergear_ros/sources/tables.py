"""Steady-state tables: one row per operating point, a dwell mean (no time series, no sensor noise).

Two kinds. CSV or Parquet with a channel map of ``format: steady_state`` (:mod:`.channelmap`): the
measured loss from a ``loss_torque`` column, or from ``output_torque`` (with ``output_speed``, or
the map's ``ratio``, or the gearbox's) as ``(T_in·ω_in − T_out·ω_out)/|ω_in|``, or from
``efficiency`` (``|T|(1 − η)`` driving, ``|T|(1/η − 1)`` regenerating; rows of efficiency 0 -- no
power through -- drop); a ``group`` column keeps gearbox states apart, a ratio column gives each row's
ratio. A table of the output side -- output torque, output speed, efficiency and the ratio, as NREL
ADVISOR's maps -- is put on the input shaft first (:func:`_input_side`). And VECTO transmission loss
maps (``.vtlm``), read by VECTO's own rules (``VectoCSVFile`` + ``TransmissionLossMapReader``):
``,`` delimiter, ``.`` decimal mark, lines starting with ``#`` are comments and a cell ends at
``#``; one header line whose ``[unit]`` parts name the units (rpm, Nm) -- a header of numbers means
no header and the columns by position, as VECTO falls back to; the columns ``Input Speed`` [rpm],
``Input Torque`` [N·m] (negative: overrun) and ``Torque Loss`` [N·m], input-referred, ≥ 0; further
columns (``Eff``) ignored; at least four rows. Bad files raise :class:`~base.errors.InputFileError` with
one line naming the file, the line and what is wrong. No rclpy import.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .channelmap import ChannelMap, ChannelSpec
from ..base.errors import InputFileError
from .formats import format_by_suffix, is_format
from ..base.interface import RPM_PER_RAD_S, Channel

__all__ = ["SteadyStateTable", "is_table", "read_table", "read_vtlm"]

VTLM_COLUMNS = (("Input Speed", "rpm"), ("Input Torque", "Nm"), ("Torque Loss", "Nm"))
_UNIT = re.compile(r"\[(.*?)\]")
_UNIT_SPELLINGS = {"rpm": {"rpm", "1/min", "min-1", "min^-1"}, "Nm": {"nm", "n·m", "n*m", "n m"}}
MIN_ROWS = 4  #: VECTO: "at least four lines with numeric values" (also what a written map must hold)


@dataclass
class SteadyStateTable:
    """Operating points with their measured input-referred loss."""

    path: Path
    speed_rad_s: np.ndarray
    torque_nm: np.ndarray
    loss_nm: np.ndarray
    temperature_c: np.ndarray  #: NaN where the table has none
    line: np.ndarray  #: line number of each row in the file (for messages)
    group: np.ndarray | None = None  #: gearbox state of each row (the map's group column)
    dropped: int = 0  #: rows without a finite torque, speed or loss (e.g. a loss from output torque at standstill)
    ratio: float | None = None  #: the table's own input/output ratio (the map's), when it has one
    #: the loss is the power balance of the rows' drive and output torque (not a loss or efficiency
    #: column): the drive torque is a sensor's dwell mean, and that sensor's errors are in the loss
    readings: bool = False


def is_table(path: str | Path, cmap: ChannelMap | None = None) -> bool:
    """Whether ``path`` is read as a steady-state table: a ``.vtlm``, or any file with a
    ``format: steady_state`` channel map."""
    return is_format(path, "VTLM") or (cmap is not None and cmap.format == "steady_state")


def read_table(path: str | Path, cmap: ChannelMap | None = None, ratio: float | None = None) -> SteadyStateTable:
    """Read a steady-state table; ``ratio``: the gearbox's, when neither output speed nor the map gives one."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path} does not exist")
    if not path.is_file():  # a folder, a FIFO or a device
        raise InputFileError(f"{path} is not a regular file")
    if is_format(path, "VTLM"):
        return read_vtlm(path)
    if cmap is None or cmap.format != "steady_state":
        raise InputFileError(f"{path}: a steady-state table is a .vtlm, or CSV/Parquet with a channel map of "
                             "format: steady_state")
    if not getattr(format_by_suffix(path), "arrow", False):  # read through pyarrow: CSV, Parquet
        raise InputFileError(f"{path}: steady-state tables are read from CSV or Parquet ({path.suffix!r})")
    return _read_mapped(path, cmap, ratio)


def _read_mapped(path: Path, cmap: ChannelMap, ratio: float | None) -> SteadyStateTable:
    from .arrowfiles import arrow_table, numeric_column

    table, first_line = arrow_table(path, cmap)
    col = {name: spec.to_si(numeric_column(path, name, spec, table)) for name, spec in cmap.channels.items()}
    if cmap.ratio_column is not None:  # each row's ratio
        ratio = numeric_column(path, "ratio", ChannelSpec("ratio", cmap.ratio_column, "1"), table)
        if not (ratio[np.isfinite(ratio)] > 0).all():
            raise InputFileError(f"{path}: ratio ({cmap.ratio_column}): a ratio that is not > 0")
    else:
        ratio = cmap.ratio or ratio
    if cmap.output_side:
        _check_efficiency(path, col["efficiency"])
        col = _input_side(col, ratio)
    elif Channel.MOTOR_SPEED not in col:  # input torque with the output speed: ω_in = ω_out·r
        col[Channel.MOTOR_SPEED] = col[Channel.OUTPUT_SPEED] * ratio
    torque, speed = col[Channel.MOTOR_TORQUE], col[Channel.MOTOR_SPEED]
    if "loss_torque" in col:
        loss = col["loss_torque"]
    elif Channel.OUTPUT_TORQUE in col:
        w_out = col.get(Channel.OUTPUT_SPEED, speed / ratio if ratio is not None and np.all(np.asarray(ratio) != 0)
                        else np.full(len(speed), np.nan))
        with np.errstate(divide="ignore", invalid="ignore"):
            loss = (torque * speed - col[Channel.OUTPUT_TORQUE] * w_out) / np.abs(speed)
    else:
        eta = col["efficiency"]
        _check_efficiency(path, eta)
        driving = torque * speed > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            loss = np.where(driving, np.abs(torque) * (1 - eta), np.abs(torque) * (1 / eta - 1))
        loss = np.where(eta > 0, loss, np.nan)  # efficiency 0: no power through, no loss to read (drops)
    line = np.arange(len(torque), dtype=np.int64) + first_line
    ok = np.isfinite(torque) & np.isfinite(speed) & np.isfinite(loss)
    if not ok.any():
        raise InputFileError(f"{path}: no row with finite torque, speed and loss (a loss from output torque needs "
                             "|speed| > 0)")
    theta = col.get(Channel.OIL_TEMPERATURE, np.full(len(torque), np.nan))
    group = None
    if cmap.group is not None:
        group = np.asarray(table.column(cmap.group).to_pylist(), dtype=object)[ok].astype(str)
    if len(np.flatnonzero(ok)) < MIN_ROWS:
        raise InputFileError(f"{path}: {int(ok.sum())} usable rows; a table needs at least {MIN_ROWS}")
    own = cmap.ratio if cmap.ratio is not None else (
        float(ratio[ok][0]) if cmap.ratio_column is not None and np.unique(ratio[ok]).size == 1 else None)
    readings = "loss_torque" not in col and Channel.OUTPUT_TORQUE in col and not cmap.output_side
    return SteadyStateTable(path, speed[ok], torque[ok], loss[ok], theta[ok], line[ok], group,
                            int(np.count_nonzero(~ok)), own, readings)


def _check_efficiency(path: Path, eta: np.ndarray) -> None:
    """An efficiency outside [0, 1] after the map's unit is one line naming the row (0: no power
    through, the row drops; empty: no row)."""
    bad = np.isfinite(eta) & ((eta < 0) | (eta > 1))
    if bad.any():
        raise InputFileError(f"{path}: data row {int(np.flatnonzero(bad)[0]) + 1}: efficiency "
                             f"{eta[bad][0]:.4g} is not in [0, 1] (after the map's unit)")


def _input_side(col: dict[str, np.ndarray], ratio) -> dict[str, np.ndarray]:
    """An output-side efficiency table on the input shaft: ``ω_in = ω_out·r``; ``T_in = T_out/(r·η)``
    driving (power flows out, ``T_out·ω_out > 0``), ``T_out·η/r`` overrunning.  Rows at standstill or
    without load, and rows of efficiency 0 (no power through: NREL ADVISOR writes 0 there and where
    its regression's loss exceeds the power), have no input torque: they drop (counted)."""
    t_out, w_out, eta = col[Channel.OUTPUT_TORQUE], col[Channel.OUTPUT_SPEED], col["efficiency"]
    moving = (t_out != 0) & (w_out != 0) & (eta > 0)
    driving = t_out * w_out > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in = np.where(driving, t_out / (ratio * eta), t_out * eta / ratio)
    out = dict(col)
    out[Channel.MOTOR_TORQUE] = np.where(moving, t_in, np.nan)
    out[Channel.MOTOR_SPEED] = w_out * ratio
    return out


def _cells(line: str) -> list[str]:
    return [c.split("#", 1)[0].strip() for c in line.split(",")]


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def read_vtlm(path: str | Path) -> SteadyStateTable:
    """A VECTO ``.vtlm`` loss map (see the module docstring for the rules)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputFileError(f"{path}: not a text file ({exc.reason})") from None
    lines = [(k, ln) for k, ln in enumerate(text.splitlines(), start=1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputFileError(f"{path}: no header and no data (a VECTO loss map has Input Speed, Input Torque, "
                             "Torque Loss)")
    first_no, first = lines[0]
    header = _cells(first)
    if all(_number(c) is not None for c in header if c):
        index = [0, 1, 2]  # no header: by position, as VECTO reads it
        data_lines = lines
    else:
        names = [_UNIT.sub("", c).strip() for c in header]
        index = []
        for name, unit in VTLM_COLUMNS:
            if name not in names:
                raise InputFileError(f"{path}: line {first_no}: no column {name!r} in the header "
                                     f"({', '.join(c for c in header if c)})")
            i = names.index(name)
            given = _UNIT.search(header[i])
            if given and given.group(1).strip().lower() not in _UNIT_SPELLINGS[unit]:
                raise InputFileError(f"{path}: line {first_no}: column {name!r} is in [{given.group(1)}]; "
                                     f"a VECTO loss map has it in [{unit}]")
            index.append(i)
        data_lines = lines[1:]
    rows, numbers = [], []
    for k, ln in data_lines:
        cells = _cells(ln)
        values = [_number(cells[i]) if i < len(cells) else None for i in index]
        if any(v is None for v in values):
            columns = ", ".join(str(i + 1) for i in index)
            raise InputFileError(f"{path}: line {k}: expected numbers in columns {columns}, got {ln.strip()!r}")
        rows.append(values)
        numbers.append(k)
    data = np.array(rows, dtype=float).reshape(-1, 3)
    line = np.array(numbers, dtype=np.int64)
    if len(data) < MIN_ROWS:
        raise InputFileError(f"{path}: {len(data)} data rows; a loss map has at least {MIN_ROWS}")
    for col, what in ((0, "input speed"), (1, "input torque"), (2, "torque loss")):
        bad = ~np.isfinite(data[:, col])
        if bad.any():
            raise InputFileError(f"{path}: line {line[bad][0]}: {what} is not finite")
    if (data[:, 0] < 0).any():
        raise InputFileError(f"{path}: line {line[data[:, 0] < 0][0]}: negative input speed (VECTO: 0 … 1e6 rpm)")
    if (data[:, 2] < 0).any():
        raise InputFileError(f"{path}: line {line[data[:, 2] < 0][0]}: negative torque loss (a loss is >= 0)")
    return SteadyStateTable(path, data[:, 0] / RPM_PER_RAD_S, data[:, 1], data[:, 2], np.full(len(data), np.nan), line)
