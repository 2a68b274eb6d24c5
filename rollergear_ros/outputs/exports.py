"""Replay's estimates as tables for spreadsheets and measurement tools: CSV, Parquet and MDF4.

One row per estimated sample: its log time, the inputs it was estimated from and the estimates
(:data:`COLUMNS`), in time order.  Units go where each format keeps them: in the CSV header
(``loss_torque [N*m]``), in each Parquet field's metadata (``unit``) and in each MDF4 channel
(asammdf, one channel group, the time channel in seconds since the first row and the file's start
time that row's date).  A quantity the recording does not have (no output torque, no oil
temperature) is NaN in its column, so every export of every recording has the same columns.

An export is written beside its final name and renamed onto it when complete (:mod:`base.atomic`);
an interrupted replay commits what it processed, like its MCAP.  No rclpy.
"""

from __future__ import annotations

import datetime
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..base.atomic import commit, discard, named, partial_path

if TYPE_CHECKING:  # the command line imports this module for its names only
    from ..core.batchpath import BatchEstimate

__all__ = ["COLUMNS", "EXPORT_KINDS", "Column", "Export"]


@dataclass(frozen=True)
class Column:
    """One exported quantity: its name, SI unit and how it is taken from a batch of estimates."""

    name: str
    unit: str
    take: Callable[[BatchEstimate], np.ndarray | None]

    @property
    def header(self) -> str:
        """The CSV header cell: name and unit."""
        return f"{self.name} [{self.unit}]"


#: the exported columns after the time columns, in order
COLUMNS: tuple[Column, ...] = (
    Column("motor_torque", "N*m", lambda b: b.torque_nm),
    Column("motor_speed", "rad/s", lambda b: b.speed_rad_s),
    Column("output_torque", "N*m", lambda b: b.out_torque_nm),
    Column("output_speed", "rad/s", lambda b: b.out_speed_rad_s),
    Column("oil_temperature", "degC", lambda b: b.temperature_c),
    Column("loss_torque", "N*m", lambda b: b.loss_torque_nm),
    Column("loss_power", "W", lambda b: b.loss_power_w),
    Column("efficiency", "1", lambda b: b.efficiency),
    Column("measured_loss", "N*m", lambda b: b.measured_loss_nm),
    Column("residual_torque", "N*m", lambda b: b.residual_nm),
    Column("efficiency_measured", "1", lambda b: b.efficiency_measured),
    Column("efficiency_measured_window", "1", lambda b: b.efficiency_measured_window),
    Column("efficiency_measured_uncertainty", "1", lambda b: b.efficiency_measured_uncertainty),
)
#: the time columns: seconds since the first exported row, and the exact log time
TIME_COLUMN, LOG_TIME_COLUMN = Column("time", "s", lambda b: None), Column("log_time", "ns", lambda b: b.t_ns)
#: kind of export -> what the file is
EXPORT_KINDS = {"csv": "CSV", "parquet": "Parquet", "mf4": "MDF4"}


def _values(b: BatchEstimate) -> list[np.ndarray]:
    n = len(b.t_ns)
    out = []
    for c in COLUMNS:
        v = c.take(b)
        out.append(np.full(n, np.nan) if v is None else np.asarray(v, np.float64))
    return out


class Export:
    """One export file being written: :meth:`add` each batch of estimates, then :meth:`close`."""

    def __init__(self, kind: str, path: str | Path) -> None:
        if kind not in EXPORT_KINDS:
            raise ValueError(f"unknown export kind {kind!r}; one of {', '.join(EXPORT_KINDS)}")
        self.kind, self.path = kind, Path(path)
        self.rows = 0
        self._start_ns: int | None = None
        self._partial = partial_path(self.path)
        self._writer = None
        self._mdf = None

    def add(self, b: BatchEstimate) -> None:
        """The rows of one batch (in time order after the batches before it)."""
        if not len(b.t_ns):
            return
        t_ns = np.asarray(b.t_ns, np.int64)
        if self._start_ns is None:
            self._start_ns = int(t_ns[0])
        time_s = (t_ns - self._start_ns) * 1e-9
        with named(self.path):
            getattr(self, f"_add_{self.kind}")(time_s, t_ns, _values(b))
        self.rows += len(t_ns)

    def _table(self, time_s: np.ndarray, t_ns: np.ndarray, values: list[np.ndarray], headers: bool):
        import pyarrow as pa

        cols = (TIME_COLUMN, LOG_TIME_COLUMN, *COLUMNS)
        fields = [pa.field(c.header if headers else c.name, pa.int64() if c is LOG_TIME_COLUMN else pa.float64(),
                           metadata=None if headers else {"unit": c.unit}) for c in cols]
        return pa.Table.from_arrays([pa.array(time_s), pa.array(t_ns), *(pa.array(v) for v in values)],
                                    schema=pa.schema(fields))

    def _add_csv(self, time_s, t_ns, values) -> None:
        import pyarrow.csv as pacsv

        table = self._table(time_s, t_ns, values, headers=True)
        if self._writer is None:
            self._writer = pacsv.CSVWriter(str(self._partial), table.schema)
        self._writer.write_table(table)

    def _add_parquet(self, time_s, t_ns, values) -> None:
        import pyarrow.parquet as pq

        table = self._table(time_s, t_ns, values, headers=False)
        if self._writer is None:
            self._writer = pq.ParquetWriter(str(self._partial), table.schema, compression="zstd")
        self._writer.write_table(table)

    def _add_mf4(self, time_s, t_ns, values) -> None:
        from asammdf import MDF, Signal

        if self._mdf is None:
            self._mdf = MDF(version="4.10")
            self._mdf.start_time = datetime.datetime.fromtimestamp(self._start_ns * 1e-9, datetime.UTC)
            self._mdf.append([Signal(v, time_s, name=c.name, unit=c.unit) for c, v in zip(COLUMNS, values)],
                             comment="rollergear replay: estimates with their inputs")
        else:
            self._mdf.extend(0, [(time_s, None), *((v, None) for v in values)])

    def close(self, commit_file: bool = True) -> None:
        """Finish the file and put it in place (``commit_file``), or remove what was written."""
        try:
            with named(self.path):
                if commit_file and self._writer is None and self._mdf is None:  # no rows: the columns alone
                    self._start_ns = 0
                    getattr(self, f"_add_{self.kind}")(np.empty(0), np.empty(0, np.int64),
                                                       [np.empty(0)] * len(COLUMNS))
                if self._writer is not None:
                    self._writer.close()
                if self._mdf is not None:
                    if commit_file:  # asammdf wants its own suffix: saved as .NAME.<random>.partial.mf4
                        saved = Path(self._mdf.save(self._mdf_partial(), overwrite=True))
                        os.replace(saved, self._partial)
                    self._mdf.close()
            if commit_file:
                commit(self._partial, self.path)
            else:
                discard(self._partial)
        except BaseException:
            discard(self._partial)
            if self._mdf is not None:
                discard(self._mdf_partial())
            raise

    def _mdf_partial(self) -> Path:
        return self._partial.with_name(self._partial.name + ".mf4")

