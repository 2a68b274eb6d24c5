"""A simulated fleet for tests and the demo: N gearboxes × D daily logs, a few of them drifting.

``rollergear simulate --fleet N --days D --out DIR`` writes ``DIR/gbNN/dayDD.mcap``: each a rig
map in both directions (so that a seal's drag is not mistaken for a torque-sensor offset), the
gearbox named in the ``rollergear`` metadata record (``gearbox_id``).  About a third of the
gearboxes develop an effect from a day drawn at random -- a seal starting to drag
(``drag_constant``) or worn bearings (``load_dependent``) -- which nothing but
``DIR/fleet_truth.json`` (for tests and the demo) records.  No rclpy import.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..base.atomic import write_text
from ..core.params import Config
from ..calibration.simulate import DeclaredEffect, SimulationOptions, simulate, write_rig_bag

__all__ = ["DAY_NS", "simulate_fleet"]

DAY_NS = 86_400 * 10**9
FLEET_START_NS = 1_767_225_600 * 10**9  #: 2026-01-01T00:00:00Z, the first day's log


def _drift(rng: np.random.Generator, k: int) -> DeclaredEffect:
    if k % 2 == 0:  # a seal starting to drag
        return DeclaredEffect("drag_constant", {"c": float(rng.uniform(0.06, 0.1))})
    q = float(rng.uniform(1.0, 1.3))  # worn bearings: more load friction
    return DeclaredEffect("load_dependent", {"c": float(rng.uniform(0.15, 0.25)) / 90.0 ** q, "q": q})


@dataclass(frozen=True)
class FleetScenario:
    """The simulated fleet's size and sampling: how many gearboxes, how many daily logs each, the
    logs' sample rate and the random seed (the same seed, the same fleet)."""

    gearboxes: int = 6
    days: int = 8
    rate_hz: float = 100.0
    seed: int = 0
    start_ns: int = FLEET_START_NS  #: the first day's midnight (UTC)


def simulate_fleet(config: Config, out_dir: Path, scenario: FleetScenario = FleetScenario(), progress=None) -> dict:
    """Write the fleet (see the module docstring); returns the truth written to ``fleet_truth.json``."""
    gearboxes, days, rate_hz, seed = scenario.gearboxes, scenario.days, scenario.rate_hz, scenario.seed
    start_ns = scenario.start_ns
    rng = np.random.default_rng(seed)
    ids = [f"gb{g:02d}" for g in range(gearboxes)]
    drifting = sorted(rng.choice(gearboxes, size=max(1, gearboxes // 3), replace=False).tolist())
    truth: dict = {"days": days, "rate_hz": rate_hz, "start_ns": start_ns, "gearboxes": {}}
    for k, g in enumerate(drifting):
        effect = _drift(rng, k)
        truth["gearboxes"][ids[g]] = {"effect": effect.name, "params": effect.params,
                                      "from_day": int(rng.integers(2, max(days - 2, 3)))}
    for g, gid in enumerate(ids):
        drift = truth["gearboxes"].get(gid)
        for d in range(days):
            effects = [DeclaredEffect(drift["effect"], drift["params"])] if drift and d >= drift["from_day"] else []
            opts = SimulationOptions(profile="bidirectional_map", rate_hz=rate_hz, seed=seed * 10_000 + g * 100 + d,
                                     effects=effects, start_ns=start_ns + d * DAY_NS + g * 3_600 * 10**9)
            path = out_dir / gid / f"day{d:02d}.mcap"
            path.parent.mkdir(parents=True, exist_ok=True)
            write_rig_bag(simulate(config, opts), opts, path, gearbox_id=gid)
            if progress:
                progress(1)
    write_text(out_dir / "fleet_truth.json", json.dumps(truth, indent=1) + "\n")
    return truth
