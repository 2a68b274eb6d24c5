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
time).  A recording that cannot be read is a ``failed`` row with its reason; the rest go on.
The drift report is :mod:`.fleet_report`.  No rclpy import.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .errors import RollergearError, UsageError
from .interface import Metadata
from .params import Config, config_to_yaml

__all__ = ["FLEET_TABLE", "CALIBRATE_TABLE", "Recording", "dask_client", "discover", "read_table", "run_calibrate",
           "run_replay"]

FLEET_TABLE = "fleet.parquet"
CALIBRATE_TABLE = "fleet_calibrate.parquet"
SOURCE_SUFFIXES = (".mcap", ".db3", ".csv", ".parquet", ".mf4", ".mdf", ".tdms")
GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class Recording:
    """One log of the fleet."""

    path: str  #: local path or fsspec URL
    gearbox_id: str
    size: int
    mtime: float
    start_ns: int | None = None  #: first message (MCAP summary), for time windows

    @property
    def key(self) -> str:
        """What identifies a recording already done: path, size and modification time."""
        return f"{self.path}|{self.size}|{self.mtime:.6f}"


# ------------------------------------------------------------------------------------ discovery
def discover(logs: Sequence[str], group_by: str = "auto") -> list[Recording]:
    """The recordings under ``logs`` (files, folders, globs; local or fsspec URLs), sorted by
    gearbox and start.  ``group_by``: ``auto`` (metadata ``gearbox_id``, else the folder),
    ``folder`` or ``metadata``."""
    import fsspec

    found: dict[str, Recording] = {}
    for log in logs:
        fs, root = fsspec.core.url_to_fs(str(log))
        local = "file" in (fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,))
        if GLOB_CHARS & set(root):
            paths = sorted(fs.glob(root))
        elif fs.isdir(root):
            paths = sorted(p for p in fs.find(root) if p.lower().endswith(SOURCE_SUFFIXES))
        elif fs.exists(root):
            paths = [root]
        else:
            raise UsageError(f"{log} does not exist")
        for p in paths:
            info = fs.info(p)
            url = p if local else fs.unstrip_protocol(p)
            mtime = info.get("mtime") or info.get("LastModified") or info.get("updated") or 0.0
            mtime = mtime.timestamp() if hasattr(mtime, "timestamp") else float(mtime)
            gid, start = _identity(url, local, group_by)
            found[url] = Recording(url, gid, int(info.get("size") or 0), mtime, start)
    if not found:
        raise UsageError(f"no recordings under {', '.join(map(str, logs))} ({', '.join(SOURCE_SUFFIXES)})")
    return sorted(found.values(), key=lambda r: (r.gearbox_id, r.start_ns or 0, r.path))


def _identity(url: str, local: bool, group_by: str) -> tuple[str, int | None]:
    """Gearbox id and start time of a recording (metadata and summary of a local MCAP)."""
    folder = Path(url.rstrip("/")).parent.name or "fleet"
    gid, start = None, None
    if local and url.lower().endswith(".mcap"):
        from .bag import inspect_bag, read_metadata

        try:
            record = read_metadata(url, Metadata.GEARBOX) or {}
            gid = record.get("gearbox_id")
            start = inspect_bag(url).start_ns or None
        except RollergearError:
            pass  # a damaged recording: it fails in its task, with the reason
    if group_by == "folder":
        gid = folder
    elif group_by == "metadata" and not gid:
        raise UsageError(f"{url} has no '{Metadata.GEARBOX}' metadata record with a gearbox_id (--group-by metadata)")
    return gid or folder, start


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


def replay_task(rec: Recording, config: Config, channels: str | None) -> dict:
    """Replay one recording; the fleet table's row for it (``failed`` with the reason when it cannot)."""
    from .importer import as_mcap
    from .replay import replay

    row = {"gearbox_id": rec.gearbox_id, "recording": rec.path, "key": rec.key, "status": "ok", "reason": ""}
    t0 = time.perf_counter()
    try:
        with _local(rec.path) as local, as_mcap([local], channels) as (bag,):
            s, _ = replay(bag, config, show_progress=False)
    except Exception as exc:  # noqa: BLE001 - one bad recording must not stop the fleet; the row says why
        return _failed(row, exc) | {"seconds": time.perf_counter() - t0}
    if s.estimated == 0:
        return row | {"status": "failed", "reason": "no sample could be estimated", "samples": s.samples,
                      "seconds": time.perf_counter() - t0}
    return row | {
        "start_ns": s.start_ns, "end_ns": s.end_ns, "duration_s": s.duration_s, "samples": s.samples,
        "estimated": s.estimated, "skipped": sum(s.skipped.values()), "energy_in_j": s.energy_in_j,
        "energy_lost_j": s.energy_lost_j, "mean_efficiency": s.mean_efficiency, "mean_loss_nm": s.mean_loss_nm,
        # energy efficiencies: estimated, and measured where output torque was recorded
        "efficiency_energy": 1.0 - s.energy_lost_j / s.energy_in_j if s.energy_in_j > 0 else math.nan,
        "efficiency_measured": (1.0 - s.energy_lost_measured_j / s.energy_in_measured_j
                                if s.energy_in_measured_j > 0 else math.nan),
        "residual_mean_nm": s.residual_mean_nm, "residual_rms_nm": s.residual_rms_nm, "alarms": s.alarms,
        "seconds": time.perf_counter() - t0,
    }


