"""One typed parameter set for the whole package, validated in one place.

Every parameter is declared once in :mod:`.paramspecs` (the effects' from the registry of
:mod:`.effects`) with its type, default, unit, allowed range and description.  The same table feeds

* the YAML loader (``config/gearbox.yaml``, ROS 2 parameter-file format
  ``loss_estimator: ros__parameters: {...}``), which rejects unknown keys;
* :func:`validate`, the single place where values are checked (the node calls it for run-time
  parameter changes, so a change is refused with exactly the same message as a bad YAML);
* the node's ``ParameterDescriptor`` s (description, ranges, read-only flags).

Names are dotted (``gearbox.dw_m``) like ROS parameters loaded from nested YAML.  All lengths are
metres, angles degrees (``_deg``), viscosities Pa·s.  No rclpy import here.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from collections.abc import Callable, Mapping

import yaml

from ..base import safeyaml
from ..base.errors import ParameterError
from ..base.interface import NODE_NAME, OUTPUT_QUEUE_DEPTH
from .effects import EFFECTS, viscosity_law
from .equations import contact_geometry
from .paramspecs import parameter_specs, spec_by_name


@dataclass(frozen=True)
class GearboxParams:
    """Geometry, material and lubricant of the ball track (paper Table 1, SI units)."""

    dw_m: float = 0.006
    dm1_m: float = 0.0475
    dm2_m: float = 0.065
    Z: int = 86
    z: int = 5
    alpha_deg: float = 20.0
    beta_deg: float = 0.0
    f1: float = 0.53
    f2: float = 0.53
    eta0_pa_s: float = 0.1
    Y: float = 0.34
    mu_m: float = 0.1
    mu_b: float = 0.1
    Fg_n: float = 0.0
    E_eq_pa: float = 2.3077e11
    alpha_p_per_pa: float = 2.0e-8
    internal_ratio: float = 0.0
    ellipse_a: float = 1.1552
    ellipse_b: float = 1.1502
    ratio: float = 0.0
    rated_speed_rpm: float = 3000.0
    rated_torque_nm: float = 100.0
    oil_nu40_mm2_s: float = 0.0
    oil_nu100_mm2_s: float = 0.0
    oil_density15_kg_m3: float = 880.0

    @property
    def datasheet_oil(self) -> tuple[float, float, float] | None:
        """The oil's data sheet (ν40, ν100 [mm²/s], ρ15 [kg/m³]) when the file gives one."""
        if self.oil_nu40_mm2_s > 0:
            return self.oil_nu40_mm2_s, self.oil_nu100_mm2_s, self.oil_density15_kg_m3
        return None

    @property
    def internal_ratio_effective(self) -> float:
        """Ball turns per drive-disc turn; ``dm1/dw`` (pure rolling) when configured as 0."""
        return self.internal_ratio if self.internal_ratio > 0 else self.dm1_m / self.dw_m

    @property
    def ratio_effective(self) -> float:
        """Input/output speed ratio; ``dm2/dm1`` when configured as 0."""
        return self.ratio if self.ratio > 0 else self.dm2_m / self.dm1_m


@dataclass(frozen=True)
class EffectParams:
    """The extra effects of the registry (:mod:`.effects`): which are enabled (accepted by
    ``calibrate``) and every effect's parameters, by their keys in the parameter file."""

    switches: Mapping[str, bool] = field(default_factory=dict)  #: effect -> enabled
    values: Mapping[str, Mapping[str, float]] = field(default_factory=dict)  #: effect -> key -> value
    #: enabled effects the file states no values of, derived from what it does state (the oil's data sheet's law)
    derived: tuple[str, ...] = ()
    #: derived effects ``calibrate`` set aside to fit them whole (the file as given has them: :meth:`as_given`)
    set_aside: tuple[str, ...] = ()

    def enabled(self) -> tuple[str, ...]:
        """Names of the enabled effects, in registry order."""
        return tuple(n for n in EFFECTS if self.switches.get(n, False))

    def params(self, name: str) -> dict[str, float]:
        """An effect's parameters by their short names (those of its term and of ``calibrate --json``)."""
        values = self.values.get(name, {})
        return {q.short: values.get(q.key, q.default) for q in EFFECTS[name].parameters}

    def active(self) -> dict[str, dict[str, float]]:
        """Enabled effect -> its parameters by short name (what the terms are evaluated with)."""
        return {n: self.params(n) for n in self.enabled()}


