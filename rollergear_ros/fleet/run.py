"""A fleet's drive logs on Dask distributed: the run that fills the fleet table as its tasks land.

``rollergear fleet replay|calibrate LOGS… --out DIR`` finds the recordings (:mod:`.logs`) and
runs one task (:mod:`.tasks`) per recording (``replay``) or per gearbox and time window
(``calibrate``) on a Dask client (:mod:`.cluster`).  Results land in ``DIR/fleet.parquet`` (replay:
one row per recording) or ``DIR/fleet_calibrate.parquet`` (one row per gearbox and window) as they
finish, rewritten atomically, so an interrupted run keeps what it did and a rerun with the same
``--out`` skips every recording already in the table (keyed by path, size and modification time).
A long recording is replayed in time slices (one task each); its row is made of theirs when the
last one lands, and the slices done are kept in ``DIR/fleet_slices.parquet`` so that a resumed run
does not redo them.  The drift report is :mod:`.report`.  No rclpy import.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..base.atomic import replacing
from ..core.params import Config, SensorParams, config_to_yaml
from .logs import SLICE_MESSAGES, Recording, time_slices
from ..calibration.samples import TimeSpan
from .tasks import CalibrationWindow, calibrate_task, combine_slices, replay_task

__all__ = ["FLEET_TABLE", "CALIBRATE_TABLE", "SLICES_TABLE", "FleetRun", "FleetTable", "read_table", "run_calibrate",
           "run_replay", "settings_fingerprint", "window_parts"]

FLEET_TABLE = "fleet.parquet"
CALIBRATE_TABLE = "fleet_calibrate.parquet"
SLICES_TABLE = "fleet_slices.parquet"  #: the time slices done of recordings not yet complete


# ------------------------------------------------------------------------------------ the table
def read_table(path: Path) -> list[dict]:
    """The rows of a fleet table (empty when there is none yet)."""
    if not path.exists():
        return []
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pylist()


def _write_table(path: Path, rows: list[dict]) -> None:
    """Rewrite the table atomically (a reader, or a killed run, never sees half of it)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    columns: dict[str, None] = {}
    for r in rows:
        columns.update(dict.fromkeys(r))
    table = pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows])
    with replacing(path) as partial:
        pq.write_table(table, partial)


#: a unit of the fleet table: its key and the tasks (key, function, arguments) that make its row
Unit = tuple[str, list[tuple[str, Callable, tuple]]]


def settings_fingerprint(config: Config, channels: str | None, *extra: object) -> str:
    """What a row's result depends on besides its recordings: the parameters, the channel map's
    text and ``extra`` (the calibration window), as a short hash (the tables' ``settings``)."""
    import hashlib

    text = config_to_yaml(config) + "\n--\n" + (Path(channels).read_text(encoding="utf-8") if channels else "")
    text += "".join(f"\n--\n{e!r}" for e in extra)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class FleetRun:
    """How a fleet job runs: on which Dask client, with which parameters and channel map, and how it
    tells what it does (a progress bar, notes)."""

    client: Any
    config: Config
    channels: str | None = None  #: channel map of the recordings that are not MCAP or rosbag2
    progress: bool = False
    note: Callable[[str], None] = field(default=lambda m: None)


@dataclass(frozen=True)
class FleetTable:
    """Where a fleet job's rows go: the table, what its units are called (in notes), the settings
    that make a row current (:func:`settings_fingerprint`) and the table of units' finished parts."""

    path: Path
    what: str
    settings: str = ""
    parts: Path | None = None


