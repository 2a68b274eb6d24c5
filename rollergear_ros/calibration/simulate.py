"""Synthetic rig recordings: drive profiles through the model plus *declared* extra effects.

The rig's "true" loss is ``model(T, ω, η(θ)) + Σ physical effects``: the whole chain of eq. 1–30
(:func:`core.model.reference_terms`) evaluated at the oil's viscosity per sample, not the estimator's
factored form.  ``η(θ)`` follows the declared ``viscosity_temperature`` effect's Vogel law (written
out here, not the effect's term) or, with ``oil_nu40_nu100_mm2_s``, a real oil's ASTM D341 (Walther)
line through its data-sheet ν40 and ν100 -- a law the calibrator does not share.  The measured output torque is
``T_out = ratio·(T_in − T_loss·sgn ω)`` (power balance with ``ω_out = ω_in/ratio``), and sensor
effects corrupt the *reported* input torque: ``T_in,meas = (1 + g)·T_in + b``.  Noise (white or
AR(1)-coloured) is added to every channel; an optional lag delays the output-torque channel.
What was simulated is written into the bag's metadata record ``rollergear_simulation`` (ground
truth for tests — ``calibrate`` never reads it).  Seeded and reproducible.  No rclpy.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from collections.abc import Callable

import numpy as np

from ..core.oil import oil_viscosity_ratio, vogel_viscosity_ratio, walther_viscosity_mm2_s  # noqa: F401 - re-exported
from ..recordings.bagwriter import BagWriter
from ..recordings.messages import TopicMap, float64_payloads, stamp
from ..core.effects import EFFECTS, EffectInputs, takes_load, viscosity_law
from ..base.errors import UsageError
from ..base.interface import RAD_S_PER_RPM, MessageType, Metadata
from ..core.model import LossModel, reference_terms, rotation_sign
from ..core.params import Config


@dataclass
class DeclaredEffect:
    name: str
    params: dict[str, float]

    @classmethod
    def parse(cls, text: str) -> DeclaredEffect:
        """``drag_speed:c=2e-4,p=1.5``: an effect of the registry with its parameters by their short
        names; missing values take the registry's ``simulated`` defaults."""
        name, _, rest = text.partition(":")
        name = name.strip()
        if name not in EFFECTS:
            raise UsageError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        params = EFFECTS[name].simulated_defaults()
        for item in filter(None, (s.strip() for s in rest.split(","))):
            k, _, v = item.partition("=")
            if k not in params:
                raise UsageError(f"effect {name} has no parameter {k!r}; it takes {', '.join(params)}")
            try:
                val = float(v)
            except ValueError:
                val = math.nan
            if not math.isfinite(val):
                raise UsageError(f"effect {name}: {k} must be a finite number, not {v!r}")
            params[k] = val
        return cls(name, params)


@dataclass
class Profile:
    """A drive profile: time [s], drive speed [rad/s], drive torque [N·m], oil temperature [°C]."""

    t_s: np.ndarray
    speed_rad_s: np.ndarray
    torque_nm: np.ndarray
    temperature_c: np.ndarray
    dwell_id: np.ndarray  #: operating-point index (for grouped cross-validation downstream)


def _dwells(points: list[tuple[float, float]], dwell_s: float, rate_hz: float, ramp_s: float,
            temperature_c: float = 40.0) -> Profile:
    """Piecewise-constant operating points with short linear ramps between them."""
    n_dwell = int(round(dwell_s * rate_hz))
    n_ramp = max(int(round(ramp_s * rate_hz)), 1)
    w_parts, t_parts, ids = [], [], []
    prev = (0.0, 0.0)
    for i, (w, tq) in enumerate(points):
        w_parts.append(np.linspace(prev[0], w, n_ramp, endpoint=False))
        t_parts.append(np.linspace(prev[1], tq, n_ramp, endpoint=False))
        ids.append(np.full(n_ramp, -1))
        w_parts.append(np.full(n_dwell, w))
        t_parts.append(np.full(n_dwell, tq))
        ids.append(np.full(n_dwell, i))
        prev = (w, tq)
    w = np.concatenate(w_parts)
    tq = np.concatenate(t_parts)
    n = len(w)
    return Profile(np.arange(n) / rate_hz, w, tq, np.full(n, temperature_c), np.concatenate(ids))