@dataclass(frozen=True)
class EstimatorParams:
    """How samples are paired, screened and adapted (see :mod:`.estimator`)."""

    min_torque_for_efficiency_nm: float = 0.2
    min_speed_for_efficiency_rad_s: float = 0.5
    speed_noise_rad_s: float | str = "auto"  #: a number, or ``auto`` (:mod:`.speednoise`)
    sync_tolerance_s: float = 0.0
    motor_speed_lag_s: float = 0.0
    output_torque_lag_s: float = 0.0
    output_speed_lag_s: float = 0.0
    resample_max_age_s: float = 0.05
    staleness_s: float = 0.1
    max_abs_torque_nm: float = 5000.0
    max_abs_speed_rad_s: float = 2000.0
    paper_model: bool = True
    adapt: bool = True
    rls_forgetting: float = 0.9995
    rls_max_covariance: float = 1e6
    change_block_samples: int = 200
    change_threshold_nm: float = 0.02

    def plausible(self, torque_nm, speed_rad_s):
        """Where a drive torque and speed (floats or arrays) lie in the range the estimator takes
        (``max_abs_torque_nm``, ``max_abs_speed_rad_s``; NaN does not); beyond it a sample is skipped as
        implausible."""
        return (abs(torque_nm) <= self.max_abs_torque_nm) & (abs(speed_rad_s) <= self.max_abs_speed_rad_s)


@dataclass(frozen=True)
class NodeParams:
    """Settings only the live node uses."""

    input_mode: str = "float64"
    input_joint: str = "motor"
    output_joint: str = "output"
    executor: str = "events"
    input_qos: str = "sensor_data"
    publish_every_n: int = 1
    output_depth: int = OUTPUT_QUEUE_DEPTH
    publish_stamped: bool = True
    publish_map: bool = True
    map_file: str = ""
    map_oil_step_c: float = 5.0
    publish_float64: bool = True
    expected_rate_hz: float = 1000.0
    sample_clock: str = "arrival"
    learn_input_rate: bool = True
    efficiency_window_s: float = 10.0
    min_efficiency_warn: float = 0.9
    hardware_id: str = "rollergear_gearbox"
    record_mcap: str = ""
    rerun_rrd: str = ""
    record_max_mb: float = 0.0
    record_max_s: float = 0.0
    rerun_connect: str = ""
    trace: bool = True
    trace_window_s: float = 60.0
    trace_min_after_s: float = 20.0
    trace_period_s: float = 300.0
    accept_traced: str = "propose"
    traced_params_file: str = ""

    def traced_params_path(self) -> str:
        """Where ``propose`` writes the candidate parameter file (``node.traced_params_file``)."""
        if self.traced_params_file:
            return self.traced_params_file
        if self.record_mcap:  # beside the recording, without its name's fields ({start}, {index})
            plain = re.sub(r"[_-]?\{(start|index)\}", "", self.record_mcap)
            return str(Path(plain).with_suffix("")) + ".traced.yaml"
        return "loss_estimator.traced.yaml"


@dataclass(frozen=True)
class SensorParams:
    """The sensors' stated accuracy limits (0: not stated; :mod:`.uncertainty`)."""

    input_torque_full_scale_nm: float = 0.0
    input_torque_fs_pct: float = 0.0
    input_torque_reading_pct: float = 0.0
    output_torque_full_scale_nm: float = 0.0
    output_torque_fs_pct: float = 0.0
    output_torque_reading_pct: float = 0.0
    input_speed_resolution_rad_s: float = 0.0
    output_speed_resolution_rad_s: float = 0.0

    @property
    def stated(self) -> bool:
        """Whether any accuracy is stated."""
        return any(getattr(self, f) > 0 for f in ("input_torque_fs_pct", "input_torque_reading_pct",
                                                  "output_torque_fs_pct", "output_torque_reading_pct",
                                                  "input_speed_resolution_rad_s", "output_speed_resolution_rad_s"))


