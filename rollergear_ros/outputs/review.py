"""Rerun recordings for review: batched (``send_columns``) logging and a ready blueprint.

rerun-sdk is pinned (0.41): ``rr.Scalars``/``rr.SeriesLines``, ``rr.TimeColumn(..., timestamp=)``
with ``datetime64[ns]``; recordings are read back with ``rerun.chunk.RrdReader``.  No rclpy.
"""

from __future__ import annotations

import errno
import os
import uuid
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ..base import atomic

TIMELINE = "log_time"
#: longest a closing recording waits for a streamed viewer to take the data (seconds)
FLUSH_TIMEOUT_S = 10.0
#: ... for a viewer only (no file): rerun's gRPC client then waits up to 5 s more on its own to
#: connect before it drops what it holds, and a node's shutdown stays within 10 s
CONNECT_FLUSH_TIMEOUT_S = 2.0

#: the entities, one tree per unit (a view each): what a reviewer compares shares an axis
DRIVE_TORQUE = "/inputs/torque/drive_nm"
OUTPUT_TORQUE = "/inputs/torque/output_nm"
DRIVE_SPEED = "/inputs/speed/drive_rad_s"
OUTPUT_SPEED = "/inputs/speed/output_rad_s"
OIL_TEMPERATURE = "/inputs/temperature/oil_c"
LOSS_TORQUE = "/loss/torque/total_nm"
BREAKDOWN = "/loss/torque/breakdown"  #: + ``/<term>_nm`` and ``/effects_nm``
LOSS_POWER = "/loss/power/total_w"
EFFICIENCY = "/efficiency/efficiency_pct"
EFFICIENCY_MEASURED = "/efficiency/measured_pct"  #: per sample, where the output torque is measured
EFFICIENCY_WINDOW = "/efficiency/window/measured_pct"  #: energy-weighted over node.efficiency_window_s
EFFICIENCY_WINDOW_LOW = "/efficiency/window/minus_u_pct"  #: ... less its standard uncertainty
EFFICIENCY_WINDOW_HIGH = "/efficiency/window/plus_u_pct"  #: ... plus it
MEASURED_LOSS = "/residual/measured_loss_nm"
ESTIMATED_LOSS = "/residual/estimated_loss_nm"
RESIDUAL = "/residual/residual_nm"
ADAPTATION = "/adaptation"  #: + ``/<effect>``
EVENTS = "/events"  #: change alarms, skipped samples, stale inputs (text log on the timeline)

#: entity -> legend name
SERIES: dict[str, str] = {
    DRIVE_TORQUE: "drive torque [N·m]",
    OUTPUT_TORQUE: "output torque, measured [N·m]",
    DRIVE_SPEED: "drive speed [rad/s]",
    OUTPUT_SPEED: "output speed, measured [rad/s]",
    OIL_TEMPERATURE: "oil temperature [°C]",
    LOSS_TORQUE: "loss torque (signed) [N·m]",
    LOSS_POWER: "loss power [W]",
    EFFICIENCY: "efficiency, model [%]",
    EFFICIENCY_MEASURED: "efficiency, measured per sample [%]",
    EFFICIENCY_WINDOW: "efficiency, measured over the window [%]",
    EFFICIENCY_WINDOW_LOW: "... − its standard uncertainty [%]",
    EFFICIENCY_WINDOW_HIGH: "... + its standard uncertainty [%]",
    MEASURED_LOSS: "measured loss [N·m]",
    ESTIMATED_LOSS: "estimated loss [N·m]",
    RESIDUAL: "residual (measured − estimated) [N·m]",
}


