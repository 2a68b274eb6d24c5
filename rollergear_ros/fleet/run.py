"""A fleet's drive logs on Dask distributed: replay and calibrate many recordings, the fleet table.

``rollergear fleet replay|calibrate LOGS… --out DIR`` finds the recordings (files, folders,
globs; local or any ``fsspec`` URL), names each one's gearbox (the ``rollergear`` metadata
record's ``gearbox_id``, else its folder), and runs one task per recording (``replay``) or per
gearbox and time window (``calibrate``) on a Dask cluster -- a ``LocalCluster`` of worker
processes by default, ``--scheduler ADDRESS`` for a real one.  Each task is the very replay or
calibrate of a single recording; results land in ``DIR/fleet.parquet`` (replay: one row per
recording) or ``DIR/fleet_calibrate.parquet`` (one row per gearbox and window) as they finish,
rewritten atomically, so an interrupted run keeps what it did and a rerun with the same
``--out`` skips every recording already in the table (keyed by path, size and modification
time).  A long recording is replayed in time slices (:func:`time_slices`, one task each, so that
a task stays well under a minute); its row is made of theirs when the last one lands, and the
slices done are kept in ``DIR/fleet_slices.parquet`` so that a resumed run does not redo them.
A recording that cannot be read is a ``failed`` row with its reason; the rest go on.
The drift report is :mod:`.report`.  No rclpy import.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..base.atomic import replacing
from ..base.errors import RollergearError, UsageError
from ..base.stopping import children_spared_interrupts
from ..sources.formats import is_format, recording_suffixes
from ..base.interface import Metadata
from ..core.measured import EnergyBalance
from ..core.params import Config, SensorParams, config_to_yaml

__all__ = ["FLEET_TABLE", "CALIBRATE_TABLE", "SLICES_TABLE", "SLICE_MESSAGES", "CalibrationWindow", "FleetRun",
           "FleetTable", "Recording", "combine_slices", "dask_client", "discover", "read_table", "run_calibrate",
           "run_replay", "settings_fingerprint", "time_slices"]

FLEET_TABLE = "fleet.parquet"
CALIBRATE_TABLE = "fleet_calibrate.parquet"
SLICES_TABLE = "fleet_slices.parquet"  #: the time slices done of recordings not yet complete
#: a recording of more messages is replayed in time slices of about this many: a task of seconds to
#: a minute, short enough to spread an hours-long recording over the workers
SLICE_MESSAGES = 30_000_000
GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class Recording:
    """One log of the fleet."""

    path: str  #: local path or fsspec URL
    gearbox_id: str
    size: int
    mtime: float
    start_ns: int | None = None  #: first message (MCAP summary), for time windows
    end_ns: int | None = None  #: last message (MCAP summary), for time slices
    messages: int | None = None  #: message count (MCAP summary), for time slices
    problem: str = ""  #: why it cannot be read at all (a FIFO, a symlink loop): its row fails with this

    @property
    def key(self) -> str:
        """What identifies a recording already done: path, size and modification time."""
        return f"{self.path}|{self.size}|{self.mtime:.6f}"


# ------------------------------------------------------------------------------------ discovery
def discover(logs: Sequence[str], group_by: str = "auto", exclude: str | Path | None = None) -> list[Recording]:
    """The recordings under ``logs`` (files, folders, globs; local or fsspec URLs), sorted by
    gearbox and start.  ``group_by``: ``auto`` (metadata ``gearbox_id``, else the folder),
    ``folder`` or ``metadata``.  ``exclude``: a local folder whose files are not recordings (the
    fleet's own output).  A file that cannot be read at all (a FIFO, a device, a symlink loop) is
    a recording with a ``problem``: its row fails with the reason and the rest go on."""
    import fsspec

    skip = os.path.realpath(exclude) + os.sep if exclude is not None else None
    found: dict[str, Recording] = {}
    for log in logs:
        try:
            fs, root = fsspec.core.url_to_fs(str(log))
        except ImportError as exc:  # s3://, gs://, http:// without their fsspec packages
            raise UsageError(f"{log}: {exc} (pip install it into this environment)") from None
        except ValueError as exc:
            raise UsageError(f"{log}: not a path or URL fsspec can open ({exc})") from None
        local = "file" in (fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,))
        if GLOB_CHARS & set(root):
            paths = sorted(fs.glob(root))
        elif local and os.path.isdir(root):
            paths = _local_files(root)
        elif fs.isdir(root):
            paths = sorted(p for p in fs.find(root) if p.lower().endswith(recording_suffixes()))
        elif fs.exists(root) or os.path.islink(root):
            paths = [root]
        else:
            raise UsageError(f"{log} does not exist")
        for p in paths:
            url = p if local else fs.unstrip_protocol(p)
            if local and skip and os.path.realpath(p).startswith(skip):
                continue
            key = os.path.realpath(p) if local else url  # one file under two names is one recording
            if key in found:
                continue
            problem = _unreadable(p) if local else ""
            if problem:
                found[key] = Recording(url, Path(url).parent.name or "fleet", 0, 0.0, problem=problem)
                continue
            info = fs.info(p)
            mtime = info.get("mtime") or info.get("LastModified") or info.get("updated") or 0.0
            mtime = mtime.timestamp() if hasattr(mtime, "timestamp") else float(mtime)
            gid, span = _identity(url, local, group_by)
            found[key] = Recording(url, gid, int(info.get("size") or 0), mtime, *span)
    if not found:
        raise UsageError(f"no recordings under {', '.join(map(str, logs))} ({', '.join(recording_suffixes())})")
    return sorted(found.values(), key=lambda r: (r.gearbox_id, r.start_ns or 0, r.path))


def _local_files(root: str) -> list[str]:
    """The recordings under a local folder, without following symlinks to folders (a loop would
    never end); a symlink to a file is listed (and checked by :func:`_unreadable`)."""
    paths = []
    for folder, _dirs, files in os.walk(root, followlinks=False):
        paths += [os.path.join(folder, f) for f in files if f.lower().endswith(recording_suffixes())]
    return sorted(paths)


def _unreadable(path: str) -> str:
    """Why a local path cannot be read as a recording ('' when it can be)."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        return f"cannot be read: {exc.strerror or exc}"
    if stat.S_ISDIR(mode):
        return ""
    if not stat.S_ISREG(mode):
        kind = "a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else \
            "a socket" if stat.S_ISSOCK(mode) else "not a regular file"
        return f"is {kind}, not a recording"
    return ""


def _identity(url: str, local: bool, group_by: str) -> tuple[str, tuple[int | None, int | None, int | None]]:
    """Gearbox id and (start, end, message count) of a recording (metadata and summary of a local MCAP)."""
    folder = Path(url.rstrip("/")).parent.name or "fleet"
    gid, span = None, (None, None, None)
    if local and is_format(url, "MCAP"):
        from ..recordings.baginfo import inspect_bag, read_metadata

        try:
            record = read_metadata(url, Metadata.GEARBOX) or {}
            gid = record.get("gearbox_id")
            info = inspect_bag(url)
            if info.message_count:  # log time may start at 0 (relative times of an imported table)
                span = (info.start_ns, info.end_ns, info.message_count) if info.indexed else (info.start_ns, None, None)
        except RollergearError:
            pass  # a damaged recording: it fails in its task, with the reason
    if group_by == "folder":
        gid = folder
    elif group_by == "metadata" and not gid:
        raise UsageError(f"{url} has no '{Metadata.GEARBOX}' metadata record with a gearbox_id (--group-by metadata)")
    return gid or folder, span


def time_slices(rec: Recording, slice_messages: int = SLICE_MESSAGES) -> list[tuple[int | None, int | None]]:
    """The time slices ``[start, end)`` (``None``: open) a recording is replayed in: one, unless
    its MCAP summary counts more than ``slice_messages`` messages; then equal spans of log time."""
    if not rec.messages or rec.start_ns is None or rec.end_ns is None or rec.messages <= slice_messages:
        return [(None, None)]
    n = math.ceil(rec.messages / slice_messages)
    edges = [rec.start_ns + (rec.end_ns - rec.start_ns) * i // n for i in range(1, n)]
    return list(zip([None, *edges], [*edges, None]))


@contextmanager
def _local(url: str) -> Iterator[str]:
    """A local path for ``url`` (a remote file is copied to a temporary folder first)."""
    import fsspec

    fs, path = fsspec.core.url_to_fs(url)
    protocols = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    if "file" in protocols:
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="rollergear_fleet_") as tmp:
        local = os.path.join(tmp, os.path.basename(path))
        fs.get(path, local)
        yield local


# ------------------------------------------------------------------------------------ tasks (run on workers)
def _failed(row: dict, exc: BaseException) -> dict:
    reason = str(exc) if isinstance(exc, RollergearError) else f"{type(exc).__name__}: {exc}"
    return row | {"status": "failed", "reason": reason}


def replay_task(rec: Recording, config: Config, channels: str | None,
                window: tuple[int | None, int | None] = (None, None), part: str = "") -> dict:
    """Replay one recording, or one time slice of it (``window``; ``part``: e.g. ``2/5``); the
    fleet table's row for it (``failed`` with the reason when it cannot)."""
    from ..sources.importer import as_mcap
    from ..replay.run import replay

    row = {"gearbox_id": rec.gearbox_id, "recording": rec.path, "key": rec.key, "status": "ok", "reason": ""}
    if part:
        row |= {"key": f"{rec.key}|slice {part}", "recording_key": rec.key, "slice": part}
    t0 = time.perf_counter()
    if rec.problem:
        return row | {"status": "failed", "reason": rec.problem, "seconds": 0.0}
    try:
        with _local(rec.path) as local, as_mcap([local], channels) as (bag,):
            s, _ = replay(bag, config, show_progress=False, window_ns=None if window == (None, None) else window)
        if s.interrupted:  # a row of part of a recording would pass for the whole
            raise KeyboardInterrupt
    except Exception as exc:  # noqa: BLE001 - one bad recording must not stop the fleet; the row says why
        return _failed(row, exc) | {"seconds": time.perf_counter() - t0}
    if s.estimated == 0 and not part:
        return row | {"status": "failed", "reason": "no sample could be estimated", "samples": s.samples,
                      "seconds": time.perf_counter() - t0}
    return row | {
        "start_ns": s.start_ns, "end_ns": s.end_ns, "duration_s": s.duration_s, "samples": s.samples,
        "estimated": s.estimated, "skipped": sum(s.skipped.values()), "energy_in_j": s.energy_in_j,
        "energy_lost_j": s.energy_lost_j, "mean_efficiency": s.mean_efficiency, "mean_loss_nm": s.mean_loss_nm,
        # energy efficiencies: estimated, and measured where output torque was recorded (core.measured)
        "efficiency_energy": _energy_efficiency(s.energy_in_j, s.energy_lost_j),
        "efficiency_measured": s.efficiency_measured, "efficiency_measured_uncertainty": s.measured_uncertainty,
        "energy_in_measured_j": s.energy_in_measured_j, "energy_lost_measured_j": s.energy_lost_measured_j,
        "measured_balance": s.measured.as_list(),
        "efficiency_samples": s.efficiency_samples, "residual_samples": s.residual_samples,
        "residual_mean_nm": s.residual_mean_nm, "residual_rms_nm": s.residual_rms_nm, "alarms": s.alarms,
        "seconds": time.perf_counter() - t0,
    }


def _energy_efficiency(energy_in_j: float, energy_lost_j: float) -> float:
    """Energy out over energy in (NaN when nothing went through)."""
    return 1.0 - energy_lost_j / energy_in_j if energy_in_j > 0 else math.nan


def combine_slices(parts: Sequence[dict], sensors: SensorParams | None = None) -> dict:
    """A recording's row from the rows of its time slices (in order): sums, and means weighted by
    the samples they are over; the measured efficiency and its uncertainty (``sensors``) from the
    slices' summed energy balances.  One slice is the row itself."""
    if len(parts) == 1:
        return {k: v for k, v in parts[0].items() if k not in ("recording_key", "slice")}
    first = parts[0]
    row = {"gearbox_id": first["gearbox_id"], "recording": first["recording"], "key": first["recording_key"],
           "status": "ok", "reason": "", "slices": len(parts)}
    failed = [p for p in parts if p["status"] != "ok"]
    if failed:
        return row | {"status": "failed", "reason": f"slice {failed[0]['slice']}: {failed[0]['reason']}",
                      "seconds": sum(p.get("seconds") or 0.0 for p in parts)}

    def total(key: str):
        return sum(p[key] for p in parts)

    def mean(key: str, weight: str) -> float:
        n = sum(p[weight] for p in parts if p[weight])
        return sum(p[key] * p[weight] for p in parts if p[weight]) / n if n else math.nan

    starts = [p["start_ns"] for p in parts if p["start_ns"] is not None]
    ends = [p["end_ns"] for p in parts if p["end_ns"] is not None]
    row |= {key: total(key) for key in ("samples", "estimated", "skipped", "energy_in_j", "energy_lost_j",
                                        "energy_in_measured_j", "energy_lost_measured_j", "efficiency_samples",
                                        "residual_samples", "alarms", "seconds")}
    measured = sum((EnergyBalance.from_list(p["measured_balance"]) for p in parts if p.get("measured_balance")),
                   EnergyBalance())
    if row["estimated"] == 0:
        return row | {"status": "failed", "reason": "no sample could be estimated"}
    rms = [(p["residual_rms_nm"] ** 2, p["residual_samples"]) for p in parts if p["residual_samples"]]
    n_res = sum(n for _, n in rms)
    row |= {
        "start_ns": min(starts), "end_ns": max(ends), "duration_s": (max(ends) - min(starts)) * 1e-9,
        "mean_efficiency": mean("mean_efficiency", "efficiency_samples"),
        "mean_loss_nm": mean("mean_loss_nm", "estimated"),
        "efficiency_energy": _energy_efficiency(row["energy_in_j"], row["energy_lost_j"]),
        "efficiency_measured": measured.efficiency,
        "efficiency_measured_uncertainty": measured.uncertainty(sensors or SensorParams()),
        "measured_balance": measured.as_list(),
        "residual_mean_nm": mean("residual_mean_nm", "residual_samples"),
        "residual_rms_nm": math.sqrt(sum(m * n for m, n in rms) / n_res) if n_res else math.nan,
    }
    return row


@dataclass(frozen=True)
class CalibrationWindow:
    """One gearbox's recordings in one time window (number ``window`` of ``window_ns`` each)."""

    gearbox_id: str
    window: int
    window_ns: int
    recordings: tuple[Recording, ...]

    @property
    def key(self) -> str:
        """The window's row key: gearbox, window and its recordings' keys."""
        return _window_key(self.gearbox_id, self.window, self.recordings)


def calibrate_task(win: CalibrationWindow, config: Config, channels: str | None, assume: Sequence[str] = ()) -> dict:
    """Calibrate one gearbox over one time window (all its recordings there); ``assume``: as
    :func:`~calibration.calibrate.calibrate`'s."""
    from contextlib import ExitStack

    from ..calibration.calibrate import CalibrationSettings, calibrate, load_samples
    from ..calibration.samples import power_balance_warning
    from ..sources.importer import as_mcap

    gearbox_id, window, window_ns, recs = win.gearbox_id, win.window, win.window_ns, win.recordings
    row = {"gearbox_id": gearbox_id, "window": window, "window_start_ns": window * window_ns,
           "window_end_ns": (window + 1) * window_ns, "window_start": utc_text(window * window_ns),
           "window_end": utc_text((window + 1) * window_ns), "recordings": len(recs),
           "key": win.key, "status": "ok", "reason": "", "warning": ""}
    t0 = time.perf_counter()
    bad = [r for r in recs if r.problem]
    if bad:
        return row | {"status": "failed", "reason": f"{bad[0].path} {bad[0].problem}", "seconds": 0.0}
    try:
        with ExitStack() as stack:
            local = [stack.enter_context(_local(r.path)) for r in recs]
            bags = stack.enter_context(as_mcap(local, channels))
            data = load_samples(bags, config)
            row["warning"] = power_balance_warning(data) or ""  # as calibrate's command line warns
            result = calibrate(data, config, CalibrationSettings(assume=assume))
    except Exception as exc:  # noqa: BLE001 - one bad window must not stop the fleet; the row says why
        return _failed(row, exc) | {"seconds": time.perf_counter() - t0}
    row |= {"samples": result.samples, "verdict": result.verdict,
            "effects": json.dumps([e.to_json() for e in result.effects]),
            "error_before_rmse_nm": result.error_before.rmse_nm, "error_after_rmse_nm": result.error_after.rmse_nm,
            "calibrated_yaml": config_to_yaml(result.config), "seconds": time.perf_counter() - t0}
    return row | _effect_columns(result.effects)


def _effect_columns(effects) -> dict:
    """Flat columns: one coefficient (and its interval and RMS contribution) per effect, 0 where not found."""
    from ..core.effects import EFFECTS

    row = {}
    found = {e.name: e for e in effects}
    for name, effect in EFFECTS.items():
        e = found.get(name)
        coef = effect.coefficient
        lo, hi = e.ci95[coef] if e else (math.nan, math.nan)
        row |= {f"{name}.{coef}": e.params[coef] if e else 0.0, f"{name}.{coef}_lo": lo,
                f"{name}.{coef}_hi": hi, f"{name}.rms_nm": e.rms_contribution_nm if e else 0.0}
    return row


def utc_text(t_ns: int) -> str:
    """A time as people read it in a table: ISO 8601 in UTC, to the second (``2026-01-05T00:00:00Z``)."""
    from datetime import UTC, datetime

    return datetime.fromtimestamp(t_ns // 10**9, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _window_key(gearbox_id: str, window: int, recs: Sequence[Recording]) -> str:
    return f"{gearbox_id}|{window}|" + ";".join(sorted(r.key for r in recs))


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


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None,
                note: Callable[[str], None] | None = None) -> Iterator:
    """A Dask client: of the scheduler at ``scheduler``, else of a ``LocalCluster`` of ``workers``
    processes (one thread each: the estimator is numpy and Python, the GIL would serialise threads)."""
    import logging

    from dask.distributed import Client, LocalCluster

    if scheduler:
        with _scheduler_client(scheduler) as client:
            yield client
        return
    import dask

    cores = os.cpu_count() or 1
    n = workers or cores
    if n > cores:  # more worker processes than cores only adds memory, open files and start-up time
        if note:
            note(f"--workers {n}: this machine has {cores} cores; running {cores} worker processes")
        n = cores
    # Dask's nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536: glibc then maps and unmaps
    # every allocation above 128 KB instead of reusing it, which slows replay's numpy batches in a
    # worker.  None: the workers inherit this process's setting.
    # the workers start with Ctrl-C ignored: the terminal's SIGINT is this process's to handle; it
    # closes the cluster, which ends them quietly
    with ExitStack() as stack:
        stack.enter_context(dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}))
        with children_spared_interrupts():  # a Ctrl-C meanwhile comes when the cluster is on the stack
            cluster = stack.enter_context(LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                       silence_logs=logging.ERROR, dashboard_address=":0"))
        client = stack.enter_context(Client(cluster))
        stack.enter_context(_without_gc_diagnosis())
        if note:
            note(f"running on a local Dask cluster of {n} worker process{'es' if n > 1 else ''}"
                 + (f" (dashboard: {client.dashboard_link})" if _has_bokeh() else ""))
        yield client