def calibrate_task(gearbox_id: str, window: int, window_ns: int, recs: Sequence[Recording], config: Config,
                   channels: str | None) -> dict:
    """Calibrate one gearbox over one time window (all its recordings there)."""
    from contextlib import ExitStack

    from .calibrate import calibrate, load_samples
    from .effects import EFFECTS
    from .importer import as_mcap

    row = {"gearbox_id": gearbox_id, "window": window, "window_start_ns": window * window_ns,
           "window_end_ns": (window + 1) * window_ns, "recordings": len(recs),
           "key": _window_key(gearbox_id, window, recs), "status": "ok", "reason": ""}
    t0 = time.perf_counter()
    try:
        with ExitStack() as stack:
            local = [stack.enter_context(_local(r.path)) for r in recs]
            bags = stack.enter_context(as_mcap(local, channels))
            data = load_samples(bags, config)
            result = calibrate(data, config)
    except Exception as exc:  # noqa: BLE001 - one bad window must not stop the fleet; the row says why
        return _failed(row, exc) | {"seconds": time.perf_counter() - t0}
    row |= {"samples": result.samples, "verdict": result.verdict,
            "effects": json.dumps([e.to_json() for e in result.effects]),
            "error_before_rmse_nm": result.error_before.rmse_nm, "error_after_rmse_nm": result.error_after.rmse_nm,
            "calibrated_yaml": config_to_yaml(result.config), "seconds": time.perf_counter() - t0}
    found = {e.name: e for e in result.effects}
    for name, effect in EFFECTS.items():  # flat columns: one coefficient (and its interval) per effect
        e = found.get(name)
        coef = effect.coefficient
        lo, hi = e.ci95[coef] if e else (math.nan, math.nan)
        row |= {f"{name}.{coef}": e.params[coef] if e else 0.0, f"{name}.{coef}_lo": lo,
                f"{name}.{coef}_hi": hi, f"{name}.rms_nm": e.rms_contribution_nm if e else 0.0}
    return row


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
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None,
                note: Callable[[str], None] | None = None) -> Iterator:
    """A Dask client: of the scheduler at ``scheduler``, else of a ``LocalCluster`` of ``workers``
    processes (one thread each: the estimator is numpy and Python, the GIL would serialise threads)."""
    import logging

    from dask.distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    import dask

    n = workers or os.cpu_count() or 1
    # Dask's nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536: glibc then maps and unmaps
    # every allocation above 128 KB instead of reusing it, and replay's numpy batches ran 1.6-1.9x
    # slower in a worker than in a plain process.  None: the workers inherit this process's setting.
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}), \
            LocalCluster(n_workers=n, threads_per_worker=1, processes=True, silence_logs=logging.ERROR,
                         dashboard_address=":0") as cluster, Client(cluster) as client:
        if note and _has_bokeh():
            note(f"Dask dashboard: {client.dashboard_link}")
        yield client


def _has_bokeh() -> bool:
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


def _run(client, table: Path, tasks: list[tuple[str, Callable, tuple]], progress: bool, what: str,
         note: Callable[[str], None]) -> tuple[list[dict], int]:
    """Run ``(key, function, args)`` tasks not yet in ``table``; rows land as they finish."""
    from dask.distributed import as_completed
    from tqdm import tqdm

    rows = read_table(table)
    done = {r["key"] for r in rows}
    todo = [t for t in tasks if t[0] not in done]
    skipped = len(tasks) - len(todo)
    if skipped:
        note(f"{skipped} of {len(tasks)} {what} already in {table}: not done again")
    if not todo:
        return rows, 0
    futures = [client.submit(fn, *args, key=f"rollergear-{abs(hash(key))}-{i}", pure=False)
               for i, (key, fn, args) in enumerate(todo)]
    failed = samples = 0
    t0 = time.perf_counter()
    last_write = 0.0
    with tqdm(total=len(futures), unit=what[:-1] if what.endswith("s") else what, file=sys.stderr,
              disable=not progress, mininterval=0.2) as bar:
        for future in as_completed(futures):
            row = future.result()
            rows.append(row)
            failed += row["status"] != "ok"
            samples += int(row.get("samples") or 0)
            bar.update(1)
            running = sum(f.status == "pending" for f in futures)
            bar.set_postfix(failed=failed, running=min(running, len(client.scheduler_info()["workers"])),
                            samples_per_s=f"{samples / max(time.perf_counter() - t0, 1e-9):,.0f}")
            if time.perf_counter() - last_write > 1.0 or bar.n == len(futures):
                _write_table(table, rows)
                last_write = time.perf_counter()
    _write_table(table, rows)
    return rows, len(todo)


def run_replay(recs: Sequence[Recording], out_dir: Path, client, config: Config, channels: str | None = None,
               progress: bool = False, note: Callable[[str], None] = lambda m: None) -> tuple[list[dict], int]:
    """Replay every recording on the cluster; returns the table's rows and how many were run now."""
    out_dir.mkdir(parents=True, exist_ok=True)
    tasks = [(r.key, replay_task, (r, config, channels)) for r in recs]
    return _run(client, out_dir / FLEET_TABLE, tasks, progress, "recordings", note)


def run_calibrate(recs: Sequence[Recording], out_dir: Path, client, config: Config, window_ns: int,
                  channels: str | None = None, progress: bool = False,
                  note: Callable[[str], None] = lambda m: None) -> tuple[list[dict], int]:
    """Calibrate every gearbox over each time window; returns the table's rows and how many ran now."""
    out_dir.mkdir(parents=True, exist_ok=True)
    groups: dict[tuple[str, int], list[Recording]] = {}
    for r in recs:
        start = r.start_ns if r.start_ns is not None else int(r.mtime * 1e9)
        groups.setdefault((r.gearbox_id, start // window_ns), []).append(r)
    tasks = [(_window_key(gid, w, rs), calibrate_task, (gid, w, window_ns, rs, config, channels))
             for (gid, w), rs in sorted(groups.items())]
    return _run(client, out_dir / CALIBRATE_TABLE, tasks, progress, "windows", note)

