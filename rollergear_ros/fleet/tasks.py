"""The fleet's tasks, run on Dask workers: one recording's replay, one gearbox window's calibration.

Each task is the very replay or calibrate of the single-recording commands and returns its row
of the fleet table; a recording that cannot be read is a ``failed`` row with its reason, never an
exception that stops the fleet.  :func:`combine_slices` makes a recording's row of its time
slices' rows.  No rclpy import.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

from ..base.errors import RollergearError
from ..core.measured import EnergyBalance
from ..core.params import Config, SensorParams, config_to_yaml
from .logs import Recording

__all__ = ["CalibrationWindow", "calibrate_task", "combine_slices", "replay_task", "utc_text"]


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
    #: per recording, its part in the window (``[start, end)`` ns, None: open; empty: every one whole)
    parts: tuple[tuple[int | None, int | None], ...] = ()

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
           "key": win.key, "status": "ok", "reason": "", "warning": "",
           "recordings_in_part": sum(p != (None, None) for p in win.parts)}
    t0 = time.perf_counter()
    bad = [r for r in recs if r.problem]
    if bad:
        return row | {"status": "failed", "reason": f"{bad[0].path} {bad[0].problem}", "seconds": 0.0}
    try:
        with ExitStack() as stack:
            local = [stack.enter_context(_local(r.path)) for r in recs]
            bags = stack.enter_context(as_mcap(local, channels))
            # a recording across windows: only its part in this one is read
            data = load_samples(bags, config, windows=win.parts or None)
            row["warning"] = power_balance_warning(data) or ""  # as calibrate's command line warns
            result = calibrate(data, config, CalibrationSettings(assume=assume))
    except Exception as exc:  # noqa: BLE001 - one bad window must not stop the fleet; the row says why
        return _failed(row, exc) | {"seconds": time.perf_counter() - t0}
    first, last = int(data.t_ns.min()), int(data.t_ns.max())  # what the window holds: the samples analysed
    row |= {"data_start_ns": first, "data_end_ns": last, "data_start": utc_text(first), "data_end": utc_text(last),
            "samples": result.samples, "verdict": result.verdict,
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