@dataclass(frozen=True)
class MapParams:
    """Grid of ``rollergear map`` (the command's options override it)."""

    speed_min_rpm: float = 0.0
    speed_max_rpm: float = 0.0  #: 0: the gearbox's rated speed
    speed_step_rpm: float = 100.0
    torque_min_nm: float | str = "auto"  #: a number, or ``auto``: −gearbox.rated_torque_nm
    torque_max_nm: float | str = "auto"  #: a number, or ``auto``: gearbox.rated_torque_nm
    torque_step_nm: float = 5.0
    both_directions: bool = False

    def last_speed_rpm(self, gearbox: GearboxParams) -> float:
        """The map's last speed: ``speed_max_rpm``, or the rated speed when that is 0."""
        return self.speed_max_rpm if self.speed_max_rpm > 0 else gearbox.rated_speed_rpm

    def torque_range_nm(self, gearbox: GearboxParams) -> tuple[float, float]:
        """The map's first and last torque: as given, ``auto`` ± the gearbox's rated torque."""
        return (-gearbox.rated_torque_nm if self.torque_min_nm == "auto" else float(self.torque_min_nm),
                gearbox.rated_torque_nm if self.torque_max_nm == "auto" else float(self.torque_max_nm))

    def torques_nm(self, gearbox: GearboxParams) -> tuple[float, float, float]:
        """``(first, last, step)`` of the torque grid."""
        return (*self.torque_range_nm(gearbox), self.torque_step_nm)


@dataclass(frozen=True)
class CalibrationParams:
    """What ``calibrate`` records about its fit beside the parameters it wrote."""

    covariance: str = ""  #: :class:`core.covariance.ParameterCovariance` as JSON text ('' = none)
    model_form: str = ""  #: :class:`core.modelform.ModelForm` as JSON text ('' = none)


#: a loss map's largest grid: points per axis and cells (checked before anything is allocated;
#: VECTO's own maps have tens of points per axis)
MAX_MAP_AXIS_POINTS = 10_001
MAX_MAP_CELLS = 1_000_000


def grid_points(start: float, stop: float, step: float) -> float:
    """How many points ``start..stop`` in ``step`` increments has (a float: computed, not allocated)."""
    return math.floor((stop - start) / step + 1e-9) + 1.0


def grid_axis_problem(first: float, last: float, step: float, name: str = "") -> str | None:
    """Why a loss-map axis ``first..last`` in ``step`` increments has too many points, or None."""
    n = grid_points(first, last, step)
    if n <= MAX_MAP_AXIS_POINTS:
        return None
    return (f"the {name + ' ' if name else ''}grid {first:g}…{last:g} in steps of {step:g} has {n:.3g} points; "
            f"at most {MAX_MAP_AXIS_POINTS:,} (a larger step)")


def grid_cells_problem(n_speeds: float, n_torques: float) -> str | None:
    """Why a loss map of this many speeds and torques has too many cells, or None."""
    if n_speeds * n_torques <= MAX_MAP_CELLS:
        return None
    return (f"the map has {n_speeds:.0f} x {n_torques:.0f} = {n_speeds * n_torques:,.0f} cells; at most "
            f"{MAX_MAP_CELLS:,} (larger steps)")


@dataclass(frozen=True)
class Config:
    """The complete, validated parameter set."""

    gearbox: GearboxParams = field(default_factory=GearboxParams)
    effects: EffectParams = field(default_factory=EffectParams)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    node: NodeParams = field(default_factory=NodeParams)
    map: MapParams = field(default_factory=MapParams)
    calibration: CalibrationParams = field(default_factory=CalibrationParams)

    def to_flat(self) -> dict[str, Any]:
        """Dotted-name dictionary of every parameter (the inverse of :func:`validate`)."""
        return {spec.name: self.value(spec.name) for spec in parameter_specs()}

    def value(self, name: str) -> Any:
        """One parameter by its dotted name."""
        section, rest = name.split(".", 1)
        if section == "effects":
            effect, key = rest.split(".", 1)
            spec = spec_by_name()[name]
            if key == "enabled":
                return self.effects.switches.get(effect, spec.default)
            return self.effects.values.get(effect, {}).get(key, spec.default)
        return getattr(getattr(self, section), rest)

    def as_given(self) -> Config:
        """The parameter file as given: with the derived effects ``calibrate`` set aside derived again."""
        if not self.effects.set_aside:
            return self
        return validate({k: v for k, v in self.to_flat().items()
                         if k not in {f"effects.{n}.enabled" for n in self.effects.set_aside}})

    def with_values(self, values: Mapping[str, Any]) -> Config:
        """A new validated config with some dotted parameters changed."""
        flat = self.to_flat()
        flat.update(values)
        return validate(flat)


