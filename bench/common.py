"""Shared by the benchmarks: a long synthetic rig recording (generated once, cached by path)."""

from __future__ import annotations

import time
from dataclasses import fields
from pathlib import Path

import numpy as np

from rollergear_ros.core.params import load_config
from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate, write_rig_bag


def long_bag(path: Path, minutes: float, rate_hz: float, effects: list[str] = ()) -> Path:
    """The warm-up profile repeated to ``minutes`` at ``rate_hz`` (4 Float64 topics + temperature)."""
    if path.exists():
        return path
    t0 = time.perf_counter()
    opts = SimulationOptions(profile="bidirectional_map", rate_hz=rate_hz, seed=1,
                             effects=[DeclaredEffect.parse(e) for e in effects])
    rig = simulate(load_config(), opts)
    n = int(minutes * 60 * rate_hz)
    reps = -(-n // len(rig.t_ns))
    for f in fields(rig):
        v = getattr(rig, f.name)
        if isinstance(v, np.ndarray) and len(v) == len(rig.t_ns) and f.name != "t_ns":
            setattr(rig, f.name, np.tile(v, reps)[:n])
    rig.t_ns = rig.t_ns[0] + (np.arange(n) * (1e9 / rate_hz)).astype(np.int64)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_rig_bag(rig, opts, path)
    print(f"generated {path} ({path.stat().st_size / 1e6:.0f} MB, {n:,} samples) in {time.perf_counter() - t0:.0f} s")
    return path


def best_of(fn, repeat: int = 5) -> float:
    """The fastest of ``repeat`` calls of ``fn`` [s]."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
