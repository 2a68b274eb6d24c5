#!/usr/bin/env python3
"""One step of the gearbox FMU through fmpy (#44: <= 100 us), against baselines of the same run.

Builds the unit of a parameter file whose model follows the oil (viscosity_temperature and a speed
drag), then times, best of --repeat runs of --steps steps each:
  1. the unit's step through fmpy: set the three inputs, doStep, get the three outputs;
  2. fmpy's own cost of a call into the unit (getReal of one output), the floor any unit pays;
  3. the package's estimator at one operating point per call (what a planner calling the model
     sample by sample would pay without the unit).
  4. with --against UNIT.fmu, another unit of the same variables (one an earlier release exported) timed
     as in 1., in the same run.
Usage: python bench/bench_fmu.py [--steps 20000] [--repeat 3] [--no-oil] [--against UNIT.fmu]
  --no-oil   the package's default parameters (a model that follows no oil: a table of one temperature)
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from rollergear_ros.core.operating_points import evaluate_points
from rollergear_ros.core.params import load_config, validate
from rollergear_ros.outputs.fmu import build_fmu


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-oil", action="store_true", help="the default parameters: no oil law, a quick build")
    ap.add_argument("--against", type=Path, metavar="UNIT.fmu", help="another unit to time the same way")
    args = ap.parse_args()
    config = load_config() if args.no_oil else validate(load_config().to_flat() | {
        "effects.viscosity_temperature.enabled": True, "effects.viscosity_temperature.B_k": 1100.0,
        "effects.drag_speed.enabled": True, "effects.drag_speed.c": 2e-4})
    rng = np.random.default_rng(1)
    torque = rng.uniform(-90, 90, args.steps).tolist()
    speed = rng.uniform(-300, 300, args.steps).tolist()
    oil = rng.uniform(0, 120, args.steps).tolist()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "gearbox.fmu"
        t0 = time.perf_counter()
        table = build_fmu(config, path)
        print(f"built {path.stat().st_size / 1e6:.1f} MB unit in {time.perf_counter() - t0:.1f} s: "
              f"{table.loss_nm.size:,} nodes, interpolation error <= {table.interpolation_error_nm:.3g} N·m")
        step, call = _time_unit(path, Path(tmp) / "x", torque, speed, oil, args.repeat)
        other = _time_unit(args.against, Path(tmp) / "y", torque, speed, oil, args.repeat)[0] if args.against \
            else None
    points = min(2_000, args.steps)
    model = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        for i in range(points):
            evaluate_points(config, [torque[i]], [speed[i]], oil[i])
        model = min(model, (time.perf_counter() - t0) / points)
    print(f"FMU step through fmpy (3 inputs, doStep, 3 outputs): {1e6 * step:.1f} us (target <= 100 us)")
    print(f"  fmpy's call into the unit alone (getReal of one output): {1e6 * call:.1f} us")
    print(f"  the package's model at one point per call (evaluate_points): {1e6 * model:.0f} us "
          f"-> the unit is {model / step:.0f}x faster per sample")
    if other is not None:
        print(f"  {args.against.name} the same way: {1e6 * other:.1f} us -> this unit {other / step:.2f}x faster")


def _time_unit(path: Path, folder: Path, torque, speed, oil, repeat: int) -> tuple[float, float]:
    """Best of ``repeat`` runs: one step (3 inputs, doStep, 3 outputs) and fmpy's bare call into the unit [s]."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unit = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path), unzipdir=folder),
                     modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    unit.instantiate()
    unit.setupExperiment(startTime=0.0)
    unit.enterInitializationMode()
    unit.exitInitializationMode()
    inputs = [vr["drive_torque_nm"], vr["drive_speed_rad_s"], vr["oil_temperature_c"]]
    outputs = [vr["loss_torque_nm"], vr["loss_power_w"], vr["efficiency"]]
    step = call = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for i in range(len(torque)):
            unit.setReal(inputs, [torque[i], speed[i], oil[i]])
            unit.doStep(currentCommunicationPoint=1e-3 * i, communicationStepSize=1e-3)
            unit.getReal(outputs)
        step = min(step, (time.perf_counter() - t0) / len(torque))
        t0 = time.perf_counter()
        for _ in range(len(torque)):
            unit.getReal(outputs[:1])
        call = min(call, (time.perf_counter() - t0) / len(torque))
    unit.terminate()
    unit.freeInstance()
    return step, call


if __name__ == "__main__":
    main()
