"""The loss maps of several oil temperatures as one long table (``map --oil-temperature-c T1 T2 …``).

One row per map point and temperature -- what an energy manager's own interpolation reads:

=================  ======  ===========================================================
column             unit    meaning
=================  ======  ===========================================================
oil_temperature_c  degC    the oil temperature the map was evaluated at
reverse            --      1: a reverse-rotation map's row (speed and torque as in its .vtlm)
speed_rpm          rpm     input speed (≥ 0, as in the .vtlm)
torque_nm          N·m     input torque (positive: drives in the map's direction)
loss_nm            N·m     input-referred torque loss magnitude (the .vtlm's column)
loss_power_w       W       ``loss_nm · speed_rpm · 2π/60``
efficiency         1       the map's efficiency; empty (CSV) / null (Parquet) where undefined
=================  ======  ===========================================================

CSV (``.csv``) or Parquet (``.parquet``, each field's unit in its metadata), written atomically.
No rclpy import.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..base.atomic import replacing
from ..base.interface import RPM_PER_RAD_S
from ..core.operating_points import temperature_effects
from ..core.params import Config
from .lossmap import LossMap

__all__ = ["MAX_MAP_TEMPERATURES", "TABLE_COLUMNS", "long_rows", "oil_dependence_warning", "write_long_table"]

#: the most oil temperatures one ``map`` run evaluates (each is a whole map)
MAX_MAP_TEMPERATURES = 100

#: (name, unit) of the table's columns, in order
TABLE_COLUMNS: tuple[tuple[str, str], ...] = (
    ("oil_temperature_c", "degC"), ("reverse", "1"), ("speed_rpm", "rpm"), ("torque_nm", "N*m"),
    ("loss_nm", "N*m"), ("loss_power_w", "W"), ("efficiency", "1"))


def long_rows(maps: Sequence[tuple[float, LossMap]]) -> dict[str, np.ndarray]:
    """The table's columns for ``(oil temperature, map)`` pairs, in the order given, each map speed-major."""
    parts = []
    for temperature_c, loss_map in maps:
        rows = loss_map.rows()
        n = len(rows)
        parts.append({
            "oil_temperature_c": np.full(n, float(temperature_c)),
            "reverse": np.full(n, int(loss_map.reverse), dtype=np.int64),
            "speed_rpm": rows[:, 0], "torque_nm": rows[:, 1], "loss_nm": rows[:, 2],
            "loss_power_w": rows[:, 2] * rows[:, 0] / RPM_PER_RAD_S,
            "efficiency": loss_map.efficiency.ravel().astype(float)})
    return {name: np.concatenate([p[name] for p in parts]) for name, _ in TABLE_COLUMNS}


def write_long_table(maps: Sequence[tuple[float, LossMap]], path: str | Path) -> int:
    """Write the long table to ``path`` (``.parquet``: Parquet, else CSV); returns its row count."""
    columns = long_rows(maps)
    path = Path(path)
    with replacing(path) as partial:
        if path.suffix.lower() == ".parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq

            fields = [pa.field(name, pa.int64() if name == "reverse" else pa.float64(), metadata={"unit": unit})
                      for name, unit in TABLE_COLUMNS]
            arrays = [pa.array(columns[name], mask=~np.isfinite(columns[name]) if name == "efficiency" else None)
                      for name, _ in TABLE_COLUMNS]
            pq.write_table(pa.Table.from_arrays(arrays, schema=pa.schema(fields)), partial)
        else:
            with partial.open("w", newline="", encoding="utf-8") as fh:
                writer = csv.writer(fh)
                writer.writerow([name for name, _ in TABLE_COLUMNS])
                for row in zip(*(columns[name] for name, _ in TABLE_COLUMNS)):
                    writer.writerow([_cell(v) for v in row])
    return len(columns["speed_rpm"])


def oil_dependence_warning(config: Config, temperatures_c: Sequence[float]) -> str | None:
    """A warning when maps at several oil temperatures were asked of a model that does not follow
    the oil (no accepted effect needs its temperature): they are all the same map."""
    if len(temperatures_c) < 2 or temperature_effects(config):
        return None
    return ("the parameter file's model does not follow the oil temperature (no accepted effect needs it, e.g. "
            "viscosity_temperature): the maps of every temperature are the same")


def _cell(value) -> str:
    """A CSV cell: integers as such, floats to 9 significant digits, NaN empty."""
    if isinstance(value, (np.integer, int)):
        return str(int(value))
    return "" if not np.isfinite(value) else f"{float(value):.9g}"