def blueprint():
    """The layout a reviewer wants open at once: a view per unit, events below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Grid(
                rrb.TimeSeriesView(origin="/inputs/torque", name="Torque: drive and output [N·m]"),
                rrb.TimeSeriesView(origin="/inputs/speed", name="Speed: drive and output [rad/s]"),
                rrb.TimeSeriesView(origin="/loss/torque", name="Loss torque and its breakdown [N·m]"),
                rrb.TimeSeriesView(origin="/loss/power", name="Loss power [W]"),
                rrb.TimeSeriesView(origin="/efficiency", name="Efficiency: model, measured, window ± u [%]"),
                rrb.TimeSeriesView(origin="/residual", name="Measured vs estimated loss, residual [N·m]"),
                rrb.TimeSeriesView(origin="/inputs/temperature", name="Oil temperature [°C]"),
                rrb.TimeSeriesView(origin=ADAPTATION, name="Adapted effect coefficients"),
                grid_columns=2,
            ),
            rrb.TextLogView(origin=EVENTS, name="Events: change alarms, skipped samples, stale inputs"),
            row_shares=[4, 1],
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=False,
    )


def estimate_series(b, breakdown_terms: Iterable[str] = (), with_effects: bool = False
                    ) -> list[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """The series of a batch of estimates (:class:`~core.estimator.BatchEstimate`), grouped by the
    samples they exist at: ``[(t_ns, {entity: values}), ...]``.

    ``breakdown_terms``: the paper's terms to draw (not those whose coefficient is 0, which would
    only draw a zero line); ``with_effects``: the accepted effects' share of the loss.  A measured
    output, an oil temperature or a residual only where the sample has one.
    """
    sign = np.sign(b.loss_torque_nm)
    main = {DRIVE_TORQUE: b.torque_nm, DRIVE_SPEED: b.speed_rad_s, LOSS_TORQUE: b.loss_torque_nm,
            LOSS_POWER: b.loss_power_w, EFFICIENCY: 100.0 * b.efficiency}
    for key in breakdown_terms:
        if key in b.breakdown_nm:
            main[f"{BREAKDOWN}/{key}_nm"] = b.breakdown_nm[key] * sign
    if with_effects and b.effects_nm is not None:
        main[f"{BREAKDOWN}/effects_nm"] = b.effects_nm * sign
    main.update({f"{ADAPTATION}/{name}": coef for name, coef in b.coefficients.items()})
    groups = [(b.t_ns, main)]
    res = np.isfinite(b.residual_nm)
    if res.any():
        groups.append((b.t_ns[res], {MEASURED_LOSS: b.measured_loss_nm[res],
                                     ESTIMATED_LOSS: np.abs(b.loss_torque_nm[res]), RESIDUAL: b.residual_nm[res]}))
    measured = None if b.efficiency_measured is None else 100.0 * b.efficiency_measured
    for entity, values in ((OIL_TEMPERATURE, b.temperature_c), (OUTPUT_TORQUE, b.out_torque_nm),
                           (OUTPUT_SPEED, b.out_speed_rad_s), (EFFICIENCY_MEASURED, measured)):
        if values is not None:
            have = np.isfinite(values)
            if have.any():
                groups.append((b.t_ns[have], {entity: values[have]}))
    return groups


class SkipEvents:
    """Skipped samples as events: the counts that grew since the last call, as one line."""

    def __init__(self) -> None:
        self._seen: dict[str, int] = {}

    def since_last(self, counts: Mapping[str, int]) -> str | None:
        grown = {k: v - self._seen.get(k, 0) for k, v in counts.items() if v > self._seen.get(k, 0)}
        self._seen = dict(counts)
        if not grown:
            return None
        return "skipped " + ", ".join(f"{n:,} {k.replace('_', ' ')}" for k, n in sorted(grown.items()))


class RerunLog:
    """A rerun recording written to an ``.rrd`` file and/or streamed to a viewer."""

    def __init__(self, application_id: str = "rollergear", rrd_path: str | Path | None = None,
                 connect_url: str | None = None, breakdown_terms: Iterable[str] = (),
                 with_effects: bool = False, replace_atomically: bool = False) -> None:
        """``breakdown_terms``, ``with_effects``: what :meth:`send_estimates` draws of the loss's
        breakdown (:func:`estimate_series`).  ``replace_atomically``: the ``.rrd`` is written beside
        ``rrd_path`` and renamed onto it by :meth:`close` (a replay's output; the node's live
        recording is written in place, so that a kill keeps what came)."""
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream(application_id, recording_id=str(uuid.uuid4()))
        bp = blueprint()
        sinks = []
        self.rrd_path = Path(rrd_path) if rrd_path else None
        self._flush_timeout_s = CONNECT_FLUSH_TIMEOUT_S if connect_url and not rrd_path else FLUSH_TIMEOUT_S
        self._partial = atomic.partial_path(rrd_path) if rrd_path and replace_atomically else None
        self._pump: _FilePump | None = None
        if rrd_path:
            Path(rrd_path).parent.mkdir(parents=True, exist_ok=True)
            if self._partial is not None:  # rerun writes into a pipe this process drains into the file
                self._pump = _FilePump(self._partial)
                rrd_path = self._pump.fifo
            sinks.append(rr.FileSink(str(rrd_path)))
        if connect_url:
            sinks.append(rr.GrpcSink(connect_url))
        if len(sinks) == 1 and rrd_path:
            self.rec.save(str(rrd_path), default_blueprint=bp)
        elif sinks:
            self.rec.set_sinks(*sinks, default_blueprint=bp)
        self._named: set[str] = set()
        self.breakdown_terms = tuple(breakdown_terms)
        self.with_effects = with_effects
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

    def send_estimates(self, b) -> None:
        """A batch of estimates (:func:`estimate_series`) and its change alarms as events."""
        for t_ns, series in estimate_series(b, self.breakdown_terms, self.with_effects):
            self.send(t_ns, series)
        if b.alarms_t_ns and len(b.t_ns):
            lo, hi = int(b.t_ns[0]), int(b.t_ns[-1])
            alarms = [t for t in b.alarms_t_ns if lo <= t <= hi]
            self.events(alarms, ["residual change alarm: the loss behaves differently from here"] * len(alarms),
                        "WARN")

    def send_windows(self, windows) -> None:
        """The measured efficiency's windows (:class:`~core.measured.WindowValue`, in time order) with
        their ± one standard uncertainty, at the second each ends at."""
        if not windows:
            return
        eta = 100.0 * np.array([w.efficiency for w in windows])
        u = 100.0 * np.array([w.uncertainty for w in windows])
        self.send(np.array([w.end_ns for w in windows], dtype=np.int64),
                  {EFFICIENCY_WINDOW: eta, EFFICIENCY_WINDOW_LOW: eta - u, EFFICIENCY_WINDOW_HIGH: eta + u})

    def events(self, t_ns: Sequence[int], texts: Sequence[str], level: str = "INFO") -> None:
        """Text events on the timeline (:data:`EVENTS`)."""
        if not len(t_ns):
            return
        times = self.rr.TimeColumn(TIMELINE, timestamp=np.asarray(t_ns, dtype=np.int64).astype("datetime64[ns]"))
        self.rec.send_columns(EVENTS, indexes=[times],
                              columns=self.rr.TextLog.columns(text=list(texts), level=[level] * len(texts)))

    def close(self, commit: bool = True) -> None:
        """Flush and end the recording; with ``replace_atomically`` put the ``.rrd`` in place (or,
        ``commit=False``, remove it)."""
        if self.closed:
            return
        self.closed = True
        if self._partial is None:
            try:
                # bounded: the default waits forever for a viewer that never answers (raises on timeout)
                self.rec.flush(timeout_sec=self._flush_timeout_s)
            finally:
                self.rec.disconnect()
            return
        try:
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except BaseException:
            commit = False
            raise
        finally:
            self.rec.disconnect()  # rerun closes the pipe: the pump sees its end
            error = self._pump.finish()
            if error is not None or not commit:
                atomic.discard(self._partial)
        if error is not None:
            raise OSError(error.errno, error.strerror or str(error), str(self.rrd_path))
        if not commit:
            return
        with atomic.named(self.rrd_path):
            atomic.commit(self._partial, self.rrd_path)


class _FilePump:
    """A FIFO that rerun's file sink writes to and a thread that copies it into ``path``.

    rerun's own file sink hangs (in ``save`` or ``flush``) when the disk refuses a write; here
    rerun only ever writes to a reader that keeps reading, and a failed write to the disk is this
    process's OSError, naming the output (the rest of the stream is read and dropped)."""

    def __init__(self, path: Path) -> None:
        import tempfile
        import threading

        self.path = path
        self._folder = tempfile.mkdtemp(prefix="rollergear_rrd_")
        self.fifo = os.path.join(self._folder, "rrd.fifo")
        os.mkfifo(self.fifo)
        self.error: OSError | None = None
        self._thread = threading.Thread(target=self._run, name="rrd-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            with open(self.fifo, "rb") as src, open(self.path, "wb") as dst:
                while block := src.read(1 << 20):
                    if self.error is None:
                        try:
                            dst.write(block)
                        except OSError as exc:
                            self.error = exc
                try:
                    dst.flush()
                except OSError as exc:
                    self.error = self.error or exc
        except OSError as exc:
            self.error = self.error or exc

    def finish(self, timeout_s: float = FLUSH_TIMEOUT_S) -> OSError | None:
        """Wait for the stream's end; the write's error, if any."""
        import shutil

        self._thread.join(timeout_s)
        if self._thread.is_alive():  # rerun never opened or never closed the pipe
            try:  # open its write end once: the reader sees an end and stops
                os.close(os.open(self.fifo, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
            self._thread.join(1.0)
            self.error = self.error or OSError(errno.EIO, "rerun did not finish writing the recording")
        shutil.rmtree(self._folder, ignore_errors=True)
        return self.error


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


def read_rrd_events(path: str | Path) -> list[tuple[int, str, str]]:
    """The text events of an ``.rrd`` (:data:`EVENTS`), read with rerun's own loader: ``(time ns,
    level, text)`` in time order."""
    from rerun.chunk import RrdReader

    events = []
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path != EVENTS:
            continue
        rb = chunk.to_record_batch()
        names = rb.schema.names
        t = rb.column(names.index(TIMELINE)).cast("int64").to_pylist()
        level = rb.column(names.index("TextLog:level")).to_pylist()
        text = rb.column(names.index("TextLog:text")).to_pylist()
        events += [(ti, lv[0], tx[0]) for ti, lv, tx in zip(t, level, text)]
    return sorted(events)
