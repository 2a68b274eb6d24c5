"""The live loss map: the calibrated model with the online-adapted coefficients, for energy managers.

The node publishes it on ``loss/map`` (``std_msgs/msg/Float64MultiArray``; reliable,
transient-local, depth 1: a late subscriber gets the last one) when it starts, whenever an
adapted coefficient has moved beyond its 95 % interval since the map last published and, for a
model that follows the oil, whenever the oil temperature has moved ``node.map_oil_step_c`` from
the map's; and optionally rewrites a VECTO ``.vtlm`` file atomically (``node.map_file``).  The
grid is the parameter file's ``map.*`` (as ``rollergear map``), forward rotation.

Layout of the message (:func:`to_multiarray`, read back by :func:`from_multiarray`): a map over
speed × torque × oil temperature with one temperature, the one it was evaluated at::

    layout.dim[0] = {label: "speed_rpm", size: Ns, stride: Ns*Nt}
    layout.dim[1] = {label: "torque_nm", size: Nt, stride: Nt}
    layout.dim[2] = {label: "oil_temperature_c", size: 1, stride: 1}
    layout.data_offset = Ns + Nt + 1
    data[0 : Ns]                  input speeds [rpm], ascending
    data[Ns : Ns + Nt]            input torques [N·m], ascending (negative: overrun)
    data[Ns + Nt]                 the oil temperature [°C] the map was evaluated at; NaN: the
                                  model does not follow the oil (the map holds at any temperature)
    data[Ns + Nt + 1 + i*Nt + j]  torque loss [N·m] (input-referred magnitude, as in a .vtlm)
                                  at speed i, torque j

No rclpy import (the node fills the message from :func:`to_multiarray`'s plain values).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..core.effects import EFFECTS
from .lossmap import LossMap, build_map, grid
from ..core.operating_points import reference_temperature_c, temperature_effects
from ..core.params import Config, validate

__all__ = ["MapArray", "ReceivedMap", "adapted_config", "coefficients_moved", "from_multiarray", "live_map",
           "map_grid", "oil_moved", "to_multiarray"]

SPEED_LABEL = "speed_rpm"
TORQUE_LABEL = "torque_nm"
TEMPERATURE_LABEL = "oil_temperature_c"


def map_grid(config: Config) -> tuple[np.ndarray, np.ndarray]:
    """Speeds [rpm] and torques [N·m] of the parameter file's map grid (``map.*``)."""
    m = config.map
    return (grid(m.speed_min_rpm, m.last_speed_rpm(config.gearbox), m.speed_step_rpm),
            grid(*m.torques_nm(config.gearbox)))


def adapted_config(config: Config, coefficients: Mapping[str, float]) -> Config:
    """``config`` with the adapted linear coefficients of its accepted effects (validated)."""
    flat = config.to_flat()
    for name, value in coefficients.items():
        effect = EFFECTS[name]
        flat[f"effects.{name}.{effect.parameter(effect.coefficient).key}"] = float(value)
    return validate(flat)


def live_map(config: Config, coefficients: Mapping[str, float],
             oil_temperature_c: float | None) -> tuple[Config, LossMap]:
    """The parameters with the adapted ``coefficients``, and their map.  An accepted effect that
    needs the oil temperature is evaluated at ``oil_temperature_c`` (the last one measured), else
    at its reference temperature (where it changes nothing); a model that follows no oil is
    evaluated at none (the map's ``temperature_c`` is None)."""
    adapted = adapted_config(config, coefficients)
    temperature = None
    if temperature_effects(adapted):
        temperature = oil_temperature_c if oil_temperature_c is not None else reference_temperature_c(adapted)
    speeds, torques = map_grid(adapted)
    return adapted, build_map(adapted, speeds, torques, temperature)


def coefficients_moved(published: Mapping[str, float], current: Mapping[str, float],
                       intervals: Mapping[str, tuple[float, float]]) -> list[str]:
    """The coefficients whose value when the map was published lies outside their current 95 %
    interval (the adaptation has moved them by more than their uncertainty)."""
    moved = []
    for name in current:
        lo, hi = intervals.get(name, (-math.inf, math.inf))
        if name not in published or not lo <= published[name] <= hi:
            moved.append(name)
    return moved


def oil_moved(config: Config, map_temperature_c: float | None, oil_temperature_c: float | None) -> bool:
    """Whether a model that follows the oil needs a new map: the oil has moved at least
    ``node.map_oil_step_c`` (> 0) from the temperature the last map was evaluated at."""
    step = config.node.map_oil_step_c
    if step <= 0 or oil_temperature_c is None or not temperature_effects(config):
        return False
    return map_temperature_c is None or abs(oil_temperature_c - map_temperature_c) >= step


@dataclass(frozen=True)
class MapArray:
    """The plain values of a ``Float64MultiArray`` (see the module docstring)."""

    labels: tuple[str, str]
    sizes: tuple[int, int]
    strides: tuple[int, int]
    data_offset: int
    data: np.ndarray


def to_multiarray(loss_map: LossMap) -> MapArray:
    """The map in the message's layout."""
    ns, nt = len(loss_map.speeds_rpm), len(loss_map.torques_nm)
    temperature = math.nan if loss_map.temperature_c is None else float(loss_map.temperature_c)
    data = np.concatenate([loss_map.speeds_rpm, loss_map.torques_nm, [temperature],
                           loss_map.loss_nm.ravel()]).astype(float)
    return MapArray((SPEED_LABEL, TORQUE_LABEL, TEMPERATURE_LABEL), (ns, nt, 1), (ns * nt, nt, 1), ns + nt + 1, data)


@dataclass(frozen=True)
class ReceivedMap:
    """A loss map read back from a message (:func:`from_multiarray`)."""

    speeds_rpm: np.ndarray
    torques_nm: np.ndarray
    oil_temperature_c: float  #: NaN: the model follows no oil
    loss_nm: np.ndarray  #: ``[speed, torque]``


def from_multiarray(labels, sizes, data_offset: int, data) -> ReceivedMap:
    """The map of a received message's fields (the module docstring's layout)."""
    if tuple(labels) != (SPEED_LABEL, TORQUE_LABEL, TEMPERATURE_LABEL):
        raise ValueError(f"not a loss map: dimensions {list(labels)}")
    ns, nt, nk = (int(s) for s in sizes)
    values = np.asarray(data, dtype=float)
    head = ns + nt + nk
    if nk != 1 or data_offset != head or len(values) != head + ns * nt:
        raise ValueError(f"a loss map of {ns} x {nt} x 1 needs {head + ns * nt} values after an offset of "
                         f"{head}, got {len(values)} (offset {data_offset}, {nk} temperatures)")
    return ReceivedMap(values[:ns], values[ns:ns + nt], float(values[ns + nt]), values[head:].reshape(ns, nt))
