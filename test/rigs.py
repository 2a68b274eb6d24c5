"""Rigs simulated for the tests from their own formulas -- not the effect registry's, not the package's
simulator -- and written as a DAQ would log them: a CSV with a channel map.  What calibrate must find
is only in these formulas.

* :func:`slow_joint`: a robot joint's friction test -- constant-speed sweeps up to 0.1 rad/s both ways,
  an encoder whose speed reading has 1e-4 rad/s of noise, a gravity-compensated torque with a zero
  error, nothing on the output (the drive torque is the friction).
* :func:`worm_drive`: a self-locking worm drive (efficiency 0.4) lifting and lowering one payload at
  steady speeds both ways, its friction a wavy function of speed no law of the vocabulary has; the
  payload given as a constant output torque, or left out (a spin test).
* :func:`warm_up`: the paper's gearbox warming up (oil 25 -> 75 °C) in an oil that is not the parameter
  file's (40 % more viscous at 40 °C, another Vogel shape), with a speed drag: the model evaluated at the
  oil's own viscosity sample by sample (Vogel's law written here).
* :func:`loaded_rig`: a gearbox on a test rig (the paper's model switched off: its loss is the
  formulas here), drive torque and speed in both directions, motoring and back-driving, output torque
  measured; options: a lag of the output-torque channel, a step change, friction that differs by
  direction or appears only while the output drives the input.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

NO_PAPER_MODEL = ("/**/loss_estimator:\n  ros__parameters:\n    estimator: {paper_model: false}\n")


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> Path:
    """The columns as a CSV (the first one the time)."""
    names = list(columns)
    data = np.column_stack([columns[n] for n in names])
    with path.open("w") as fh:
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.9g")
    return path


def spin_map(path: Path) -> Path:
    """A spin test's channel map: drive torque and speed, nothing on the output."""
    path.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T, unit: N*m}\n"
                    "motor_speed: {column: w, unit: rad/s}\noutput_torque: {constant: 0, unit: N*m}\n")
    return path


def rig_map(path: Path, ratio: float, lag_s: float | None = None) -> Path:
    """A loaded rig's channel map (the output speed from the ratio); ``lag_s``: the output torque's."""
    lag = f", lag_s: {lag_s}" if lag_s is not None else ""
    path.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T_in, unit: N*m}\n"
                    "motor_speed: {column: w_in, unit: rad/s}\n"
                    f"output_torque: {{column: T_out, unit: N*m{lag}}}\nratio: {ratio}\n")
    return path


def params(path: Path, extra: str = "") -> Path:
    """A parameter file with the paper's model switched off (a machine it does not describe)."""
    path.write_text(NO_PAPER_MODEL + extra)
    return path


@dataclass(frozen=True)
class Joint:
    coulomb_nm: float = 0.5
    viscous_nm_s: float = 2.0
    offset_nm: float = 0.05


def slow_joint(tmp: Path, joint: Joint = Joint(), seed: int = 0, rate_hz: float = 500.0) -> tuple[Path, Path]:
    """Sweeps at ±0.01 … 0.1 rad/s (4 s each, through rest between), the speed reading an encoder's
    (noise 1e-4 rad/s), the torque ``(Fc + Fv·|ω|)·sgn ω + offset`` with 0.01 N·m noise."""
    rng = np.random.default_rng(seed)
    levels = [0.01, 0.02, 0.035, 0.05, 0.07, 0.1]
    pieces = []
    for _repeat in range(2):
        for v in levels:
            for d in (1.0, -1.0):
                ramp = np.linspace(0.0, 1.0, int(0.5 * rate_hz), endpoint=False)
                pieces += [d * v * ramp, np.full(int(4.0 * rate_hz), d * v), d * v * ramp[::-1]]
    w = np.concatenate(pieces)
    t = np.arange(len(w)) / rate_hz
    friction = (joint.coulomb_nm + joint.viscous_nm_s * np.abs(w)) * np.sign(w)
    torque = friction + joint.offset_nm + rng.normal(0.0, 0.01, len(w))
    speed = w + rng.normal(0.0, 1e-4, len(w))
    csv = write_csv(tmp / "joint.csv", {"t": t, "T": torque, "w": speed})
    return csv, spin_map(tmp / "joint_map.yaml")


@dataclass(frozen=True)
class Rig:
    """A loaded rig's gearbox: its loss (input-referred, N·m) from formulas of its own."""

    ratio: float = 4.0
    drag_nm: float = 0.2  #: a constant drag
    viscous_nm_s: float = 0.002  #: a viscous drag c·|ω|
    load_share: float = 0.0  #: a load friction k·|T_load| (the output-side load)
    viscous_reverse_nm_s: float | None = None  #: the viscous drag in reverse (None: as forward)
    backdrive_share: float = 0.0  #: a friction k·|T_load| only while the output drives the input
    step_at_s: float | None = None  #: the drag appears here (None: from the start)
    output_lag_s: float = 0.0  #: the output torque channel's lag behind the drive torque
    rate_hz: float = 100.0
    torque_noise_nm: float = 0.01


