"""Joints with friction computed from their own formulas (not the effect registry's), shared by the
low-speed and memory tests: the LuGre model integrated by scipy, a back-and-forth drive, the CSV a
rig would log of it."""

from __future__ import annotations

import numpy as np

from rollergear_ros.core.params import load_config


def joint_velocity(rate: float = 500.0, duration_s: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """Back and forth at up to 0.4 rad/s, a 0.5 s dwell at rest before each reversal."""
    t = np.arange(0, duration_s, 1.0 / rate)
    phase = t % 5.0
    v = np.where(phase < 2.0, 0.4 * np.sin(np.pi * phase / 2.0),
                 np.where(phase < 2.5, 0.0, np.where(phase < 4.5, -0.4 * np.sin(np.pi * (phase - 2.5) / 2.0), 0.0)))
    return t, v


def lugre_friction(t, v, sigma0: float, fc: float, sigma2: float) -> np.ndarray:
    """The LuGre model integrated by scipy's stiff solver: ``dz/dt = v − σ0·|v|·z/Fc``,
    ``F = σ0·z + σ2·v`` (no Stribeck rise, no bristle damping: its presliding angle is Fc/σ0)."""
    from scipy.integrate import solve_ivp

    def rhs(tt, z):
        vv = np.interp(tt, t, v)
        return [vv - sigma0 * abs(vv) * z[0] / fc]

    with np.errstate(divide="ignore"):  # Radau's step control divides by a zero error at rest
        sol = solve_ivp(rhs, (t[0], t[-1]), [0.0], t_eval=t, method="Radau", max_step=0.002, rtol=1e-8, atol=1e-10)
    return sigma0 * sol.y[0] + sigma2 * v


def joint_csv(tmp_path, name: str, friction: np.ndarray, t: np.ndarray, v: np.ndarray, seed: int = 0):
    rng = np.random.default_rng(seed)
    torque = friction + rng.normal(0, 0.003, len(t))
    speed = v + rng.normal(0, 0.002, len(t))
    path = tmp_path / f"{name}.csv"
    path.write_text("t,T,w\n" + "".join(f"{a:.4f},{b:.6f},{c:.6f}\n" for a, b, c in zip(t, torque, speed)))
    (tmp_path / "spin.yaml").write_text(
        "time: {column: t, unit: s}\nmotor_torque: {column: T, unit: N*m}\n"
        "motor_speed: {column: w, unit: rad/s}\noutput_torque: {constant: 0, unit: N*m}\n")
    (tmp_path / "joint.yaml").write_text(
        "/**/loss_estimator:\n  ros__parameters:\n    estimator: {paper_model: false, speed_noise_rad_s: 0.002}\n")
    return path, tmp_path / "spin.yaml", tmp_path / "joint.yaml"


def memory_config():
    return load_config().with_values({"estimator.paper_model": False, "estimator.speed_noise_rad_s": 0.002,
                                      "effects.dahl.enabled": True, "effects.dahl.c_nm": 0.3,
                                      "effects.dahl.presliding_rad": 0.01, "effects.drag_constant.enabled": True,
                                      "effects.drag_constant.c_nm": 0.02})
