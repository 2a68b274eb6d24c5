"""The calibrated model at operating points: what ``model`` and ``map`` print and write.

The losses come from the one :class:`~.estimator.Estimator` -- the paper's model plus the
accepted effects of the parameter file, exactly as the node and ``replay`` evaluate them -- fed
with the operating points as samples without measured output (so nothing adapts).  Two things
differ on purpose from evaluating a *recording*:

* the torque of an operating point is the gearbox's true input torque, so the accepted
  torque-sensor errors (``physical = False`` in the registry) are not applied: they describe the
  rig's sensors, not the gearbox the map is for;
* nothing is learned from the points: with ``estimator.speed_noise_rad_s: auto`` the loss's sign is
  the plain sign of each point's speed (a list of points is no speed reading whose noise could be
  learned; learning it from a grid smoothed the sign of its slow points), with a number the file's
  smooth sign as replay applies it -- each point's loss is the same alone or in any list;
* an effect that needs the oil temperature (``needs_temperature``) is evaluated at the
  temperature given; without one :func:`evaluate_points` refuses rather than silently using
  the reference viscosity.

Besides the totals, :class:`PointLosses` splits the loss magnitude into the paper's model
(``model_nm``, at ``η0``) and each accepted physical effect (``effects_nm``: the estimator with
that effect alone minus the model alone; a law in the load its term at the load the whole loss leaves,
:func:`~.effectsum.output_load`); they add up to ``loss_magnitude_nm`` (tested).  No rclpy import.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .effects import EFFECTS, EffectInputs, takes_load
from ..base.errors import UsageError
from .estimator import Estimator
from .params import Config, EffectParams
from .speednoise import AUTO

__all__ = ["PointLosses", "evaluate_points", "map_config", "only", "points_config", "reference_temperature_c",
           "rows_config", "temperature_effects"]


@dataclass
class PointLosses:
    """Losses of the calibrated model at operating points (arrays of equal length)."""

    torque_nm: np.ndarray
    speed_rad_s: np.ndarray
    temperature_c: np.ndarray  #: NaN where not given
    loss_torque_nm: np.ndarray  #: signed, input-referred, opposes rotation (NaN: point skipped)
    loss_magnitude_nm: np.ndarray
    loss_power_w: np.ndarray
    efficiency: np.ndarray  #: NaN where undefined
    model_nm: np.ndarray  #: the paper's model alone (at η0), loss magnitude
    breakdown_nm: dict[str, np.ndarray]  #: the paper's terms (at the effects' viscosity)
    effects_nm: dict[str, np.ndarray] = field(default_factory=dict)  #: accepted physical effect -> its share
    skipped: dict[str, int] = field(default_factory=dict)  #: reason -> points (implausible, non-finite)


def map_config(config: Config) -> Config:
    """``config`` with the sensor errors switched off (an operating point's torque is the true one)."""
    switches = {n: on and EFFECTS[n].physical for n, on in config.effects.switches.items()}
    return replace(config, effects=EffectParams(switches, config.effects.values))


def points_config(config: Config) -> Config:
    """``config`` as operating points are evaluated: :func:`map_config`, and a speed noise that is the
    file's number, never learned from the points (``auto``: the plain sign)."""
    cfg = map_config(config)
    if cfg.estimator.speed_noise_rad_s == AUTO:
        cfg = replace(cfg, estimator=replace(cfg.estimator, speed_noise_rad_s=0.0))
    return cfg


def rows_config(config: Config) -> Config:
    """``config`` as a steady-state table's rows are estimated against their measured loss: each row
    an operating point on its own -- nothing adapts between rows, the speed noise is never learned from
    them (``auto``: the plain sign) -- with the sensor errors kept (a row's torque is a reading)."""
    noise = config.estimator.speed_noise_rad_s
    return replace(config, estimator=replace(config.estimator, adapt=False,
                                             speed_noise_rad_s=0.0 if noise == AUTO else noise))


def temperature_effects(config: Config) -> list[str]:
    """Accepted physical effects that need the oil temperature."""
    return [n for n in config.effects.enabled() if EFFECTS[n].physical and EFFECTS[n].needs_temperature]


def reference_temperature_c(config: Config) -> float | None:
    """The reference temperature of the accepted effect that needs the oil's (where it changes
    nothing), None when no accepted effect needs one."""
    needing = temperature_effects(config)
    return float(config.effects.params(needing[0]).get("theta_ref", 40.0)) if needing else None


def evaluate_points(config: Config, torque_nm, speed_rad_s, temperature_c: float | None = None) -> PointLosses:
    """Evaluate the calibrated model at operating points (see the module docstring).

    ``torque_nm``, ``speed_rad_s``: equal-length arrays (signed; negative torque with positive
    speed is regeneration); ``temperature_c``: the oil temperature for effects that need one.
    Raises :class:`~base.errors.UsageError` when such an effect is accepted and no temperature given.
    """
    torque = np.atleast_1d(np.asarray(torque_nm, float))
    speed = np.atleast_1d(np.asarray(speed_rad_s, float))
    if torque.shape != speed.shape:
        raise ValueError("torque and speed must have the same length")
    cfg = points_config(config)
    needing = temperature_effects(cfg)
    if needing and temperature_c is None:
        raise UsageError(f"the accepted effect {', '.join(needing)} needs the oil temperature: "
                         "give --oil-temperature-c")
    n = len(torque)
    theta = np.full(n, np.nan if temperature_c is None else float(temperature_c))

    def run(effects: Config) -> tuple[np.ndarray, Estimator, object]:
        estimator = Estimator(effects, operating_points=True)  # points in no order: no run of them is a direction
        batch = estimator.process_batch(np.arange(n, dtype=np.int64), torque, speed, temperature=theta)
        magnitude = np.full(n, np.nan)
        magnitude[batch.t_ns.astype(np.intp)] = batch.loss_magnitude_nm
        return magnitude, estimator, batch

    magnitude, estimator, batch = run(cfg)
    kept = batch.t_ns.astype(np.intp)

    def scatter(values) -> np.ndarray:
        out = np.full(n, np.nan)
        out[kept] = values
        return out

    # each effect's share: the estimator with only that effect minus the paper's model alone
    # (exact for additive terms; Fr-scaling effects add up too, the model is linear in Fr)
    # a law in the load: its term at the load of the whole loss (alone it would see another load)
    model_nm = run(only(cfg, ()))[0]
    active = cfg.effects.active()
    load_x = EffectInputs(np.abs(torque), np.abs(speed), torque, np.sign(scatter(batch.sign)), theta,
                          abs_load=np.abs(torque - scatter(batch.loss_torque_nm)))
    shares = {name: EFFECTS[name].term(load_x, **active[name]) if takes_load(EFFECTS[name])
              else run(only(cfg, (name,)))[0] - model_nm for name in cfg.effects.enabled()}
    return PointLosses(
        torque_nm=torque, speed_rad_s=speed, temperature_c=theta,
        loss_torque_nm=scatter(batch.loss_torque_nm), loss_magnitude_nm=magnitude,
        loss_power_w=scatter(batch.loss_power_w), efficiency=scatter(batch.efficiency),
        model_nm=model_nm, breakdown_nm={k: scatter(v) for k, v in batch.breakdown_nm.items()},
        effects_nm=shares, skipped={k: v for k, v in estimator.counts.items() if v},
    )


def locked_points(config: Config, points: PointLosses) -> np.ndarray:
    """Which of ``points`` have no loss though inside the estimator's plausible range: where the file's
    laws in the load lock a back-driven drive (``load_unbalanced``, :func:`~.effectsum.output_load`)."""
    return np.isnan(points.loss_magnitude_nm) & config.estimator.plausible(np.asarray(points.torque_nm, float),
                                                                           np.asarray(points.speed_rad_s, float))


def only(config: Config, names: tuple[str, ...]) -> Config:
    """``config`` with only the effects ``names`` enabled (their parameters kept)."""
    switches = {n: n in names for n in config.effects.switches}
    return replace(config, effects=EffectParams(switches, config.effects.values))
