#!/usr/bin/env python3
"""The node's online trace of a 60 s window at 1 kHz, as its worker process runs it.

A drive cycle at ``--rate`` (1 kHz) whose gearbox develops a speed drag at 50 s, estimated as the
node estimates it; the buffer the node would hold when the trace is due (the alarm + 60 s) traced
(:func:`~rollergear_ros.calibration.tracing.trace`): the 60 s after the change point and the 50 s
before it.  Timed in this process, and through the worker process the node uses: the first request
(the process spawned and its imports) and a second one.  Baseline of the same run: the estimator
over the same samples once (what replay does with them), to compare machines.

Usage: python bench/bench_trace.py [--rate 1000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate
from rollergear_ros.calibration.traceworker import TraceWorker
from rollergear_ros.calibration.tracing import INPUT_FIELDS, SAMPLE_FIELDS, TraceRequest, trace
from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.params import load_config

ONSET_S = 50.0
WINDOW_S = 60.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    config = load_config()
    rig = simulate(config, SimulationOptions("drive_cycle", args.rate, 5, [DeclaredEffect("drag_speed", {
        "c": 3e-4, "p": 1.4})], step_change_at_s=ONSET_S))
    inputs = (rig.t_ns, rig.torque_meas_nm, rig.speed_rad_s, rig.out_torque_meas_nm, rig.out_speed_meas_rad_s,
              rig.temperature_c)
    est = Estimator(config).process_batch(*inputs, breakdown=False)
    samples = {f: np.asarray(getattr(est, f)) for f in SAMPLE_FIELDS}  # every estimate, as the node buffers them
    alarm = est.alarms_t_ns[0]
    end = alarm + int(WINDOW_S * 1e9)
    request = TraceRequest(samples, config.to_flat(), "alarm", alarm, WINDOW_S, 20.0, end)
    window = samples["t_ns"] <= end
    print(f"{int(window.sum()):,} samples buffered at {args.rate:g} Hz; alarm {(alarm - rig.t_ns[0]) * 1e-9:.2f} s "
          f"after the start, onset at {ONSET_S:g} s")
    base, here, first, again = [], [], [], []
    worker = TraceWorker()
    try:
        for rep in range(args.repeat):
            t0 = time.perf_counter()
            Estimator(config).process_batch(*(samples[f][window] for f in INPUT_FIELDS), breakdown=False)
            base.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            result = trace(request)
            here.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            worker.submit(request)
            worker.future.result()
            (first if rep == 0 else again).append(time.perf_counter() - t0)
            worker.result()
    finally:
        worker.close()
    print(f"result: {result.verdict}: {result.message}")
    print(f"baseline, the estimator over the {int(window.sum()):,} samples once: "
          f"{', '.join(f'{b:.2f}' for b in base)} s")
    print(f"trace in this process: {', '.join(f'{h:.2f}' for h in here)} s "
          f"(median {float(np.median(here)) / float(np.median(base)):.1f}× the baseline)")
    print(f"through the worker process: first request (spawn + imports + trace) {first[0]:.2f} s; then "
          f"{', '.join(f'{a:.2f}' for a in again) or '-'} s (target <= 10 s)")


if __name__ == "__main__":
    main()
