"""A simulated gearbox's samples as the live node keeps them for a trace (tests of the tracer and its worker)."""

from __future__ import annotations

import numpy as np

from rollergear_ros.calibration.simulate import SimulationOptions, simulate
from rollergear_ros.calibration.tracing import INPUT_FIELDS, TraceBuffer
from rollergear_ros.core.estimator import Estimator

ONSET_S = 50.0


def node_samples(config, effects=(), seed=0, onset_s=ONSET_S, rate_hz=200.0):
    """A simulated drive cycle estimated as the node estimates it: (the buffer's arrays, the alarms)."""
    rig = simulate(config, SimulationOptions("drive_cycle", rate_hz, seed, list(effects),
                                             step_change_at_s=onset_s if effects else None))
    est = Estimator(config).process_batch(rig.t_ns, rig.torque_meas_nm, rig.speed_rad_s, rig.out_torque_meas_nm,
                                          rig.out_speed_meas_rad_s, rig.temperature_c, breakdown=False)
    buffer = TraceBuffer(10 ** 6)
    for i in range(len(est.t_ns)):  # the node's publish_estimate: every estimate's inputs
        buffer.add((int(est.t_ns[i]), float(est.torque_nm[i]), float(est.speed_rad_s[i]),
                    float(est.out_torque_nm[i]), float(est.out_speed_rad_s[i]), float(est.temperature_c[i]),
                    float(est.measured_loss_nm[i])))
    return buffer.snapshot(), est.alarms_t_ns, int(rig.t_ns[0])


def rms_residual(config, samples, window_ns):
    """The RMS residual of ``config``'s estimator, started fresh, over the samples in ``window_ns``."""
    keep = (samples["t_ns"] >= window_ns[0]) & (samples["t_ns"] <= window_ns[1])
    est = Estimator(config).process_batch(*(samples[f][keep] for f in INPUT_FIELDS), breakdown=False)
    return float(np.sqrt(np.nanmean(est.residual_nm ** 2)))


def up_to(samples, end_ns):
    """What the buffer held at ``end_ns`` (the node traces before the recording is over)."""
    keep = samples["t_ns"] <= end_ns
    return {k: v[keep] for k, v in samples.items()}
