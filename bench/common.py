"""Shared by the benchmarks: a long synthetic rig recording (generated once, cached by path)."""

from __future__ import annotations

import time
from pathlib import Path


from rollergear_ros.core.params import load_config
from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, write_simulation


def long_bag(path: Path, minutes: float, rate_hz: float, effects: list[str] = ()) -> Path:
    """The both-ways rig map run again and again to ``minutes`` at ``rate_hz``, its seed one more each pass
    (``simulate --duration``: 4 Float64 topics + temperature)."""
    if path.exists():
        return path
    t0 = time.perf_counter()
    opts = SimulationOptions(profile="bidirectional_map", rate_hz=rate_hz, seed=1,
                             effects=[DeclaredEffect.parse(e) for e in effects])
    path.parent.mkdir(parents=True, exist_ok=True)
    written = write_simulation(load_config(), opts, path, minutes * 60.0)
    print(f"generated {path} ({path.stat().st_size / 1e6:.0f} MB, {written.samples:,} samples) in "
          f"{time.perf_counter() - t0:.0f} s")
    return path


def best_of(fn, repeat: int = 5) -> float:
    """The fastest of ``repeat`` calls of ``fn`` [s]."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
