"""The enabled effects at a sample: their sum, the laws in the load at the load they take, the factor on the
model's Fr part -- what the estimator adds to the paper's model (:mod:`.effects` holds the laws).

A law in the load (:func:`~.effects.takes_load`) takes the output-side load ``T_load = T − sgn(ω)·L``, ``L``
the whole loss with the law's own part in it: where a sample gives only the drive torque, it is solved
(:func:`output_load`).  Everything runs on Python floats (the node's per-sample path) and numpy arrays
(replay) alike, with the same floats.  No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .effects import EFFECTS, Effect, EffectInputs, takes_load, with_temperature

__all__ = ["LOAD_BALANCE", "LOAD_MIN_SLOPE", "LOAD_STEPS", "EffectTerms", "additive_terms", "fr_scale", "output_load"]


@dataclass(frozen=True)
class EffectTerms:
    """The contributions of the enabled effects for one sample or an array of samples."""

    physical_nm: object  #: added to the published loss torque magnitude
    sensor_nm: object  #: added only to the expected *measured* loss
    #: the inputs the terms were evaluated at, ``abs_load`` among them (solved where it was not given)
    inputs: EffectInputs | None = None


#: Newton steps of :func:`output_load` (a fixed count: a float and an array element take the same steps)
LOAD_STEPS = 24
#: the torque balance :func:`output_load` must close, relative to the torques in it: no load closes it
#: closer where the laws lock the drive (a friction growing faster than the load that back-drives it)
LOAD_BALANCE = 1e-9
#: the least slope Newton's step divides by: a back-driven law may take up to 95 % of each further unit of
#: load; where a friction grows with the load as fast as the load (a self-locking drive) the steps run off
LOAD_MIN_SLOPE = 0.05


def _at_least(a, floor: float):
    return max(a, floor) if isinstance(a, float) else np.maximum(a, floor)


def output_load(x: EffectInputs, other_loss_nm, laws: Sequence[tuple[Effect, Mapping[str, float]]]):
    """``|T_load|`` and the laws' loss: ``T_load = T − s·(L_other + F(|T_load|))`` solved for ``T_load``.

    ``T`` the drive torque (``x.torque``), ``s`` the direction the loss opposes (``x.rot_sign``),
    ``L_other`` every loss that is not a law in the load (the paper's model and the other effects),
    ``F`` the sum of ``laws`` (effect, its parameters) at the load.  In the direction's frame
    ``v = sgn(s)·T_load`` solves ``v + |s|·F(|v|) = u``, ``u = sgn(s)·T − |s|·L_other``: Newton from ``v = u``,
    :data:`LOAD_STEPS` steps, each law's slope ``e·F_i/|T_load|`` (its exponent ``e`` in the load: a law
    linear in the load is solved in one step).  Where the load without the laws' own loss drives
    (``u ≥ |s|·F(0)``) the root is the one in ``[0, u]``, and a step never goes below a sixteenth of the
    last iterate -- a law steeper than the load near zero also balances a spurious back-driven load there;
    else the load back-drives (``v ≤ 0``).  Where the balance does not close (:data:`LOAD_BALANCE`: the
    laws lock a back-driven drive) both are NaN.  Same floats for a float and an array.
    """
    torque, s = x.torque, x.rot_sign
    if not laws:
        return abs(torque - s * other_loss_nm), 0.0 * x.abs_speed
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):  # a locked drive runs off: NaN below
        return _newton_load(x, torque, s, other_loss_nm, laws)


def _laws_at(x: EffectInputs, w, laws) -> tuple:
    """The laws' sum at the load ``w`` and its slope there (``Σ e_i·F_i / w``)."""
    xi = x._replace(abs_load=w)
    f, slope = 0.0 * w, 0.0 * w
    for effect, params in laws:
        fi = effect.term(xi, **params)
        e = params[effect.load_exponent] if isinstance(effect.load_exponent, str) else effect.load_exponent
        f = f + fi
        slope = slope + e * fi
    return f, slope / _at_least(w, 1e-300)


def _newton_load(x: EffectInputs, torque, s, other_loss_nm, laws):
    """:func:`output_load`'s steps (in the direction's frame ``v``)."""
    scalar = isinstance(torque, float)
    sigma = (s > 0) * 1.0 - (s < 0) * 1.0
    a = abs(s)
    u = sigma * torque - a * other_loss_nm
    f0, _ = _laws_at(x, 0.0 * u, laws)
    drives = u >= a * f0
    v = u
    for _ in range(LOAD_STEPS):
        f, slope = _laws_at(x, abs(v), laws)
        direction = (v > 0) * 1.0 - (v < 0) * 1.0
        step = (v + a * f - u) / _at_least(1.0 + a * direction * slope, LOAD_MIN_SLOPE)
        if scalar:
            v = min(max(v - step, 0.0625 * v), u) if drives else min(v - step, 0.0)
        else:
            v = np.where(drives, np.minimum(np.maximum(v - step, 0.0625 * v), u), np.minimum(v - step, 0.0))
    y = sigma * v + (sigma == 0) * torque  # no direction: the load is the drive torque
    w = abs(y)
    f, _ = _laws_at(x, w, laws)
    # where the balance stays open the laws lock the drive: no load (NaN), never a guess
    unbalanced = abs(y - torque + s * (other_loss_nm + f)) > LOAD_BALANCE * (abs(torque) + abs(other_loss_nm) + f)
    if scalar:
        return (math.nan, math.nan) if unbalanced or w != w else (w, f)
    return np.where(unbalanced, np.nan, w), np.where(unbalanced, np.nan, f)


def additive_terms(enabled: Mapping[str, Mapping[str, float]], x: EffectInputs,
                   model_loss_nm=0.0) -> EffectTerms:
    """Sum the enabled additive effects (``enabled``: name -> short parameters), in registry order, the
    laws in the load (:func:`takes_load`) last, at the load :func:`output_load` solves where ``x`` does
    not give it (``model_loss_nm``: the paper's model's loss magnitude, part of the loss that load is
    without); effects that scale the model's Fr part are applied inside the model instead (:func:`fr_scale`)."""
    phys = 0.0 * x.abs_speed
    sens = 0.0 * x.abs_speed
    laws = []
    for name, effect in EFFECTS.items():
        if name in enabled and not effect.scales_fr:
            xi = with_temperature(x, enabled[name]) if effect.needs_temperature else x
            if takes_load(effect):
                laws.append((effect, enabled[name]))
            elif effect.physical:
                phys = phys + effect.term(xi, **enabled[name])
            else:
                sens = sens + effect.term(xi, **enabled[name])
    if x.abs_load is None:
        w, f = output_load(x, model_loss_nm + phys, laws)
        x = x._replace(abs_load=w)
        return EffectTerms(phys + f, sens, x)
    for effect, params in laws:
        phys = phys + effect.term(x, **params)
    return EffectTerms(phys, sens, x)


def fr_scale(enabled: Mapping[str, Mapping[str, float]], x: EffectInputs):
    """Factor on the model's Fr part from the enabled Fr-scaling effects (1 when none is enabled)."""
    scale = 1.0
    for name, effect in EFFECTS.items():
        if name in enabled and effect.scales_fr:
            scale = scale + effect.term(x._replace(fr_part_nm=1.0), **enabled[name])
    return scale