def rig_map(rate_hz: float, dwell_s: float = 1.0, bidirectional: bool = False,
            speeds_rpm=(250, 500, 1000, 1500, 2000, 2500), torques_nm=(-60, -30, -10, 5, 10, 30, 60, 90)) -> Profile:
    """Speed plateaus × torque steps (both torque signs: motoring and regeneration)."""
    directions = (1, -1) if bidirectional else (1,)
    pts = [(d * s * RAD_S_PER_RPM, float(t)) for d in directions for s in speeds_rpm for t in torques_nm]
    return _dwells(pts, dwell_s, rate_hz, ramp_s=0.05)


def drive_cycle(rate_hz: float, duration_s: float = 120.0, seed: int = 0) -> Profile:
    """A dynamic cycle: accelerations, cruising, regenerative braking and a reverse manoeuvre."""
    rng = np.random.default_rng(seed + 1000)
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    # speed: smoothed random walk of targets, with a reverse segment near the end
    knots = np.concatenate([[0.0], rng.uniform(30, 280, 10), [0.0, -60.0, -60.0, 0.0]])
    kt = np.linspace(0, duration_s, len(knots))
    w = np.interp(t, kt, knots)
    k = max(int(rate_hz * 1.5), 1)
    w = np.convolve(np.pad(w, (k, k), mode="edge"), np.ones(k) / k, mode="same")[k:-k]
    dw = np.gradient(w, 1.0 / rate_hz)
    inertia = 1.0
    road = 8.0 * np.sign(w) + 2e-4 * w * np.abs(w)
    torque = inertia * dw + road * (np.abs(w) > 1.0)
    return Profile(t, w, np.clip(torque, -120, 120), np.full(n, 45.0), (t // 2.0).astype(int))


def warmup(rate_hz: float, duration_s: float = 240.0, theta0_c: float = 20.0, theta1_c: float = 85.0,
           tau_s: float = 70.0, bidirectional: bool = True) -> Profile:
    """Repeating operating points while the oil warms up (first-order, time constant ``tau_s``)."""
    pts = [(s * RAD_S_PER_RPM * d, tq) for d in ((1, -1) if bidirectional else (1,))
           for s in (500, 1500, 2500) for tq in (-40.0, 10.0, 50.0)]
    base = _dwells(pts, 1.0, rate_hz, 0.05)
    reps = int(math.ceil(duration_s * rate_hz / len(base.t_s)))
    n = int(duration_s * rate_hz)
    w = np.tile(base.speed_rad_s, reps)[:n]
    tq = np.tile(base.torque_nm, reps)[:n]
    ids = np.tile(base.dwell_id, reps)[:n]
    rep = np.repeat(np.arange(reps), len(base.t_s))[:n]
    t = np.arange(n) / rate_hz
    theta = theta1_c + (theta0_c - theta1_c) * np.exp(-t / tau_s)
    return Profile(t, w, tq, theta, np.where(ids >= 0, ids + rep * 1000, -1))


PROFILES: dict[str, Callable[..., Profile]] = {
    "rig_map": lambda rate, seed: rig_map(rate),
    "bidirectional_map": lambda rate, seed: rig_map(rate, bidirectional=True),
    "drive_cycle": lambda rate, seed: drive_cycle(rate, seed=seed),
    "warmup": lambda rate, seed: warmup(rate),
}


@dataclass
class SimulationOptions:
    profile: str = "rig_map"
    rate_hz: float = 200.0
    seed: int = 0
    effects: list[DeclaredEffect] = field(default_factory=list)
    torque_noise_nm: float = 0.01
    speed_noise_rad_s: float = 0.02
    temperature_noise_c: float = 0.05
    noise_ar1: float = 0.0  #: AR(1) coefficient of the noise (0 = white)
    output_lag_s: float = 0.0  #: delay of the output-torque channel
    temperature_rate_hz: float = 10.0
    joint_states: bool = False
    start_ns: int = 1_700_000_000_000_000_000
    step_change_at_s: float | None = None  #: effects step here (None: constant from the start)
    step_from_factor: float = 0.0  #: effect magnitudes before the step, as a fraction of the declared ones
    #: the oil of the viscosity_temperature effect, by its data-sheet ν40 and ν100 [mm²/s] (ASTM D341);
    #: None: the effect's Vogel B and C
    oil_nu40_nu100_mm2_s: tuple[float, float] | None = None


@dataclass
class SimulatedRig:
    """Everything the simulator produced (true and measured channels)."""

    t_ns: np.ndarray
    speed_rad_s: np.ndarray
    torque_true_nm: np.ndarray
    torque_meas_nm: np.ndarray
    out_torque_meas_nm: np.ndarray
    out_speed_meas_rad_s: np.ndarray
    temperature_c: np.ndarray
    loss_true_nm: np.ndarray  #: true loss magnitude (model + physical effects)
    model_loss_nm: np.ndarray  #: the paper's model at the true inputs and eta0
    dwell_id: np.ndarray
    ratio: float


def _noise(rng: np.random.Generator, n: int, sigma: float, ar1: float) -> np.ndarray:
    e = rng.normal(0.0, sigma, n)
    if ar1 <= 0 or sigma == 0:
        return e
    from scipy.signal import lfilter

    return lfilter([math.sqrt(1 - ar1 ** 2)], [1.0, -ar1], e)


def _laws_at_true_load(x: EffectInputs, other_loss_nm: np.ndarray, laws: list, active: np.ndarray,
                       halvings: int = 200) -> np.ndarray:
    """The loss of the laws in the load at the output-side load they make themselves: the root ``v`` of
    ``v + F(|v|) = s·T − L_other`` (``v = s·T_load``, ``F`` the laws' sum times ``active``) by bisection
    on a bracket, to the last bit -- the rig's physics, not the estimator's Newton steps.  A drive the laws
    lock (no root: a friction growing faster than the load that back-drives it) is refused."""
    def F(v):
        xi = x._replace(abs_load=np.abs(v))
        return active * sum(effect.term(xi, **p) for effect, p in laws)

    s = np.where(x.rot_sign == 0, 0.0, np.sign(x.rot_sign))
    u = s * x.torque - other_loss_nm
    f0 = F(np.zeros_like(u))
    lo = np.where(f0 - u <= 0, 0.0, -(np.abs(u) + f0 + 1e-12))
    hi = np.where(f0 - u <= 0, np.maximum(u, 0.0), 0.0)
    for _ in range(200):  # widen downwards until h(lo) <= 0 (a back-driven drive: |T_load| > |T|)
        up = lo + F(lo) - u > 0
        if not up.any():
            break
        hi, lo = np.where(up, lo, hi), np.where(up, 2.0 * lo, lo)
    else:
        raise UsageError("the simulated laws in the load lock the drive: no output-side load balances the "
                         "drive torque (a friction growing faster than the load that back-drives it)")
    for _ in range(halvings):
        mid = 0.5 * (lo + hi)
        below = mid + F(mid) - u <= 0
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    v = 0.5 * (lo + hi)
    return np.where(s == 0, F(x.torque), F(v))


def simulate(config: Config, opts: SimulationOptions) -> SimulatedRig:
    """Run the rig simulation (no file I/O)."""
    if opts.profile not in PROFILES:
        raise UsageError(f"unknown profile {opts.profile!r}; known: {', '.join(PROFILES)}")
    if not (opts.rate_hz > 0 and math.isfinite(opts.rate_hz)):
        raise UsageError("rate must be a positive number of Hz")
    prof = PROFILES[opts.profile](opts.rate_hz, opts.seed)
    rng = np.random.default_rng(opts.seed)
    g = config.gearbox
    model = LossModel(g)
    ratio = g.ratio_effective
    w, tq, theta = prof.speed_rad_s, prof.torque_nm, prof.temperature_c
    aw, at = np.abs(w), np.abs(tq)
    sg = rotation_sign(w, tq)
    active = (np.ones(len(w)) if opts.step_change_at_s is None
              else np.where(prof.t_s >= opts.step_change_at_s, 1.0, opts.step_from_factor))
    eta_ratio = np.ones(len(w))  # η(θ)/η0
    extra = np.zeros(len(w))
    gain, offset = 0.0, 0.0
    laws = []  # the laws in the load: at the true output-side load, once the other losses are known
    effects = list(opts.effects)
    law = viscosity_law()
    if opts.oil_nu40_nu100_mm2_s is not None and not any(e.name == law.name for e in effects):
        effects.append(DeclaredEffect(law.name, law.simulated_defaults()))
    for eff in effects:
        p = eff.params
        effect = EFFECTS[eff.name]
        if effect.viscosity_law:
            if opts.oil_nu40_nu100_mm2_s is not None:
                eta_ratio = oil_viscosity_ratio(theta, *opts.oil_nu40_nu100_mm2_s, p["theta_ref"]) ** active
            else:
                eta_ratio = vogel_viscosity_ratio(theta, p["B"], p["C"], p["theta_ref"]) ** active
        elif effect.reading_error == "offset":  # the sensor reads T_meas = (1 + g)·T + b
            offset = offset + p[effect.coefficient] * active
        elif effect.reading_error == "gain":
            gain = gain + p[effect.coefficient] * active
        elif takes_load(effect):
            laws.append((effect, p))
        elif effect.physical:  # any other loss: its term, added to the true loss
            extra += effect.term(EffectInputs(at, aw, tq, sg, theta), **p) * active
        else:
            raise UsageError(f"simulate does not know how the sensor error {eff.name} corrupts a reading")
    model_loss = model.loss_magnitude(tq, w)
    loss_true = reference_terms(g, tq, w, g.eta0_pa_s * eta_ratio)["T_loss"] + extra
    if laws:
        x = EffectInputs(at, aw, tq, sg, theta)
        loss_true = loss_true + _laws_at_true_load(x, loss_true, laws, active)
    out_torque_true = ratio * (tq - loss_true * sg)
    n = len(w)
    torque_meas = tq + gain * tq + offset + _noise(rng, n, opts.torque_noise_nm, opts.noise_ar1)
    out_torque_meas = out_torque_true + _noise(rng, n, opts.torque_noise_nm * ratio, opts.noise_ar1)
    if opts.output_lag_s > 0:
        lag = int(round(opts.output_lag_s * opts.rate_hz))
        out_torque_meas = np.concatenate([np.full(lag, out_torque_meas[0]), out_torque_meas[:n - lag]])
    speed_meas = w + _noise(rng, n, opts.speed_noise_rad_s, 0.0)
    out_speed_meas = w / ratio + _noise(rng, n, opts.speed_noise_rad_s / ratio, 0.0)
    temp_meas = theta + rng.normal(0.0, opts.temperature_noise_c, n)
    t_ns = opts.start_ns + np.round(prof.t_s * 1e9).astype(np.int64)
    return SimulatedRig(t_ns, speed_meas, tq, torque_meas, out_torque_meas, out_speed_meas, temp_meas,
                        loss_true, model_loss, prof.dwell_id, ratio)


def write_rig_bag(rig: SimulatedRig, opts: SimulationOptions, path: Path, topics: TopicMap = TopicMap(),
                  progress: Callable[[int], None] | None = None, gearbox_id: str | None = None) -> int:
    """Write a simulated rig to a ROS 2 MCAP; returns the number of messages written.  ``gearbox_id``
    goes into the ``rollergear`` metadata record, as a fleet's logger writes it."""
    with BagWriter(path) as bw:
        _write_metadata(bw, opts, gearbox_id)
        return _write_samples(bw, rig, opts, topics, progress)


@dataclass(frozen=True)
class Written:
    """What :func:`write_simulation` wrote."""

    messages: int
    samples: int
    duration_s: float  #: from the first sample to the last
    repeats: int  #: the profile's passes (the last one cut)


def write_simulation(config: Config, opts: SimulationOptions, path: Path, duration_s: float | None = None,
                     topics: TopicMap = TopicMap(), progress: Callable[[int], None] | None = None) -> Written:
    """Simulate and write a recording of ``duration_s`` seconds (None: the profile once): the profile runs
    again and again, each pass on from the last one's clock with its seed advanced by one (its noise and a
    drive cycle's knots new), the last pass cut at the duration.  One pass is held in memory at a time, so
    a week at 1 kHz costs what one pass does; a step change (``opts.step_change_at_s``) is on the
    recording's clock."""
    if duration_s is not None and not (duration_s > 0 and math.isfinite(duration_s)):
        raise UsageError(f"--duration must be a positive number of seconds, not {duration_s!r}")
    period_ns = 1e9 / opts.rate_hz
    messages = samples = repeats = 0
    last_ns = first_ns = opts.start_ns
    with BagWriter(path) as bw:
        _write_metadata(bw, opts, None, duration_s)
        while True:
            offset_ns = int(round(samples * period_ns))
            step = None if opts.step_change_at_s is None else opts.step_change_at_s - offset_ns * 1e-9
            rig = simulate(config, replace(opts, seed=opts.seed + repeats, start_ns=opts.start_ns + offset_ns,
                                           step_change_at_s=step))
            repeats += 1
            if duration_s is not None:
                rig = cut_rig(rig, first_ns + int(round(duration_s * 1e9)))
            if len(rig.t_ns):
                messages += _write_samples(bw, rig, opts, topics, progress)
                samples += len(rig.t_ns)
                last_ns = int(rig.t_ns[-1])
            if duration_s is None or not len(rig.t_ns) or last_ns + period_ns > first_ns + duration_s * 1e9:
                break
    return Written(messages, samples, (last_ns - first_ns) * 1e-9, repeats)


def cut_rig(rig: SimulatedRig, end_ns: int) -> SimulatedRig:
    """The rig's samples up to ``end_ns`` (included)."""
    keep = rig.t_ns <= end_ns
    if keep.all():
        return rig
    return replace(rig, **{f.name: getattr(rig, f.name)[keep] for f in fields(rig)
                           if isinstance(getattr(rig, f.name), np.ndarray) and len(getattr(rig, f.name)) == len(keep)})


def _write_metadata(bw: BagWriter, opts: SimulationOptions, gearbox_id: str | None,
                    duration_s: float | None = None) -> None:
    truth = {"profile": opts.profile, "seed": opts.seed, "rate_hz": opts.rate_hz,
             "effects": [{"name": e.name, "params": e.params} for e in opts.effects],
             "torque_noise_nm": opts.torque_noise_nm, "noise_ar1": opts.noise_ar1,
             "output_lag_s": opts.output_lag_s, "step_change_at_s": opts.step_change_at_s,
             "step_from_factor": opts.step_from_factor,
             "joint_states": opts.joint_states, "oil_nu40_nu100_mm2_s": opts.oil_nu40_nu100_mm2_s}
    if duration_s is not None:
        truth["duration_s"] = duration_s  # the profile repeated, each pass's seed one more
    bw.add_metadata(Metadata.SIMULATION, {"truth": json.dumps(truth)})
    if gearbox_id is not None:
        bw.add_metadata(Metadata.GEARBOX, {"gearbox_id": gearbox_id})


def _write_samples(bw: BagWriter, rig: SimulatedRig, opts: SimulationOptions, topics: TopicMap,
                   progress: Callable[[int], None] | None) -> int:
    """The rig's samples as messages (each temperature after the sample of its time); their count."""
    count = 0
    n = len(rig.t_ns)
    block = 20_000
    temp_every = max(int(round(opts.rate_hz / opts.temperature_rate_hz)), 1)
    float64_topics = [(name, MessageType.FLOAT64, None) for name in
                      (topics.motor_torque, topics.motor_speed, topics.output_torque, topics.output_speed)]
    for s in range(0, n, block):
        e = min(s + block, n)
        if opts.joint_states:
            for i in range(s, e):
                t = int(rig.t_ns[i])
                bw.write_message(topics.joint_states, MessageType.JOINT_STATE, t, {
                    "header": {"stamp": stamp(t), "frame_id": ""},
                    "name": [topics.input_joint, topics.output_joint], "position": [],
                    "velocity": [float(rig.speed_rad_s[i]), float(rig.out_speed_meas_rad_s[i])],
                    "effort": [float(rig.torque_meas_nm[i]), float(rig.out_torque_meas_nm[i])]})
        else:
            # the four channels interleaved sample by sample, as a recorder stores them
            values = np.stack([rig.torque_meas_nm[s:e], rig.speed_rad_s[s:e], rig.out_torque_meas_nm[s:e],
                               rig.out_speed_meas_rad_s[s:e]], axis=1).reshape(-1)
            bw.write_fixed_mixed(float64_topics, np.tile(np.arange(4), e - s), np.repeat(rig.t_ns[s:e], 4),
                                 float64_payloads(values))
        count += (e - s) * (1 if opts.joint_states else 4)
        # each temperature after the sample of its time (the buffer keeps the order added among equal times)
        for i in range(s + (-s) % temp_every, e, temp_every):
            bw.write_message(topics.oil_temperature, MessageType.TEMPERATURE, int(rig.t_ns[i]),
                             _temperature_message(rig, opts, i))
            count += 1
        bw.release(int(rig.t_ns[e - 1]))  # what comes next is later: written now, not held to the end
        if progress:
            progress(e - s)
    return count


def _temperature_message(rig: SimulatedRig, opts: SimulationOptions, i: int) -> dict:
    t = int(rig.t_ns[i])
    return {"header": {"stamp": stamp(t), "frame_id": "oil"}, "temperature": float(rig.temperature_c[i]),
            "variance": opts.temperature_noise_c ** 2}


def read_truth(path: Path) -> dict:
    """The ``rollergear_simulation`` metadata of a simulated bag (for tests and docs only)."""
    from ..recordings.baginfo import read_metadata

    md = read_metadata(path, Metadata.SIMULATION)
    if md is None:
        raise KeyError(f"{path} has no rollergear_simulation metadata")
    return json.loads(md["truth"])
