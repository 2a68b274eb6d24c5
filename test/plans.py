"""Test plans as rigs run them: steady runs one after another, each at one operating point, a pause between
them, a handful of speeds, a load that is whatever the rig holds -- simulated from formulas of their own and
written as a DAQ exports them (one CSV, runs in recording order, a channel map).

* :func:`joint_plan`: a robot joint behind a harmonic drive (100:1), constant-speed runs one way, its
  friction a straight line in the speed; the joint's torque sensor reads a small, nearly constant load, so
  the drive torque is mostly the friction itself.
* :func:`loaded_joint_plan`: that joint with a load friction in the output-side load, at several loads per
  speed (a law in the load testable, the drive torque still mostly the friction).
* :func:`one_load_plan`: the paper's gearbox (``config/gearbox.yaml``) in steady runs at one drive torque,
  with a drag and a viscous line the parameter file lacks.
* :func:`servo_plan`: a small servo (a coreless motor behind 288:1 spur gears) swinging a pendulum both
  ways, then letting go: the pendulum back-drives the gears until the friction holds it at rest; its friction
  Coulomb + viscous at the motor.
* :func:`held_out_runs`: the mean of a replay's residual over each run of an export (the static map's
  error at each held-out operating point).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigs import rig_map, write_csv

PAUSE_S = 2.0


def _export(path: Path, runs: list[dict[str, np.ndarray]]) -> Path:
    """Runs (column -> values, ``t`` from 0) one after another on one clock, a pause between them."""
    start, pieces = 0.0, []
    for run in runs:
        pieces.append({k: (v + start if k == "t" else v) for k, v in run.items()})
        start += float(run["t"][-1]) + PAUSE_S
    return write_csv(path, {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0]})


#: the joint's friction at the joint [N·m]: a line in its speed [rad/s]
JOINT_COULOMB_NM, JOINT_VISCOUS_NM_S, JOINT_RATIO = 1.85, 0.75, 100.0


def joint_plan(tmp: Path, speeds, name: str, seed: int, load: bool) -> tuple[Path, Path]:
    """3 s at each joint speed (200 Hz), one direction: the joint torque sensor reads −0.25 N·m (a spring
    that helps) and the motor's current-based torque ``(Fc + Fv·ω − 0.25)/100`` rises 1.6 → 2.7 N·m at the
    joint; ``load``: the sensor given as the output torque (else a spin test: 0 on the output)."""
    rng = np.random.default_rng(seed)
    runs = []
    for w in speeds:
        t = np.arange(600) / 200.0
        held = -0.25 + 0.01 * np.sin(2 * np.pi * 0.3 * t)
        friction = JOINT_COULOMB_NM + JOINT_VISCOUS_NM_S * w
        runs.append({"t": t, "T_in": (friction + held) / JOINT_RATIO + rng.normal(0.0, 4e-4, len(t)),
                     "w_in": w * JOINT_RATIO + rng.normal(0.0, 0.05, len(t)),
                     "T_out": held + rng.normal(0.0, 0.02, len(t))})
    csv = _export(tmp / f"{name}.csv", runs)
    cmap = tmp / f"{name}_map.yaml"
    out = "{column: T_out, unit: N*m}" if load else "{constant: 0, unit: N*m}"
    cmap.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T_in, unit: N*m}\n"
                    f"motor_speed: {{column: w_in, unit: rad/s}}\noutput_torque: {out}\nratio: {JOINT_RATIO}\n")
    return csv, cmap


#: the loaded joint's load friction: a share of the load at the joint (its bearings carry the load)
JOINT_LOAD_SHARE = 0.3


def loaded_joint_plan(tmp: Path, speeds, loads, name: str, seed: int) -> tuple[Path, Path]:
    """The joint of :func:`joint_plan` with a load friction ``0.3·|T_load|`` beside its line, run at several
    loads per speed, both ways (3 s each, 200 Hz): the joint torque sensor reads the load ``T_load`` (a
    spring that helps or a weight that resists, ±0.6 N·m), the motor ``((Fc + Fv·|ω| + 0.3·|T_load|)·sgn ω
    + T_load)/100`` -- the drive torque still mostly the friction."""
    rng = np.random.default_rng(seed)
    runs = []
    for w in [*speeds, *(-v for v in speeds)]:
        for held in loads:
            t = np.arange(600) / 200.0
            friction = (JOINT_COULOMB_NM + JOINT_VISCOUS_NM_S * abs(w) + JOINT_LOAD_SHARE * abs(held)) * np.sign(w)
            runs.append({"t": t, "T_in": (friction + held) / JOINT_RATIO + rng.normal(0.0, 4e-4, len(t)),
                         "w_in": w * JOINT_RATIO + rng.normal(0.0, 0.05, len(t)),
                         "T_out": held + rng.normal(0.0, 0.02, len(t))})
    return _export(tmp / f"{name}.csv", runs), rig_map(tmp / f"{name}_map.yaml", JOINT_RATIO)


def one_load_plan(tmp: Path, torque_nm: float, speeds_rpm, name: str, seed: int) -> tuple[Path, Path]:
    """The paper's gearbox in 20 s runs at each speed both ways (100 Hz), every run at ``torque_nm``; its
    loss the model's plus a 0.05 N·m drag and a viscous 2e-4·|ω| -- what the parameter file lacks."""
    from rollergear_ros.core.model import LossModel
    from rollergear_ros.core.params import load_config

    gearbox = load_config().gearbox
    model, ratio = LossModel(gearbox), gearbox.ratio_effective
    rng = np.random.default_rng(seed)
    runs = []
    for rpm in speeds_rpm:
        for direction in (1.0, -1.0):
            t = np.arange(2000) / 100.0
            w, tq = np.full(len(t), direction * rpm * np.pi / 30.0), np.full(len(t), direction * torque_nm)
            loss = model.loss_magnitude(tq, w) + 0.05 + 2e-4 * np.abs(w)
            runs.append({"t": t, "T_in": tq + rng.normal(0.0, 0.01, len(t)), "w_in": w + rng.normal(0.0, 0.02, len(t)),
                         "T_out": (tq - loss * np.sign(w)) * ratio + rng.normal(0.0, 0.01 * ratio, len(t))})
    return _export(tmp / f"{name}.csv", runs), rig_map(tmp / f"{name}_map.yaml", ratio)