def _run(run: FleetRun, table: FleetTable, units: list[Unit]) -> tuple[list[dict], int]:
    """Run the units not yet in ``table`` with its settings (rows made with others are done again and
    replaced); a unit's row (:func:`combine_slices` of its tasks' rows) lands when its last task
    does.  ``table.parts`` keeps the rows of the tasks of units not yet complete (a resumed run does
    not redo them)."""
    from dask.distributed import as_completed

    from ..base.progress import TimedProgress

    rows = _current_rows(table, run.note)
    done = {r["key"] for r in rows}
    todo = [u for u in units if u[0] not in done]
    skipped = len(units) - len(todo)
    if skipped:
        run.note(f"{skipped} of {len(units)} {table.what} already in {table.path}: not done again")
    if not todo:
        return rows, 0
    progress = _Progress(table, rows, todo, _kept_parts(table, todo, run.note), run.config.sensors)
    futures = []
    for key, tasks in todo:
        for part_key, fn, args in tasks:
            if part_key not in progress.parts[key]:
                future = run.client.submit(fn, *args, key=f"rollergear-{abs(hash(part_key))}-{len(futures)}",
                                           pure=False)
                progress.unit_of[future.key] = (key, part_key)
                futures.append(future)
    with TimedProgress("fleet", len(futures), "task", enabled=run.progress) as bar:
        for future in as_completed(futures):
            key, part_key = progress.unit_of[future.key]
            try:
                row = future.result() | {"settings": table.settings}
            except Exception as exc:  # noqa: BLE001 - the task's worker died (KilledWorker): its row fails
                row = {"key": part_key, "status": "failed", "settings": table.settings,
                       "reason": f"its task could not finish: {type(exc).__name__}: {exc}"}
                row |= _unit_identity(todo, key) | ({"recording_key": key, "slice": part_key.rsplit("|slice ", 1)[-1]}
                                                   if part_key != key else {})
            progress.add(key, part_key, row)
            bar.update(1)
            running = sum(f.status == "pending" for f in futures)
            bar.stage = (f"{table.what} {progress.finished}/{len(todo)}, failed {progress.failed}, running "
                         f"{min(running, len(run.client.scheduler_info()['workers']))}, "
                         f"{progress.samples / max(time.perf_counter() - progress.t0, 1e-9):,.0f} samples/s")
            if time.perf_counter() - progress.last_write > 1.0:
                progress.write()
    progress.write()
    return rows, len(todo)


def _current_rows(table: FleetTable, note: Callable[[str], None]) -> list[dict]:
    """The table's rows made with its settings (the others are dropped, to be done again)."""
    rows = read_table(table.path)
    stale = [r for r in rows if r.get("settings") != table.settings]
    if stale:
        note(f"{len(stale)} rows of {table.path} were made with other parameters, channel map or window: done again")
        rows = [r for r in rows if r.get("settings") == table.settings]
    return rows


def _kept_parts(table: FleetTable, todo: list[Unit], note: Callable[[str], None]) -> dict[str, dict[str, dict]]:
    """Unit -> the rows of its tasks already finished by an interrupted run (from ``table.parts``)."""
    kept = ({r["key"]: r for r in read_table(table.parts) if r.get("settings") == table.settings}
            if table.parts else {})
    parts = {key: {k: kept[k] for k, _, _ in tasks if k in kept} for key, tasks in todo}
    if kept:
        note(f"{sum(map(len, parts.values()))} time slices already in {table.parts}: not done again")
    return parts


class _Progress:
    """The rows of a fleet run as its tasks finish: a unit's row when its last task's is in, the
    counts the progress bar shows, and the tables written as it goes."""

    def __init__(self, table: FleetTable, rows: list[dict], todo: list[Unit], parts: dict[str, dict[str, dict]],
                 sensors: SensorParams | None = None):
        self.table, self.rows, self.parts, self.sensors = table, rows, parts, sensors
        self.tasks_of = {key: [k for k, _, _ in tasks] for key, tasks in todo}
        self.unit_of: dict = {}  # future key -> (unit key, task key)
        self.failed = self.samples = self.finished = 0
        self.t0 = time.perf_counter()
        self.last_write = 0.0
        for key in self.tasks_of:  # units whose tasks were all done before an interruption
            if len(parts[key]) == len(self.tasks_of[key]):
                self._complete(key)

    def add(self, key: str, part_key: str, row: dict) -> None:
        """A task's row; the unit's row when it was the last."""
        self.parts[key][part_key] = row
        self.samples += int(row.get("samples") or 0)
        if len(self.parts[key]) == len(self.tasks_of[key]):
            self._complete(key)

    def _complete(self, key: str) -> None:
        row = combine_slices([self.parts[key][k] for k in self.tasks_of[key]], self.sensors) \
            | {"settings": self.table.settings}
        self.rows.append(row)
        self.failed += row["status"] != "ok"
        self.finished += 1

    def write(self) -> None:
        """The table, and the parts of the units not yet complete (none: the parts table goes)."""
        _write_table(self.table.path, self.rows)
        self.last_write = time.perf_counter()
        parts_table = self.table.parts
        if parts_table is None:
            return
        pending = [r for key, got in self.parts.items() if len(got) < len(self.tasks_of[key]) for r in got.values()]
        if pending:
            _write_table(parts_table, pending)
        elif parts_table.exists():
            parts_table.unlink()


