"""The measured loss's uncertainty from the sensors' stated accuracy (the GUM's first-order propagation).

A torque sensor's accuracy is stated as limits: ``± a %`` of its full scale and ``± b %`` of the
reading; a speed reading's as its resolution ``q``.  Each limit is taken as a rectangular
distribution (GUM 4.3.7: a standard uncertainty of limit/√3; a resolution step q/√12), the two parts
of a torque sensor as independent::

    u(T) = √((a·FS/100)² + (b·|T|/100)²)/√3,   u(ω) = q/√12

and the measured input-referred loss ``T_loss = (T_in·ω_in − T_out·ω_out)/|ω_in|`` by the first-order
propagation of independent inputs (GUM 5.1.2)::

    u²(T_loss) = u²(T_in) + (ω_out/ω_in)²·u²(T_out) + (T_out/ω_in)²·u²(ω_out) + (T_out·ω_out/ω_in²)²·u²(ω_in)

(``ω_out = ω_in/ratio`` where the output speed is not measured: then it carries no uncertainty of its
own).  No rclpy import.
"""

from __future__ import annotations

import math

import numpy as np

from .params import SensorParams

__all__ = ["loss_uncertainty", "torque_uncertainty"]

_RECTANGULAR = 1.0 / math.sqrt(3.0)
_QUANTISED = 1.0 / math.sqrt(12.0)


def torque_uncertainty(torque_nm, full_scale_nm: float, fs_pct: float, reading_pct: float):
    """Standard uncertainty [N·m] of a torque reading: ``√((a·FS/100)² + (b·|T|/100)²)/√3``."""
    fs = fs_pct * full_scale_nm / 100.0
    return np.sqrt(fs * fs + (reading_pct * np.abs(torque_nm) / 100.0) ** 2) * _RECTANGULAR


def loss_uncertainty(sensors: SensorParams, torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s,
                     ratio: float = 1.0):
    """Standard uncertainty [N·m] of the measured input-referred loss at each sample (see the module
    docstring); ``out_speed_rad_s`` NaN where the output speed is the drive's over the ratio (it then
    carries no uncertainty of its own, and ``ω_out/ω_in`` is ``1/ratio``)."""
    t_in = np.asarray(torque_nm, float)
    w_in = np.asarray(speed_rad_s, float)
    t_out = np.nan_to_num(np.asarray(out_torque_nm, float))
    w_out_meas = np.asarray(out_speed_rad_s, float)
    measured = np.isfinite(w_out_meas)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio_term = np.where(measured, w_out_meas / w_in, np.nan)
    u_tin = torque_uncertainty(t_in, sensors.input_torque_full_scale_nm, sensors.input_torque_fs_pct,
                               sensors.input_torque_reading_pct)
    u_tout = torque_uncertainty(t_out, sensors.output_torque_full_scale_nm, sensors.output_torque_fs_pct,
                                sensors.output_torque_reading_pct)
    u_win = sensors.input_speed_resolution_rad_s * _QUANTISED
    u_wout = sensors.output_speed_resolution_rad_s * _QUANTISED
    with np.errstate(divide="ignore", invalid="ignore"):
        gain_out = np.where(measured, ratio_term, 1.0 / ratio)
        speeds = (t_out / w_in) ** 2 * u_wout ** 2 + (t_out * w_out_meas / w_in ** 2) ** 2 * u_win ** 2
        var = u_tin ** 2 + (gain_out * u_tout) ** 2 + np.where(measured, speeds, 0.0)
    return np.sqrt(var)
