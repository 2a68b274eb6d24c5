"""The calibrated model as a table an FMU carries: loss over speed × torque × oil temperature.

``rollergear export --fmu`` (:mod:`outputs.fmu`) puts the model into a co-simulation unit that
runs where this package is not installed, so the unit holds the model as a table and interpolates
it (trilinear, in the unit's C source ``outputs/fmu_gearbox.c``).  The table's nodes are the model
itself (:func:`core.operating_points.evaluate_points`: the paper's model and the accepted
physical effects, the rig's torque-sensor errors not applied, as in ``map``); its stated
interpolation error is measured here, against the model at every cell's centre and the middle
of every cell edge -- where a linear interpolation is furthest from its nodes.

Grid: the speeds of the ``map.*`` grid (0 … the rated speed, or what ``export`` asks for; widened to
what the calibration analysed) mirrored to both directions, with the nodes of the model's smoothing of
``sgn ω`` (±3 σ of the speed noise) added; the torques of ``map.*`` (both signs; widened alike); oil
temperatures ``-20 … 140 °C`` every 5 °C when an accepted effect
needs the oil's (one node otherwise: the table holds at any temperature).  No rclpy import.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from ..base.errors import UsageError
from ..base.interface import RPM_PER_RAD_S
from ..core.modelform import ModelForm
from ..core.operating_points import temperature_effects
from ..core.params import Config, grid_cells_problem
from .lossmap import plausible_points

__all__ = ["DEFAULT_OIL_GRID_C", "LossTable", "interpolate", "loss_table"]

#: oil temperatures of a table whose model follows the oil: start, stop, step [°C]
DEFAULT_OIL_GRID_C = (-20.0, 140.0, 5.0)
#: nodes added near standstill and zero torque, where the loss bends most (``U^0.66``, the sign smoothing)
NEAR_ZERO_RAD_S = np.array([0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0,
                            6.0, 7.5])
NEAR_ZERO_NM = np.array([0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5,
                         3.0, 4.0, 5.0, 6.0, 7.5, 10.0, 12.5, 15.0])
#: an oil temperature interval is halved while linear interpolation misses its middle by more than this
TEMPERATURE_TOLERANCE = 0.002
#: ... down to this step [°C]
MIN_TEMPERATURE_STEP_C = 0.25
#: the most nodes a table may hold (the FMU reads them all at instantiation)
MAX_TABLE_NODES = 2_000_000


@dataclass
class LossTable:
    """Loss magnitude [N·m] at the nodes ``speeds_rad_s × torques_nm × temperatures_c`` (ascending)."""

    speeds_rad_s: np.ndarray
    torques_nm: np.ndarray
    temperatures_c: np.ndarray  #: one node: the model follows no oil
    loss_nm: np.ndarray  #: ``[speed, torque, temperature]``
    min_torque_nm: float  #: efficiency undefined below (the estimator's threshold)
    min_speed_rad_s: float
    follows_oil: bool
    interpolation_error_nm: float = 0.0  #: the largest |table − model| found between the nodes
    #: the same relative to the model's loss, where the efficiency is defined (``|T| ≥ min_torque_nm``,
    #: ``|ω| ≥ min_speed_rad_s``) and the loss ≥ 1e-3 N·m
    interpolation_error_relative: float = 0.0
    provenance: dict[str, str] = field(default_factory=dict)
    #: what the calibration analysed: the largest |ω| [rad/s] and |T| [N·m], the oil's span [°C] (None: not
    #: said); None: the file states no calibrated range (``calibration.model_form``'s ``seen``)
    calibrated: tuple[float, float, tuple[float, float] | None] | None = None
    rated: tuple[float, float] = (math.inf, math.inf)  #: the gearbox's rated |ω| [rad/s] and |T| [N·m]

    def ranges_text(self) -> tuple[str, str]:
        """The calibrated and the rated range in words (the unit's provenance)."""
        if self.calibrated is None:
            calibrated = "not stated (the parameter file holds no calibration.model_form)"
        else:
            speed, torque, oil = self.calibrated
            calibrated = f"|w| <= {speed:.6g} rad/s, |T| <= {torque:.6g} N*m" + (
                f", oil {oil[0]:g} ... {oil[1]:g} degC" if oil is not None and self.follows_oil else "")
        return calibrated, f"|w| <= {self.rated[0]:.6g} rad/s, |T| <= {self.rated[1]:.6g} N*m"

    def as_json(self) -> dict:
        """What the FMU's JSON resource holds: everything but the loss values (those go to a binary
        file of little-endian doubles, C order ``[speed][torque][temperature]``)."""
        return {"speeds_rad_s": self.speeds_rad_s.tolist(), "torques_nm": self.torques_nm.tolist(),
                "temperatures_c": self.temperatures_c.tolist(),
                "min_torque_nm": self.min_torque_nm, "min_speed_rad_s": self.min_speed_rad_s,
                "follows_oil": self.follows_oil, "interpolation_error_nm": self.interpolation_error_nm,
                "interpolation_error_relative": self.interpolation_error_relative, "provenance": self.provenance}


def _axis(start: float, stop: float, step: float) -> np.ndarray:
    """``start … stop`` in ``step`` increments, ``stop`` included also where the range is no multiple
    of the step (the table covers what was asked for, and not beyond it)."""
    from .lossmap import grid

    points = grid(start, stop, step)
    return points if points[-1] >= stop - 1e-9 * max(1.0, abs(stop)) else np.append(points, stop)


def loss_table(config: Config, oil_grid_c: tuple[float, float, float] | None = None,
               speed_max_rpm: float | None = None, torque_max_nm: float | None = None) -> LossTable:
    """The model of ``config`` tabulated, with its interpolation error measured (module docstring).

    The grid spans ``speed_max_rpm`` and ``± torque_max_nm``; None: the ``map.*`` grid's, widened to what the
    calibration analysed where that is more (a step of the grid beyond it), so that a drive the calibration
    knows is inside the table."""
    from .livemap import map_grid

    form = ModelForm.from_text(config.calibration.model_form)
    seen = None if form is None or not math.isfinite(form.seen_speed_rad_s) else (
        form.seen_speed_rad_s, form.seen_torque_nm, form.seen_oil_c)
    m, g = config.map, config.gearbox
    if speed_max_rpm is None:
        speed_max_rpm = m.last_speed_rpm(g)
        if seen is not None and seen[0] * RPM_PER_RAD_S > speed_max_rpm:
            speed_max_rpm = (math.floor(seen[0] * RPM_PER_RAD_S / m.speed_step_rpm) + 1) * m.speed_step_rpm
    if torque_max_nm is None:
        torque_max_nm = max(abs(v) for v in m.torque_range_nm(g))
        if seen is not None and math.isfinite(seen[1]) and seen[1] > torque_max_nm:
            torque_max_nm = (math.floor(seen[1] / m.torque_step_nm) + 1) * m.torque_step_nm
    config = config.with_values({"map.speed_max_rpm": float(speed_max_rpm), "map.torque_min_nm": -float(torque_max_nm),
                                 "map.torque_max_nm": float(torque_max_nm)})
    speeds_rpm, torques = map_grid(config)
    noise = config.estimator.speed_noise_rad_s
    smoothing = 3.0 * noise if isinstance(noise, float) and noise > 0 else 0.0
    positive = np.unique(np.concatenate([speeds_rpm / RPM_PER_RAD_S, NEAR_ZERO_RAD_S, [smoothing / 2, smoothing]]))
    positive = positive[positive > 0]
    speeds = np.concatenate([-positive[::-1], [0.0], positive])
    near = np.concatenate([NEAR_ZERO_NM, -NEAR_ZERO_NM])
    torques = np.unique(np.concatenate([torques, near[(near > torques.min()) & (near < torques.max())]]))
    problem = grid_cells_problem(len(speeds), len(torques))
    if problem:
        raise UsageError(problem)
    follows = bool(temperature_effects(config))
    s, t = np.meshgrid(speeds, torques, indexing="ij")
    if follows:
        planes = _temperature_planes(config, s, t, _axis(*(oil_grid_c or DEFAULT_OIL_GRID_C)),
                                     MAX_TABLE_NODES // s.size)
    else:
        planes = {40.0: _model(config, s, t, None)}
    temperatures = np.array(sorted(planes))
    loss = np.stack([planes[theta] for theta in temperatures], axis=-1)
    est = config.estimator
    table = LossTable(speeds, torques, temperatures, loss, est.min_torque_for_efficiency_nm,
                      est.min_speed_for_efficiency_rad_s, follows, calibrated=seen,
                      rated=(g.rated_speed_rpm / RPM_PER_RAD_S if g.rated_speed_rpm > 0 else math.inf,
                             g.rated_torque_nm if g.rated_torque_nm > 0 else math.inf))
    table.interpolation_error_nm, table.interpolation_error_relative = _interpolation_error(config, table)
    return table


def _temperature_planes(config: Config, speed: np.ndarray, torque: np.ndarray, start: np.ndarray,
                        max_planes: int) -> dict[float, np.ndarray]:
    """The model's loss over ``speed × torque`` at the temperatures ``start``, each interval halved
    while the loss at its middle differs from the mean of its ends by more than
    :data:`TEMPERATURE_TOLERANCE` (relative, where the efficiency is defined) -- the oil's viscosity
    changes fastest when it is cold -- down to :data:`MIN_TEMPERATURE_STEP_C`."""
    planes = {float(theta): _model(config, speed, torque, float(theta)) for theta in start}
    est = config.estimator
    weigh = (np.abs(torque) >= est.min_torque_for_efficiency_nm) & (np.abs(speed) >= est.min_speed_for_efficiency_rad_s)
    todo = list(zip(start[:-1].tolist(), start[1:].tolist()))
    while todo:
        low, high = todo.pop()
        middle = round((low + high) / 2, 9)
        if high - low <= 2 * MIN_TEMPERATURE_STEP_C or len(planes) >= max_planes:
            continue
        exact = _model(config, speed, torque, middle)
        big = weigh & (exact >= 1e-3)
        linear = (planes[low] + planes[high]) / 2
        if big.any() and (np.abs(linear - exact)[big] / exact[big]).max() > TEMPERATURE_TOLERANCE:
            planes[middle] = exact
            todo += [(low, middle), (middle, high)]
    if len(planes) >= max_planes:
        raise UsageError(f"the table would hold more than {MAX_TABLE_NODES:,} nodes: a coarser map.* grid or a "
                         "narrower oil temperature range")
    return planes


def _model(config: Config, speed: np.ndarray, torque: np.ndarray, temperature_c: float | None) -> np.ndarray:
    """The model's loss magnitude at the points (arrays of one shape)."""
    return plausible_points(config, torque.ravel(), speed.ravel(), temperature_c, "table").loss_magnitude_nm.reshape(
        speed.shape)


def interpolate(table: LossTable, speed_rad_s, torque_nm, temperature_c) -> np.ndarray:
    """Trilinear interpolation of the table at points inside it (numpy; the FMU's own is pure Python)."""
    from scipy.interpolate import RegularGridInterpolator

    if len(table.temperatures_c) == 1:
        f = RegularGridInterpolator((table.speeds_rad_s, table.torques_nm), table.loss_nm[:, :, 0])
        return f(np.column_stack([np.ravel(speed_rad_s), np.ravel(torque_nm)]))
    f = RegularGridInterpolator((table.speeds_rad_s, table.torques_nm, table.temperatures_c), table.loss_nm)
    return f(np.column_stack([np.ravel(speed_rad_s), np.ravel(torque_nm), np.ravel(temperature_c)]))


def _interpolation_error(config: Config, table: LossTable) -> tuple[float, float]:
    """The largest absolute and relative |interpolated − model| at the cells' centres and edge middles."""
    axes = [table.speeds_rad_s, table.torques_nm, table.temperatures_c]
    mids = [(a[:-1] + a[1:]) / 2 if len(a) > 1 else a for a in axes]
    worst_abs = worst_rel = 0.0
    # per temperature plane (its own model run): every mix of node and middle on each axis, but not all nodes
    for choice in itertools.product((0, 1), repeat=3):
        if not any(choice):
            continue
        s_axis, t_axis, k_axis = (mids[i] if c else axes[i] for i, c in enumerate(choice))
        for theta in k_axis:
            s, t = np.meshgrid(s_axis, t_axis, indexing="ij")
            exact = _model(config, s, t, float(theta) if table.follows_oil else None)
            approx = interpolate(table, s, t, np.full(s.shape, theta)).reshape(s.shape)
            err = np.abs(approx - exact)
            worst_abs = max(worst_abs, float(err.max()))
            big = (exact >= 1e-3) & (np.abs(t) >= table.min_torque_nm) & (np.abs(s) >= table.min_speed_rad_s)
            if big.any():
                worst_rel = max(worst_rel, float((err[big] / exact[big]).max()))
    return worst_abs, worst_rel