def _unit_identity(todo: list[Unit], key: str) -> dict:
    """What a failed task's row says of its unit: the gearbox and recording (or window) it was for."""
    for unit_key, tasks in todo:
        if unit_key == key:
            args = tasks[0][2]
            if args and isinstance(args[0], Recording):
                return {"gearbox_id": args[0].gearbox_id, "recording": args[0].path}
            if args and isinstance(args[0], CalibrationWindow):
                return {"gearbox_id": args[0].gearbox_id, "window": args[0].window}
    return {}


def run_replay(recs: Sequence[Recording], out_dir: Path, run: FleetRun,
               slice_messages: int = SLICE_MESSAGES) -> tuple[list[dict], int]:
    """Replay every recording on the cluster (a long one in time slices of about ``slice_messages``
    messages); returns the table's rows and how many recordings were run now."""
    out_dir.mkdir(parents=True, exist_ok=True)
    config, channels = run.config, run.channels
    units: list[Unit] = []
    for r in recs:
        windows = time_slices(r, slice_messages)
        if len(windows) == 1:
            units.append((r.key, [(r.key, replay_task, (r, config, channels))]))
        else:
            n = len(windows)
            units.append((r.key, [(f"{r.key}|slice {i}/{n}", replay_task, (r, config, channels, w, f"{i}/{n}"))
                                  for i, w in enumerate(windows, 1)]))
    return _run(run, FleetTable(out_dir / FLEET_TABLE, "recordings", settings_fingerprint(config, channels),
                                out_dir / SLICES_TABLE), units)


def run_calibrate(recs: Sequence[Recording], out_dir: Path, run: FleetRun, window_ns: int,
                  assume: Sequence[str] = ()) -> tuple[list[dict], int]:
    """Calibrate every gearbox over each time window (``assume``: as :func:`~calibration.calibrate.calibrate`'s);
    a recording that runs across windows is split between them, each window's task reading only its part;
    returns the table's rows and how many ran now."""
    out_dir.mkdir(parents=True, exist_ok=True)
    groups: dict[tuple[str, int], list[tuple[Recording, TimeSpan]]] = {}
    for r in recs:
        for w, cut in window_parts(r, window_ns):
            groups.setdefault((r.gearbox_id, w), []).append((r, cut))
    units: list[Unit] = []
    for (gid, w), parts in sorted(groups.items()):
        win = CalibrationWindow(gid, w, window_ns, tuple(r for r, _ in parts), tuple(c for _, c in parts))
        units.append((win.key, [(win.key, calibrate_task, (win, run.config, run.channels, tuple(assume)))]))
    settings = settings_fingerprint(run.config, run.channels, window_ns, sorted(assume))
    return _run(run, FleetTable(out_dir / CALIBRATE_TABLE, "windows", settings), units)


def window_parts(rec: Recording, window_ns: int) -> list[tuple[int, TimeSpan]]:
    """The windows (numbers of ``window_ns`` since 1970) a recording's span falls in, each with the part of
    it there (``[start, end)`` in ns; None where the recording begins or ends inside the window).  Without a
    span (a table, a file whose summary has none) the recording is one part, in its start's (or modification
    time's) window."""
    start = rec.start_ns if rec.start_ns is not None else int(rec.mtime * 1e9)
    if rec.start_ns is None or rec.end_ns is None or rec.end_ns // window_ns == start // window_ns:
        return [(start // window_ns, (None, None))]
    first, last = start // window_ns, rec.end_ns // window_ns
    return [(w, (None if w == first else w * window_ns, None if w == last else (w + 1) * window_ns))
            for w in range(first, last + 1)]