@contextmanager
def _without_gc_diagnosis() -> Iterator[None]:
    """Dask's scheduler hooks a diagnosis into every garbage collection of this process; a Ctrl-C
    that lands in it is printed as "Exception ignored" with a traceback and lost.  Unhooked while the
    fleet runs, hooked again before the cluster closes (which unhooks it itself)."""
    import gc

    hooks = [cb for cb in gc.callbacks if type(getattr(cb, "__self__", None)).__name__ == "GCDiagnosis"]
    for cb in hooks:
        gc.callbacks.remove(cb)
    try:
        yield
    finally:
        gc.callbacks.extend(hooks)


#: how long ``--scheduler`` is waited for
SCHEDULER_TIMEOUT_S = 10.0


@contextmanager
def _scheduler_client(scheduler: str) -> Iterator:
    """A client of the scheduler at ``scheduler`` (``tcp://host:port``, ``tls://…``); a malformed or
    unreachable address is one :class:`UsageError` line within :data:`SCHEDULER_TIMEOUT_S`."""
    import re

    from dask.distributed import Client

    if not re.fullmatch(r"(tcp|tls|ucx|ws|wss)://[^\s/:]+(:\d{1,5})?/?", scheduler):
        raise UsageError(f"--scheduler {scheduler!r} is not a scheduler address (tcp://HOST:PORT)")
    try:
        client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise UsageError(f"--scheduler {scheduler}: no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s "
                         f"({type(exc).__name__}: {' '.join(str(exc).split())[:160]})") from None
    with client:
        yield client


def _has_bokeh() -> bool:
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


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
    returns the table's rows and how many ran now."""
    out_dir.mkdir(parents=True, exist_ok=True)
    groups: dict[tuple[str, int], list[Recording]] = {}
    for r in recs:
        start = r.start_ns if r.start_ns is not None else int(r.mtime * 1e9)
        groups.setdefault((r.gearbox_id, start // window_ns), []).append(r)
    units: list[Unit] = []
    for (gid, w), rs in sorted(groups.items()):
        win = CalibrationWindow(gid, w, window_ns, tuple(rs))
        units.append((win.key, [(win.key, calibrate_task, (win, run.config, run.channels, tuple(assume)))]))
    settings = settings_fingerprint(run.config, run.channels, window_ns, sorted(assume))
    return _run(run, FleetTable(out_dir / CALIBRATE_TABLE, "windows", settings), units)
