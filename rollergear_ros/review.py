"""Rerun recordings for review: batched (``send_columns``) logging and a ready blueprint.

rerun-sdk is pinned (0.41): ``rr.Scalars``/``rr.SeriesLines``, ``rr.TimeColumn(..., timestamp=)``
with ``datetime64[ns]``; recordings are read back with ``rerun.chunk.RrdReader``.  No rclpy.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from collections.abc import Mapping

import numpy as np

TIMELINE = "log_time"
#: longest a closing recording waits for a streamed viewer to take the data (seconds)
FLUSH_TIMEOUT_S = 10.0

#: entity -> (legend name) for the series a reviewer wants
SERIES: dict[str, str] = {
    "/inputs/torque_nm": "drive torque [N·m]",
    "/inputs/speed_rad_s": "drive speed [rad/s]",
    "/inputs/oil_temperature_c": "oil temperature [°C]",
    "/loss/torque_nm": "loss torque (signed) [N·m]",
    "/loss/power_w": "loss power [W]",
    "/efficiency/efficiency": "efficiency [-]",
    "/residual/measured_loss_nm": "measured loss [N·m]",
    "/residual/estimated_loss_nm": "estimated loss [N·m]",
    "/residual/residual_nm": "residual (measured − estimated) [N·m]",
}


def blueprint():
    """The layout a reviewer wants open at once."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Grid(
            rrb.TimeSeriesView(origin="/inputs", name="Drive torque, speed, oil temperature"),
            rrb.TimeSeriesView(origin="/loss", name="Loss torque and its breakdown"),
            rrb.TimeSeriesView(origin="/efficiency", name="Efficiency"),
            rrb.TimeSeriesView(origin="/residual", name="Measured vs estimated loss, residual"),
            rrb.TimeSeriesView(origin="/adaptation", name="Adapted effect coefficients"),
            grid_columns=2,
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=False,
    )


class RerunLog:
    """A rerun recording written to an ``.rrd`` file and/or streamed to a viewer."""

    def __init__(self, application_id: str = "rollergear", rrd_path: str | Path | None = None,
                 connect_url: str | None = None) -> None:
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream(application_id, recording_id=str(uuid.uuid4()))
        bp = blueprint()
        sinks = []
        if rrd_path:
            Path(rrd_path).parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(rrd_path)))
        if connect_url:
            sinks.append(rr.GrpcSink(connect_url))
        if len(sinks) == 1 and rrd_path:
            self.rec.save(str(rrd_path), default_blueprint=bp)
        elif sinks:
            self.rec.set_sinks(*sinks, default_blueprint=bp)
        self._named: set[str] = set()
        self.closed = False

    def _name(self, entity: str, label: str) -> None:
        if entity not in self._named:
            self.rec.log(entity, self.rr.SeriesLines(names=label), static=True)
            self._named.add(entity)

    def send(self, t_ns: np.ndarray, series: Mapping[str, np.ndarray], labels: Mapping[str, str] | None = None) -> None:
        """Log several series sharing one time column, one ``send_columns`` call each."""
        if len(t_ns) == 0:
            return
        times = self.rr.TimeColumn(TIMELINE, timestamp=np.asarray(t_ns, dtype=np.int64).astype("datetime64[ns]"))
        for entity, values in series.items():
            self._name(entity, (labels or {}).get(entity) or SERIES.get(entity) or entity.rsplit("/", 1)[-1])
            self.rec.send_columns(entity, indexes=[times],
                                  columns=self.rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            # bounded: the default waits forever for a viewer that never answers (raises on timeout)
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        finally:
            self.rec.disconnect()


def read_rrd_series(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Read an ``.rrd`` back with rerun's own loader: entity -> (time ns, values), time-sorted."""
    from rerun.chunk import RrdReader

    acc: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        rb = chunk.to_record_batch()
        names = rb.schema.names
        if TIMELINE not in names or "Scalars:scalars" not in names:
            continue
        t = rb.column(names.index(TIMELINE)).cast("int64").to_numpy()
        v = np.array([x[0] if x else np.nan for x in rb.column(names.index("Scalars:scalars")).to_pylist()],
                     dtype=float)
        acc.setdefault(chunk.entity_path, []).append((t, v))
    out = {}
    for entity, parts in acc.items():
        t = np.concatenate([p[0] for p in parts])
        v = np.concatenate([p[1] for p in parts])
        order = np.argsort(t, kind="stable")
        out[entity] = (t[order], v[order])
    return out