def replayed(csv: Path, cmap: Path, params: Path) -> dict[str, np.ndarray]:
    """``replay`` of an export with ``params``: its estimates' columns (``t`` in s)."""
    from rollergear_ros.core.params import load_config
    from rollergear_ros.replay.run import replay
    from rollergear_ros.sources.importer import as_mcap

    with as_mcap([csv], cmap) as bags:
        _summary, batches = replay(bags[0], load_config(params), collect=True, show_progress=False)
    names = ("speed_rad_s", "measured_loss_nm", "residual_nm", "loss_torque_nm")
    columns = {n: np.concatenate([getattr(b, n) for b in batches]) for n in names}
    columns["t"] = np.concatenate([b.t_ns for b in batches]).astype(float) * 1e-9
    return columns


def held_out_runs(csv: Path, cmap: Path, params: Path) -> tuple[np.ndarray, int, int]:
    """``replay`` of an export with ``params``: each run's mean residual (over the samples it measures a
    loss of), the rows estimated (a finite loss) and the rows."""
    c = replayed(csv, cmap, params)
    t, r, loss = c["t"], c["residual_nm"], c["loss_torque_nm"]
    cut = np.r_[0, np.flatnonzero(np.diff(t) > 1.0) + 1, len(t)]
    means = np.array([np.nanmean(r[i:j]) if np.isfinite(r[i:j]).any() else np.nan for i, j in zip(cut[:-1], cut[1:])])
    return means, int(np.count_nonzero(np.isfinite(loss))), len(np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2))


def line_at(train_csv: Path, held_csv: Path, load: bool, ratio: float) -> float:
    """The least-squares line ``a + b·ω`` through the fitted runs' mean loss, its RMS error at the held-out
    runs' means (the hand fit of a one-way plan: Coulomb + viscous)."""
    def means(csv):
        a = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
        cut = np.r_[0, np.flatnonzero(np.diff(a[:, 0]) > 1.0) + 1, len(a)]
        m = np.array([a[i:j].mean(axis=0) for i, j in zip(cut[:-1], cut[1:])])
        return m[:, 2], m[:, 1] - (m[:, 3] / ratio if load else 0.0)

    w, loss = means(train_csv)
    coef, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(w), w]), loss, rcond=None)
    w, loss = means(held_csv)
    return float(np.sqrt(np.mean((loss - (coef[0] + coef[1] * w)) ** 2)))