def rig_profile(rate_hz: float, seed: int, duration_s: float = 160.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dwells of 2 s at speeds ±20 … 200 rad/s and torques −30 … 60 N·m (a quarter back-driving), each
    dwell reached by a 0.2 s ramp: ``t, ω, T``."""
    rng = np.random.default_rng(seed)
    n_dwell = int(duration_s / 2.2)
    speeds = rng.choice([20.0, 50.0, 100.0, 150.0, 200.0], n_dwell) * rng.choice([1.0, -1.0], n_dwell)
    torques = rng.uniform(-30.0, 60.0, n_dwell)
    w_pts, t_pts, time_pts = [], [], []
    now = 0.0
    for w, tq in zip(speeds, torques):
        for dt in (0.2, 2.0):
            now += dt
            time_pts.append(now)
            w_pts.append(w)
            t_pts.append(tq * np.sign(w))
    t = np.arange(0.0, now, 1.0 / rate_hz)
    return t, np.interp(t, time_pts, w_pts), np.interp(t, time_pts, t_pts)


def loaded_rig(tmp: Path, rig: Rig = Rig(), seed: int = 0, name: str = "rig") -> tuple[Path, Path, dict]:
    """The rig's CSV and channel map: the output torque ``T_out = T_load·ratio``, the load on the output side
    ``T_load = T_in − loss·sgn ω`` (a loss opposes the motion), the load frictions ``k·|T_load|`` solved in
    closed form (linear in the load: ``s·T_load = (s·T_in − rest)/(1 ± k)``); torque noise on both torque
    channels, the output torque delayed by ``rig.output_lag_s``."""
    rng = np.random.default_rng(seed)
    t, w, tq = rig_profile(rig.rate_hz, seed)
    s = np.sign(w)
    viscous = np.where(w >= 0, rig.viscous_nm_s, rig.viscous_nm_s if rig.viscous_reverse_nm_s is None
                       else rig.viscous_reverse_nm_s)
    drag = np.full(len(t), rig.drag_nm) if rig.step_at_s is None else np.where(t >= rig.step_at_s, rig.drag_nm, 0.0)
    rest = drag + viscous * np.abs(w)
    u = s * tq - rest  # s·T_load without the load frictions
    back = tq * w < 0  # the output drives the input
    share = rig.load_share + back * rig.backdrive_share
    v = np.where(u >= 0, u / (1.0 + rig.load_share), u / (1.0 - share)) if share.any() else u
    load = np.where(s == 0, tq, s * v)
    loss = rest + rig.load_share * np.abs(load) + back * rig.backdrive_share * np.abs(load)
    t_out = load * rig.ratio
    if rig.output_lag_s:
        t_out = np.interp(t - rig.output_lag_s, t, t_out)
    t_in_meas = tq + rng.normal(0.0, rig.torque_noise_nm, len(t))
    t_out_meas = t_out + rng.normal(0.0, rig.torque_noise_nm * rig.ratio, len(t))
    csv = write_csv(tmp / f"{name}.csv", {"t": t, "T_in": t_in_meas, "w_in": w + rng.normal(0.0, 0.02, len(t)),
                                          "T_out": t_out_meas})
    return csv, rig_map(tmp / f"{name}_map.yaml", rig.ratio), {"t": t, "w": w, "T": tq, "loss": loss}


def worm_drive(tmp: Path, payload_nm: float | None, rpms=(1, 2, 3, 4, 6, 8, 10, 15, 20, 30, 40, 50, 60, 70, 80, 100,
                                                          120, 140, 160, 180, 200),
               seed: int = 0, name: str = "worm", ratio: float = 60.0, load_nm: float = 0.6) -> tuple[Path, Path]:
    """Steady runs of 4 s at ``rpms`` both ways (0.3 s ramps, 100 Hz): the motor lifts the payload with
    ``T_L/(r·η)`` and drives it down with ``T_L·(2 − 1/η)/r`` (η = 0.4), plus a friction
    ``0.04 + 0.03·sin(|ω|/3) + 0.002·|ω|`` N·m; the motor torque read with 2e-4 N·m of noise (a current),
    the speed with 0.002 rad/s.  ``payload_nm``: the output torque the channel map gives (None: a spin
    test, 0 on the output)."""
    rng = np.random.default_rng(seed)
    pieces = []
    for rpm in rpms:
        for d in (1.0, -1.0):
            w = d * rpm * 2 * np.pi / 60
            ramp = np.linspace(0.0, 1.0, 30, endpoint=False)
            pieces += [w * ramp, np.full(400, w), w * ramp[::-1]]
    w = np.concatenate(pieces)
    t = np.arange(len(w)) / 100.0
    torque = _worm_torque(w, load_nm, ratio) + rng.normal(0.0, 2e-4, len(w))
    csv = write_csv(tmp / f"{name}.csv", {"t": t, "T": torque, "w": w + rng.normal(0.0, 0.002, len(w))})
    cmap = tmp / f"{name}_map.yaml"
    cmap.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T, unit: N*m}\n"
                    "motor_speed: {column: w, unit: rad/s}\n"
                    f"output_torque: {{constant: {0.0 if payload_nm is None else payload_nm}, unit: N*m}}\n"
                    f"ratio: {ratio}\n")
    return csv, cmap


def _worm_torque(w: np.ndarray, load_nm: float, ratio: float) -> np.ndarray:
    """The worm drive's motor torque at motor speed ``w`` [rad/s] (:func:`worm_drive`), noise-free."""
    eta = 0.4
    gravity = np.where(w >= 0, load_nm / ratio / eta, load_nm / ratio * (2 - 1 / eta))
    friction = 0.04 + 0.03 * np.sin(np.abs(w) / 3.0) + 0.002 * np.abs(w)
    return gravity + friction * np.tanh(w / 0.01)


def worm_table(tmp: Path, payload_nm: float | None, rpms=(1, 2, 4, 8, 15, 30, 50, 70, 100, 140, 200),
               name: str = "worm_table", ratio: float = 60.0, load_nm: float = 0.6) -> tuple[Path, Path]:
    """The :func:`worm_drive`'s steady runs as a steady-state table: one row per speed and direction, the
    motor torque's dwell mean (noise-free); ``payload_nm`` the output torque the channel map gives (None:
    a spin test's table, 0 on the output)."""
    w = np.array([d * rpm for rpm in rpms for d in (1.0, -1.0)]) * 2 * np.pi / 60
    csv = write_csv(tmp / f"{name}.csv", {"w": w, "T": _worm_torque(w, load_nm, ratio)})
    cmap = tmp / f"{name}_map.yaml"
    cmap.write_text("format: steady_state\nmotor_torque: {column: T, unit: N*m}\n"
                    "motor_speed: {column: w, unit: rad/s}\n"
                    f"output_torque: {{constant: {0.0 if payload_nm is None else payload_nm}, unit: N*m}}\n"
                    f"ratio: {ratio}\n")
    return csv, cmap


def lifting_table(tmp: Path, rpms, name: str, seed: int, offset_nm: float = 0.0) -> tuple[Path, Path]:
    """A drive lifting (ω > 0) and lowering one payload at steady speeds, as a table of dwell means: the
    payload's torque at the motor P = 0.01 N·m, friction Fc 0.02 + 1e-3·|ω| N·m, and near standstill
    (ω_s 0.3 rad/s, δ 1) a lifting torque that rises by 0.008 N·m while the lowering torque falls by
    0.002 (a breakaway excess 0.003 ± 0.005); the drive torque read with ``offset_nm`` and 2e-5 N·m of
    scatter in a row's mean; the payload given as the output torque at 60:1."""
    rng = np.random.default_rng(seed)
    w = np.array([d * rpm for rpm in rpms for d in (1.0, -1.0)]) * np.pi / 30.0
    near = np.exp(-np.abs(w) / 0.3)
    torque = 0.01 + np.sign(w) * (0.02 + 1e-3 * np.abs(w) + 0.003 * near) + 0.005 * near
    torque = torque + offset_nm + rng.normal(0.0, 2e-5, len(w))
    path = tmp / f"{name}.csv"
    path.write_text("n,T\n" + "".join(f"{a!r},{b!r}\n" for a, b in zip((w * 30.0 / np.pi).tolist(), torque.tolist())))
    cmap = tmp / "lifting.yaml"
    cmap.write_text("format: steady_state\nmotor_torque: {column: T, unit: N*m}\nmotor_speed: {column: n, unit: rpm}\n"
                    "output_torque: {constant: 0.6, unit: N*m}\nratio: 60\n")
    return path, cmap


def lifting_recording(tmp: Path, rpms, name: str, seed: int, offset_nm: float = 0.0) -> tuple[Path, Path]:
    """:func:`lifting_table`'s drive recorded at 10 Hz as a controller reads it: 300 samples a level and
    direction, the levels slowest first; the drive torque the law at the set speed (2e-4 N·m of noise),
    the speed its average over each sample in whole rpm -- below 8 rpm the drive sticks and slips (stuck
    for 3 samples on average, reading 0; slipping for 4 at 7/4 of the set speed), above it turns evenly
    (0.5 rpm of noise).  The first 1,000 speeds, which σ is learned from, are the stick-slip readings."""
    rng = np.random.default_rng(seed)
    set_rpm, read_rpm = [], []
    for rpm in rpms:
        for d in (1.0, -1.0):
            if rpm < 8:
                out: list[float] = []
                sticking = True
                while len(out) < 300:
                    k = int(rng.geometric(1 / 3 if sticking else 1 / 4))
                    out += [0.0] * k if sticking else (1.75 * rpm * (1 + rng.normal(0, 0.1, k))).tolist()
                    sticking = not sticking
                reading = np.array(out[:300])
            else:
                reading = rpm + rng.normal(0.0, 0.5, 300)
            set_rpm.append(np.full(300, d * rpm))
            read_rpm.append(d * np.round(reading))
    n_set, n_read = np.concatenate(set_rpm), np.concatenate(read_rpm)
    w = n_set * np.pi / 30.0
    near = np.exp(-np.abs(w) / 0.3)
    torque = 0.01 + np.sign(w) * (0.02 + 1e-3 * np.abs(w) + 0.003 * near) + 0.005 * near + offset_nm
    csv = write_csv(tmp / f"{name}.csv", {"t": np.arange(len(w)) / 10.0, "T": torque + rng.normal(0.0, 2e-4, len(w)),
                                          "n": n_read})
    cmap = tmp / f"{name}_map.yaml"
    cmap.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T, unit: N*m}\n"
                    "motor_speed: {column: n, unit: rpm}\noutput_torque: {constant: 0.6, unit: N*m}\nratio: 60\n")
    return csv, cmap