_SECTION_TYPES = {"gearbox": GearboxParams, "estimator": EstimatorParams, "sensors": SensorParams,
                  "node": NodeParams, "map": MapParams, "calibration": CalibrationParams}


#: URL schemes rerun's gRPC sink accepts (``node.rerun_connect``)
RERUN_URL_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")


def rerun_url_problem(url: str) -> str | None:
    """What is wrong with a rerun gRPC URL ('' = off is fine), parsed, not prefix-matched: one of
    :data:`RERUN_URL_SCHEMES`, a host, a valid port, and no user-info (``…:9876@evil/`` would send
    the data to host ``evil``)."""
    from urllib.parse import urlsplit

    if not url:
        return None
    if any(c.isspace() or ord(c) < 32 for c in url):
        return "a URL has no spaces or control characters"
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        return f"not a valid URL ({exc})"
    if parts.scheme + "://" not in RERUN_URL_SCHEMES:
        return f"a rerun gRPC URL starts with {', '.join(RERUN_URL_SCHEMES)}"
    if "@" in parts.netloc:
        return "a rerun URL has no user-info (user@host): the part after '@' would be the host"
    if not parts.hostname:
        return "the URL names no host"
    if port is not None and not 0 < port < 65536:
        return f"port {port} is out of range"
    return None


#: the thinnest data-sheet viscosity taken (mm²/s): Walther's law (ASTM D341) needs ν + 0.7 > 1
MIN_OIL_NU_MM2_S = 0.5


def validate(values: Mapping[str, Any]) -> Config:
    """Check every parameter (range, type, cross-parameter consistency) and build a :class:`Config`.

    ``values`` maps dotted names to values; missing names take their defaults, unknown names are
    an error.  Raises :class:`ParameterError` naming the first bad parameter, its value and the
    allowed range.  This is the only place parameters are validated.
    """
    specs = spec_by_name()
    unknown = sorted(set(values) - set(specs))
    if unknown:
        import difflib

        name = unknown[0]
        section, _, key = name.rpartition(".")
        same = sorted(s for s in specs if s.rpartition(".")[0] == section)
        # the key against the keys of its own section; a misplaced key against every full name
        near = [f"{section}.{k}" for k in difflib.get_close_matches(key, [s.rpartition(".")[2] for s in same],
                                                                     n=3, cutoff=0.6)]
        near = near or [s for s in specs if s.rpartition(".")[2] == key]
        if near:
            hint = "did you mean " + " or ".join(f"'{n}'" for n in near) + "?"
        else:
            hint = (f"the keys of '{section}' are {', '.join(same)}" if same else
                    f"the sections are {', '.join(sorted({s.split('.')[0] for s in specs}))}")
        more = f" (and {len(unknown) - 1} more unknown: {', '.join(unknown[1:4])})" if len(unknown) > 1 else ""
        raise ParameterError(name, values[name], f"unknown parameter; {hint}{more}")
    checked: dict[str, dict[str, Any]] = {k: {} for k in _SECTION_TYPES}
    switches: dict[str, bool] = {}
    effect_values: dict[str, dict[str, float]] = {}
    for spec in parameter_specs():
        value = spec.check(values[spec.name]) if spec.name in values else spec.default
        section, rest = spec.name.split(".", 1)
        if section == "effects":
            effect, key = rest.split(".", 1)
            if key == "enabled":
                switches[effect] = value
            else:
                effect_values.setdefault(effect, {})[key] = value
        else:
            checked[section][rest] = value
    # a file that states the oil's data sheet and says nothing of a law: the data sheet's law
    stated = f"effects.{viscosity_law().name}."
    derived = () if any(k.startswith(stated) for k in values) else \
        _datasheet_law(checked["gearbox"], switches, effect_values)
    config = Config(effects=EffectParams(switches, effect_values, derived),
                    **{k: _SECTION_TYPES[k](**v) for k, v in checked.items()})
    _check_consistency(config)
    return config