#: the servo: its ratio, the pendulum's m·g·l [N·m] and inertia [kg·m²] at the output, the motor's Coulomb
#: [N·m] and viscous [N·m·s/rad] friction, its sampling [Hz]
SERVO_RATIO, SERVO_MGL_NM, SERVO_INERTIA, SERVO_COULOMB_NM, SERVO_VISCOUS_NM_S, SERVO_RATE_HZ = (
    288.0, 0.3, 0.009, 3e-4, 1.5e-7, 500.0)


def _servo_friction(w_motor: float) -> float:
    return (SERVO_COULOMB_NM + SERVO_VISCOUS_NM_S * abs(w_motor)) * float(np.sign(w_motor))


def _servo_run(amplitude_rad: float, freq_hz: float, rng) -> dict[str, np.ndarray]:
    """4 s driven along ``amplitude·sin(2π f t)`` (the motor torque the pendulum's torque through the gears
    plus the friction), then 4 s let go (motor torque 0): the pendulum swings back-driving the gears, the
    friction braking it, until it sticks where gravity cannot overcome the Coulomb friction.  Logged: the
    motor's current-based torque, its speed (encoder noise 1 rad/s) and the output torque the pendulum's
    dynamics give (θ̈ and θ from the joint encoder)."""
    n, dt = int(4.0 * SERVO_RATE_HZ), 1.0 / SERVO_RATE_HZ
    t = np.arange(n) * dt
    phase = 2 * np.pi * freq_hz * t
    theta, rate = amplitude_rad * np.sin(phase), amplitude_rad * 2 * np.pi * freq_hz * np.cos(phase)
    out = SERVO_INERTIA * -amplitude_rad * (2 * np.pi * freq_hz) ** 2 * np.sin(phase) + SERVO_MGL_NM * np.sin(theta)
    motor = out / SERVO_RATIO + np.array([_servo_friction(SERVO_RATIO * v) for v in rate])
    x, v, free_theta_rate, free_out = float(theta[-1]), float(rate[-1]), [], []
    substeps = 20
    for _ in range(n):
        for _ in range(substeps):  # semi-implicit Euler; a reversal that gravity cannot carry sticks
            gravity = SERVO_MGL_NM * np.sin(x)
            if v == 0.0 and abs(gravity) <= SERVO_RATIO * SERVO_COULOMB_NM:
                continue
            accel = (-SERVO_RATIO * _servo_friction(SERVO_RATIO * v) - gravity) / SERVO_INERTIA
            moved = v + accel * dt / substeps
            v = 0.0 if v != 0.0 and moved * v < 0 and abs(gravity) <= SERVO_RATIO * SERVO_COULOMB_NM else moved
            x += v * dt / substeps
        accel = 0.0 if v == 0.0 else (-SERVO_RATIO * _servo_friction(SERVO_RATIO * v) - SERVO_MGL_NM * np.sin(x)) \
            / SERVO_INERTIA
        free_theta_rate.append(v)
        free_out.append(SERVO_INERTIA * accel + SERVO_MGL_NM * np.sin(x))
    w = SERVO_RATIO * np.r_[rate, np.array(free_theta_rate)]
    return {"t": np.r_[t, t + 4.0], "T_in": np.r_[motor, np.zeros(n)] + rng.normal(0.0, 2e-5, 2 * n),
            "w_in": w + rng.normal(0.0, 1.0, 2 * n),
            "T_out": np.r_[out, np.array(free_out)] + rng.normal(0.0, 5e-3, 2 * n)}


def servo_plan(tmp: Path, swings, name: str, seed: int) -> tuple[Path, Path]:
    """The servo's swings ``(amplitude [rad], frequency [Hz])`` one after another, as one CSV and its map."""
    rng = np.random.default_rng(seed)
    csv = _export(tmp / f"{name}.csv", [_servo_run(a, f, rng) for a, f in swings])
    cmap = tmp / f"{name}_map.yaml"
    cmap.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T_in, unit: N*m}\n"
                    "motor_speed: {column: w_in, unit: rad/s}\noutput_torque: {column: T_out, unit: N*m}\n"
                    f"ratio: {SERVO_RATIO}\n")
    return csv, cmap