#: the warm-up's oil (a PAO gear oil's Vogel law from its data sheet) and the one the file states (a
#: mineral ISO VG 220's), each ``(η at 40 °C [Pa·s], B [K], C [K])``
WARM_UP_OIL = (0.14, 1362.4, 124.8)
FILE_OIL = (0.1, 1246.5, 105.9)


def warm_up(tmp: Path, seed: int, name: str = "warm", duration_s: float = 600.0) -> tuple[Path, Path]:
    """The paper's gearbox (``config/gearbox.yaml``) on the rig profile at 100 Hz while the oil warms
    from 25 to 75 °C (time constant 200 s): its loss the model's at the oil's viscosity
    ``η(θ) = η40·exp(B/(θ + C) − B/(40 + C))`` (:data:`WARM_UP_OIL`) plus a drag ``5e-5·|ω|^1.4``."""
    from rollergear_ros.core.model import LossModel
    from rollergear_ros.core.params import load_config

    rng = np.random.default_rng(seed)
    t, w, tq = rig_profile(100.0, seed, duration_s)
    theta = 75.0 - 50.0 * np.exp(-t / 200.0)
    gearbox = load_config().gearbox
    eta40, b, c = WARM_UP_OIL
    loss = np.empty(len(t))
    rounded = np.round(theta, 2)
    for th in np.unique(rounded):
        k = rounded == th
        oil = gearbox.__class__(**{**gearbox.__dict__, "eta0_pa_s": float(eta40 * np.exp(b / (th + c) - b / (40 + c)))})
        loss[k] = LossModel(oil).loss_magnitude(tq[k], w[k])
    loss += 5e-5 * np.abs(w) ** 1.4
    ratio = gearbox.ratio_effective
    t_out = (tq - loss * np.sign(w)) * ratio
    csv = write_csv(tmp / f"{name}.csv", {"t": t, "T_in": tq + rng.normal(0.0, 0.01, len(t)),
                                          "w_in": w + rng.normal(0.0, 0.02, len(t)),
                                          "T_out": t_out + rng.normal(0.0, 0.01 * ratio, len(t)),
                                          "oil": theta + rng.normal(0.0, 0.05, len(t))})
    cmap = tmp / f"{name}_map.yaml"
    cmap.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T_in, unit: N*m}\n"
                    "motor_speed: {column: w_in, unit: rad/s}\noutput_torque: {column: T_out, unit: N*m}\n"
                    f"oil_temperature: {{column: oil, unit: degC}}\nratio: {ratio}\n")
    return csv, cmap


def oil_params(path: Path, oil: tuple[float, float, float], drag: tuple[float, float] | None = None) -> Path:
    """A parameter file stating an oil ``(η40, B, C)`` (η0 and the viscosity law) and a speed drag ``(c, p)``."""
    eta40, b, c = oil
    text = ("/**/loss_estimator:\n  ros__parameters:\n"
            f"    gearbox: {{eta0_pa_s: {eta40}}}\n    effects:\n"
            f"      viscosity_temperature: {{enabled: true, B_k: {b}, C_k: {c}, theta_ref_c: 40.0, scale: 1.0}}\n")
    if drag is not None:
        text += f"      drag_speed: {{enabled: true, c: {drag[0]}, p: {drag[1]}}}\n"
    path.write_text(text)
    return path