def _datasheet_law(gearbox: dict[str, Any], switches: dict[str, bool],
                   effect_values: dict[str, dict[str, float]]) -> tuple[str, ...]:
    """An oil's data sheet (``gearbox.oil_nu40_mm2_s``, ``oil_nu100_mm2_s``) is a viscosity law: where the file
    states one and says nothing of a law (no ``effects.viscosity_temperature.*`` key), the law is the data sheet's
    (ASTM D341 as the closest Vogel law, :func:`.oil.vogel_from_datasheet`; ``gearbox.eta0_pa_s`` the viscosity
    at its reference, 40 °C), so that every command and the node follow the oil the file names.  Returns the
    effects so derived (``calibrate`` fits the law whole, from the data sheet, where the data can test it)."""
    nu40, nu100 = gearbox.get("oil_nu40_mm2_s", 0.0), gearbox.get("oil_nu100_mm2_s", 0.0)
    law = viscosity_law()
    if not (nu40 > nu100 >= MIN_OIL_NU_MM2_S) or switches.get(law.name, False):
        return ()  # no data sheet, or one _check_consistency refuses; or the file's own law
    b_k, c_k = _datasheet_vogel(float(nu40), float(nu100), float(gearbox.get("oil_density15_kg_m3", 880.0)))
    keys = {q.short: q.key for q in law.parameters}
    switches[law.name] = True
    effect_values[law.name] = {keys["B"]: b_k, keys["C"]: c_k, keys["theta_ref"]: 40.0, keys["scale"]: 1.0}
    return (law.name,)


@functools.lru_cache(maxsize=64)
def _datasheet_vogel(nu40: float, nu100: float, density15: float) -> tuple[float, float]:
    from .oil import vogel_from_datasheet

    b_k, c_k, _eta = vogel_from_datasheet(nu40, nu100, density15, theta_ref_c=40.0)
    return round(b_k, 6), round(c_k, 6)


#: the smallest size a split recording's files may be given (a file holds its header, provenance and summary)
MIN_RECORD_MB = 0.01


#: what a consistency rule finds wrong: the key to name, its value, and what it must be
Problem = tuple[str, Any, str]


def _shortened(text: str) -> str:
    return text if len(text) <= 60 else text[:57] + "..."


def _covariance_rule(config: Config) -> Problem | None:
    """``calibration.covariance`` names numeric parameters and is a covariance."""
    if not config.calibration.covariance:
        return None
    from .covariance import covariance_problem

    numeric = [s.name for s in parameter_specs() if s.kind is float]
    problem = covariance_problem(config.calibration.covariance, numeric)
    return ("calibration.covariance", _shortened(config.calibration.covariance), problem) if problem else None


def _model_form_rule(config: Config) -> Problem | None:
    """``calibration.model_form`` is one a calibration writes."""
    if not config.calibration.model_form:
        return None
    from .modelform import model_form_problem

    problem = model_form_problem(config.calibration.model_form, EFFECTS)
    return ("calibration.model_form", _shortened(config.calibration.model_form), problem) if problem else None


def _record_size_rule(config: Config) -> Problem | None:
    """A split size some file reaches with its header and summary."""
    mb = config.node.record_max_mb
    return ("node.record_max_mb", mb, f"must be 0 (one file) or at least {MIN_RECORD_MB:g} MB") \
        if 0 < mb < MIN_RECORD_MB else None


def _balls_rule(config: Config) -> Problem | None:
    g = config.gearbox
    return ("gearbox.z", g.z, f"connected balls z must be <= Z = {g.Z}") if g.z > g.Z else None


def _pitch_diameters_rule(config: Config) -> Problem | None:
    """Each track's pitch diameter exceeds the ball diameter."""
    g = config.gearbox
    for key, value in (("gearbox.dm1_m", g.dm1_m), ("gearbox.dm2_m", g.dm2_m)):
        if value <= g.dw_m:
            return key, value, f"track pitch diameter must exceed the ball diameter {g.dw_m:g} m"
    return None


def _oil_datasheet_rule(config: Config) -> Problem | None:
    """A data sheet's oil is thinner when warm, and a lubricating oil's viscosity (ISO VG 2 is the thinnest
    grade; Walther's law ends below)."""
    g = config.gearbox
    if (g.oil_nu40_mm2_s > 0 or g.oil_nu100_mm2_s > 0) and not (g.oil_nu40_mm2_s > g.oil_nu100_mm2_s > 0):
        return ("gearbox.oil_nu100_mm2_s", g.oil_nu100_mm2_s, f"an oil is thinner when warm: need "
                f"oil_nu40_mm2_s ({g.oil_nu40_mm2_s:g}) > oil_nu100_mm2_s > 0, or both 0")
    if 0 < g.oil_nu100_mm2_s < MIN_OIL_NU_MM2_S:
        return ("gearbox.oil_nu100_mm2_s", g.oil_nu100_mm2_s,
                f"a lubricating oil's viscosity is at least {MIN_OIL_NU_MM2_S:g} mm^2/s at 100 degC")
    return None


def _ellipticity_rule(config: Config) -> Problem | None:
    """The Snare term (eq. 21) needs k_j = Ry/Rx >= 1: checked on the derived geometry."""
    g = config.gearbox
    geo = contact_geometry(g)
    for j, k in ((1, geo.k1), (2, geo.k2)):
        if not (math.isfinite(k) and k >= 1.0):
            return (f"gearbox.f{j}", getattr(g, f"f{j}"),
                    f"gives an ellipticity k{j} = Ry/Rx = {k:.4g} < 1 (eq. 6); use a tighter groove")
    return None


def _sensor_full_scale_rule(config: Config) -> Problem | None:
    """An accuracy stated in % of a full scale needs the full scale."""
    sensors = config.sensors
    for side in ("input", "output"):
        if getattr(sensors, f"{side}_torque_fs_pct") > 0 and not getattr(sensors, f"{side}_torque_full_scale_nm") > 0:
            return (f"sensors.{side}_torque_full_scale_nm", 0.0,
                    f"must be > 0 when sensors.{side}_torque_fs_pct states an accuracy of its full scale")
    return None


def _some_estimate_rule(config: Config) -> Problem | None:
    """The node publishes its estimates one way at least."""
    if config.node.publish_stamped or config.node.publish_float64:
        return None
    return ("node.publish_float64", False, "and node.publish_stamped are both off: the node would publish no "
            "estimate (switch one on)")


def _sample_clock_rule(config: Config) -> Problem | None:
    """The sequence clock times Float64 inputs: joint states carry their samples' stamps."""
    if config.node.sample_clock == "sequence" and config.node.input_mode != "float64":
        return ("node.sample_clock", "sequence", "times std_msgs/Float64 inputs (node.input_mode: float64); joint "
                "states carry their samples' own stamps")
    return None


def _rerun_url_rule(config: Config) -> Problem | None:
    problem = rerun_url_problem(config.node.rerun_connect)
    return ("node.rerun_connect", config.node.rerun_connect, f"{problem} (e.g. rerun+http://127.0.0.1:9876/proxy)") \
        if problem else None


def _map_grid_rule(config: Config) -> Problem | None:
    """The loss map's ranges run upwards and its grid is one a map can hold."""
    g, m = config.gearbox, config.map
    if m.last_speed_rpm(g) < m.speed_min_rpm:
        return "map.speed_max_rpm", m.speed_max_rpm, "must be >= map.speed_min_rpm (0: gearbox.rated_speed_rpm)"
    first, last = m.torque_range_nm(g)
    if last < first:
        return ("map.torque_max_nm", m.torque_max_nm,
                f"must be >= map.torque_min_nm ({first:g} N*m; auto: ± gearbox.rated_torque_nm)")
    speeds, torques = (m.speed_min_rpm, m.last_speed_rpm(g), m.speed_step_rpm), m.torques_nm(g)
    for key, axis, name in (("map.speed_step_rpm", speeds, "speed"), ("map.torque_step_nm", torques, "torque")):
        problem = grid_axis_problem(*axis, name)
        if problem:
            return key, axis[2], problem
    problem = grid_cells_problem(grid_points(*speeds), grid_points(*torques))
    return ("map.torque_step_nm", m.torque_step_nm, problem) if problem else None


def _vogel_rule(config: Config) -> Problem | None:
    """The oil's Vogel law has a pole below its reference temperature."""
    law = viscosity_law()
    if law.name not in config.effects.enabled():
        return None
    vogel = config.effects.params(law.name)
    if vogel["theta_ref"] + vogel["C"] <= 0:
        return f"effects.{law.name}.{law.parameter('C').key}", vogel["C"], "theta_ref + C must be > 0"
    return None


#: the rules a parameter set obeys beyond each value's own range, in the order they are checked (the first
#: broken one is said)
CONSISTENCY_RULES: tuple[Callable[[Config], Problem | None], ...] = (
    _covariance_rule, _model_form_rule, _record_size_rule, _balls_rule, _pitch_diameters_rule, _oil_datasheet_rule,
    _ellipticity_rule, _sensor_full_scale_rule, _some_estimate_rule, _sample_clock_rule, _rerun_url_rule,
    _map_grid_rule, _vogel_rule,
)


def _check_consistency(config: Config) -> None:
    """:data:`CONSISTENCY_RULES`, one after the other: the first broken one as a :class:`ParameterError`."""
    for rule in CONSISTENCY_RULES:
        problem = rule(config)
        if problem:
            raise ParameterError(*problem)


def _flatten(prefix: str, data: Mapping[str, Any], out: dict[str, Any]) -> None:
    for key, value in data.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, Mapping):
            _flatten(name, value, out)
        else:
            out[name] = value


def flat_from_yaml_document(doc: Any, source: str = "<yaml>") -> dict[str, Any]:
    """Extract the dotted parameters of the ``loss_estimator`` node from a parameter-file document.

    Accepts the node key as ``loss_estimator``, ``/loss_estimator``, ``/**/loss_estimator``,
    ``<namespace>/loss_estimator`` or ``/**``.
    """
    if not isinstance(doc, Mapping):
        raise ParameterError(
            "<file>", source, "a ROS 2 parameter file must be a mapping 'loss_estimator: {ros__parameters: {...}}'"
        )
    for key, body in doc.items():
        key_s = str(key)
        if key_s == "/**" or key_s.rstrip("/").split("/")[-1] == NODE_NAME:
            if not isinstance(body, Mapping) or "ros__parameters" not in body:
                raise ParameterError(key_s, body, "the node entry must contain 'ros__parameters'")
            params = body["ros__parameters"] or {}
            if not isinstance(params, Mapping):
                raise ParameterError(key_s + ".ros__parameters", params, "must be a mapping")
            out: dict[str, Any] = {}
            _flatten("", params, out)
            out.pop("use_sim_time", None)  # a standard ROS parameter, handled by rclpy
            return out
    raise ParameterError(
        "<file>", source, f"no '{NODE_NAME}: ros__parameters:' entry (found keys: {', '.join(map(str, doc)) or 'none'})"
    )


def load_config(path: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> Config:
    """Load and validate a parameter YAML (``None``: the defaults), with optional dotted overrides."""
    flat: dict[str, Any] = {}
    if path is not None:
        try:
            doc = safeyaml.load(path)
        except safeyaml.YamlProblem as problem:
            raise ParameterError.broken_file(str(path), problem) from None
        flat = flat_from_yaml_document(doc, str(path))
    if overrides:
        flat.update(overrides)
    return validate(flat)


def config_to_yaml(config: Config, header: str = "") -> str:
    """Render a config as a ROS 2 parameter file the node and ``replay`` accept."""
    nested: dict[str, Any] = {}
    for name, value in config.to_flat().items():
        cursor = nested
        parts = name.split(".")
        for p in parts[:-1]:
            cursor = cursor.setdefault(p, {})
        cursor[parts[-1]] = value
    body = yaml.safe_dump({"/**/" + NODE_NAME: {"ros__parameters": nested}}, sort_keys=False)
    return (header + body) if header else body


__all__ = [
    "Config",
    "EffectParams",
    "EstimatorParams",
    "GearboxParams",
    "NodeParams",
    "SensorParams",
    "load_config",
    "validate",
    "config_to_yaml",
    "flat_from_yaml_document",
]
