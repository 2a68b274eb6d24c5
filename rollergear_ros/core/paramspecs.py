"""The parameter table: every parameter of the package declared once, with its type, default, unit,
allowed range and description.

:func:`parameter_specs` is the whole table (the gearbox's, Table 1 of the paper; the effects', from
the registry of :mod:`.effects`; the estimator's, the sensors', the node's, the loss map's and
calibration's); :mod:`.params` validates values against it and loads them from YAML, the node
describes its ROS parameters by it.  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from ..base.errors import ParameterError
from ..base.interface import MAX_QUEUE_DEPTH, OUTPUT_QUEUE_DEPTH
from .effects import EFFECTS, REGISTRY_VERSION

__all__ = ["ParamSpec", "parameter_specs", "spec_by_name"]


@dataclass(frozen=True)
class ParamSpec:
    """Declaration of one parameter: type, default, unit, range and documentation."""

    name: str
    kind: type  # float, int, bool or str
    default: Any
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False  # True: value must be > low (else >= low)
    high_open: bool = False  # True: value must be < high (else <= high)
    choices: tuple[str, ...] = ()
    read_only: bool = False
    auto: bool = False  #: also ``auto`` (a number learned from the data; :mod:`.speednoise`)

    def allowed_text(self) -> str:
        """Human-readable statement of the allowed values."""
        if self.auto:
            return replace(self, auto=False).allowed_text() + ", or auto"
        if self.choices:
            return "must be one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind is bool:
            return "must be true or false"
        if self.kind is str:
            return "must be a string"
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.low_open else '>='} {self.low:g}")
        if self.high is not None:
            parts.append(f"{'<' if self.high_open else '<='} {self.high:g}")
        rng = " and ".join(parts) if parts else "any finite value"
        return f"must be a finite {'integer' if self.kind is int else 'number'} {rng}".rstrip()

    def check(self, value: Any) -> Any:
        """Return ``value`` coerced to the parameter's type, or raise :class:`ParameterError`."""
        if self.auto and value == "auto":
            return "auto"
        if self.kind is bool:
            if not isinstance(value, bool):
                raise ParameterError(self.name, value, self.allowed_text())
            return value
        if self.kind is str:
            if isinstance(value, bool) and {"on", "off"} <= set(self.choices or ()):
                value = "on" if value else "off"  # YAML 1.1 (ROS parameter files, -p x:=on) reads on/off as booleans
            if not isinstance(value, str):
                raise ParameterError(self.name, value, self.allowed_text())
            if self.choices and value not in self.choices:
                raise ParameterError(self.name, value, self.allowed_text())
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(self.name, value, self.allowed_text())
        if isinstance(value, int) and abs(value) > 2**53:  # beyond a float's integers (400 digits: no float at all)
            shown = str(value) if len(str(value)) <= 20 else f"{str(value)[:12]}… ({len(str(value))} digits)"
            raise ParameterError(self.name, shown, self.allowed_text())
        if self.kind is int:
            if isinstance(value, float):
                if not (math.isfinite(value) and value.is_integer()):
                    raise ParameterError(self.name, value, self.allowed_text())
                value = int(value)
        else:
            value = float(value)
        if not math.isfinite(value):
            raise ParameterError(self.name, value, self.allowed_text())
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            raise ParameterError(self.name, value, self.allowed_text())
        if self.high is not None and (value >= self.high if self.high_open else value > self.high):
            raise ParameterError(self.name, value, self.allowed_text())
        return value


def _g(name: str, default: float, unit: str, desc: str, **kw: Any) -> ParamSpec:
    kind = int if isinstance(default, int) and not isinstance(default, bool) else float
    return ParamSpec("gearbox." + name, kind, default, desc, unit, read_only=False, **kw)


#: Table 1 of the paper plus the assumptions of ``docs/model.md``.
GEARBOX_SPECS: tuple[ParamSpec, ...] = (
    _g("dw_m", 0.006, "m", "ball diameter d_w", low=0.0, low_open=True, high=0.1),
    _g("dm1_m", 0.0475, "m", "track pitch diameter of the drive disc d_m1 (eq. 4, 24)",
       low=0.0, low_open=True, high=2.0),
    _g("dm2_m", 0.065, "m", "track pitch diameter of the driven disc d_m2 (eq. 5, 28)",
       low=0.0, low_open=True, high=2.0),
    _g("Z", 86, "", "balls in the gearbox (only z of them carry load)", low=1, high=100000),
    _g("z", 5, "", "connected (loaded) balls sharing the drive torque (eq. 1)", low=1, high=100000),
    _g("alpha_deg", 20.0, "deg", "contact angle alpha (eq. 2, 4, 5)", low=0.0, high=90.0,
       high_open=True),
    _g("beta_deg", 0.0, "deg", "second angle beta of eq. 2", low=-90.0, high=90.0,
       low_open=True, high_open=True),
    _g("f1", 0.53, "", "groove curvature parameter, drive disc (eq. 7, 18)", low=0.5,
       low_open=True, high=5.0),
    _g("f2", 0.53, "", "groove curvature parameter, driven disc (eq. 7, 18)", low=0.5,
       low_open=True, high=5.0),
    _g("eta0_pa_s", 0.1, "Pa*s", "dynamic viscosity at the inlet at the reference temperature (eq. 9)",
       low=0.0, low_open=True, high=100.0),
    _g("Y", 0.34, "", "relative pure-rolling point (eq. 17)", low=0.0, high=1.0),
    _g("mu_m", 0.1, "", "local friction coefficient of eq. 17", low=0.0, high=2.0),
    _g("mu_b", 0.1, "", "friction coefficient between balls (Tb)", low=0.0, high=2.0),
    _g("Fg_n", 0.0, "N", "pressure force between balls (eq. 22, 26)", low=0.0, high=1e6),
    _g("E_eq_pa", 2.3077e11, "Pa", "equivalent modulus E/(1-nu^2) (eq. 3, 8, 9, 15)", low=0.0,
       low_open=True, high=1e13),
    _g("alpha_p_per_pa", 2.0e-8, "1/Pa", "pressure-viscosity coefficient (eq. 8)", low=0.0,
       low_open=True, high=1e-6),
    _g("internal_ratio", 0.0, "", "ball turns per drive-disc turn (eq. 10-13); 0 = dm1/dw (pure rolling)",
       low=0.0, high=1e4),
    _g("ellipse_a", 1.1552, "", "coefficient of eq. 19 (the paper prints 1.552, a typo)", low=0.0,
       low_open=True, high=10.0),
    _g("ellipse_b", 1.1502, "", "coefficient of eq. 20 (the paper prints 1.502, a typo)", low=0.0,
       low_open=True, high=10.0),
    _g("ratio", 0.0, "", "speed ratio input/output; 0 = dm2/dm1. Only used when output speed is not measured",
       low=0.0, high=1e4),
    _g("rated_speed_rpm", 3000.0, "rpm", "rated input speed (the loss map's last speed by default)",
       low=0.0, low_open=True, high=1e6),
    _g("rated_torque_nm", 100.0, "N*m", "rated input torque (the loss map's torque range by default: ± this)",
       low=0.0, low_open=True, high=1e7),
    _g("oil_nu40_mm2_s", 0.0, "mm^2/s", "the oil's data-sheet kinematic viscosity at 40 degC (0 = not known): "
       "with oil_nu100_mm2_s and no effects.viscosity_temperature stated, the loss follows its law (ASTM D341); "
       "calibrate's viscosity law starts from it", low=0.0, high=1e5),
    _g("oil_nu100_mm2_s", 0.0, "mm^2/s", "the oil's data-sheet kinematic viscosity at 100 degC (0 = not known)",
       low=0.0, high=1e5),
    _g("oil_density15_kg_m3", 880.0, "kg/m^3", "the oil's density at 15 degC (data sheet)", low=500.0, high=1500.0),
)

def effect_specs() -> tuple[ParamSpec, ...]:
    """``effects.<name>.enabled`` and ``effects.<name>.<key>`` of every effect in the registry
    (:mod:`.effects`), in registry order."""
    specs = []
    for e in EFFECTS.values():
        specs.append(ParamSpec(f"effects.{e.name}.enabled", bool, False, e.summary))
        for q in e.parameters:
            low = q.low
            if e.physical and not e.signed and not e.scales_fr and q.short == e.coefficient:
                low = max(low, 0.0)  # a friction's level: negative, the gearbox would be a power source (η > 1)
            specs.append(ParamSpec(f"effects.{e.name}.{q.key}", float, q.default, q.description, q.unit,
                                   low=low, high=q.high, low_open=q.low_open))
    return tuple(specs)


ESTIMATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("estimator.min_torque_for_efficiency_nm", float, 0.2,
              "efficiency is NaN below this |T|", "N*m", low=0.0, high=1e5),
    ParamSpec("estimator.min_speed_for_efficiency_rad_s", float, 0.5,
              "efficiency is NaN below this |w|", "rad/s", low=0.0, high=1e5),
    ParamSpec("estimator.speed_noise_rad_s", float, "auto",
              "standard deviation of the drive speed reading: the loss torque's sign runs smoothly through 0 as "
              "tanh(w/noise), about the average sign of such a reading; within 3 of it from 0 the direction is not "
              "known and no loss is measured (calibrate leaves those samples out); auto: learned from the second "
              "differences of the first 1000 samples' speeds (before the first 50, no loss is measured)", "rad/s",
              low=0.0, high=100.0, auto=True),
    ParamSpec("estimator.sync_tolerance_s", float, 0.0,
              "input messages whose times differ by at most this are one sample (keep below half the sample "
              "period); 0 = automatic: 0.4 x the median period of the motor torque messages (offline measured in "
              "the bag, live 1/node.expected_rate_hz)", "s", low=0.0, high=10.0),
    *(ParamSpec(f"estimator.{channel}_lag_s", float, 0.0,
                f"how much later the {channel.replace('_', ' ')} reading comes than the drive torque's (a DAQ on "
                "its own clock, a sensor's filter): each sample takes its value at t + lag, interpolated between "
                "the paired samples around (the estimate waits that long); calibrate writes the lag it found "
                "and aligned", "s", low=-1.0, high=1.0)
      for channel in ("motor_speed", "output_torque", "output_speed")),
    ParamSpec("estimator.resample_max_age_s", float, 0.05,
              "a channel logged at another rate than the drive torque (a speed at 100 Hz beside a torque at 1 kHz, "
              "told from its first messages) is interpolated onto the torque's stamps, linear between its messages "
              "within this of a stamp, else its last one within this is held, else the sample has none (a speed: "
              "skipped as stale; an output: no residual); 0 = every channel is paired message by message",
              "s", low=0.0, high=10.0),
    ParamSpec("estimator.staleness_s", float, 0.1,
              "an input silent for longer than this is stale: motor samples no longer wait for it, diagnostics warn",
              "s", low=0.0, low_open=True, high=3600.0),
    ParamSpec("estimator.max_abs_torque_nm", float, 5000.0,
              "|T| above this is implausible: the sample is skipped", "N*m", low=0.0, low_open=True, high=1e7),
    ParamSpec("estimator.max_abs_speed_rad_s", float, 2000.0,
              "|w| above this is implausible: the sample is skipped", "rad/s", low=0.0, low_open=True,
              high=1e6),
    ParamSpec("estimator.paper_model", bool, True,
              "include the paper's ball-track model; false: the loss is only the accepted effects (a gearbox the "
              "paper does not describe, e.g. an axle's loss map)"),
    ParamSpec("estimator.adapt", bool, True,
              "update the coefficients of the accepted effects online by RLS when output torque is measured"),
    ParamSpec("estimator.rls_forgetting", float, 0.9995, "RLS forgetting factor lambda", "",
              low=0.9, high=1.0),
    ParamSpec("estimator.rls_max_covariance", float, 1e6, "bound on the RLS covariance trace (anti-windup)",
              "", low=0.0, low_open=True, high=1e12),
    ParamSpec("estimator.change_block_samples", int, 200,
              "block length of the residual block averages fed to the change detector", "", low=1, high=10**7),
    ParamSpec("estimator.change_threshold_nm", float, 0.02,
              "CUSUM threshold on block-averaged residuals; 0 disables the detector", "N*m", low=0.0, high=1e4),
)

NODE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("node.input_mode", str, "float64", "input topics: Float64 per channel, or one JointState",
              choices=("float64", "joint_state"), read_only=True),
    ParamSpec("node.input_joint", str, "motor", "JointState joint carrying motor torque/speed", read_only=True),
    ParamSpec("node.output_joint", str, "output",
              "JointState joint carrying measured output torque/speed (absent: no residual)", read_only=True),
    ParamSpec("node.executor", str, "events",
              "rclpy executor: events (fast; pairs inputs in arrival order) or single_threaded (pairs inputs by "
              "publisher timestamps; ~3 k messages/s at most)", choices=("events", "single_threaded"), read_only=True),
    ParamSpec("node.input_qos", str, "sensor_data",
              "QoS of the input subscriptions: sensor_data (best effort, 1000 deep: a node that falls behind loses "
              "samples, the publisher never waits) or reliable (reliable, keep all: a publisher that outpaces the "
              "node is held back instead, e.g. a recording played into it; nothing is lost)",
              choices=("sensor_data", "reliable"), read_only=True),
    ParamSpec("node.publish_every_n", int, 1, "publish every n-th estimate (decimation for slow consumers)",
              low=1, high=100000),
    ParamSpec("node.output_depth", int, OUTPUT_QUEUE_DEPTH,
              "history depth the per-sample and per-second outputs are offered with (reliable, keep last): how "
              "many messages a reliable subscriber that stalls can still have resent (1000: 1 s at 1 kHz); at "
              f"most {MAX_QUEUE_DEPTH}, the deepest Fast DDS keeps", low=1, high=MAX_QUEUE_DEPTH, read_only=True),
    ParamSpec("node.publish_stamped", bool, True,
              "publish each estimate as one stamped sensor_msgs/JointState on loss/estimate (header.stamp: the "
              "sample's time; names and values in name/position)", read_only=True),
    ParamSpec("node.publish_map", bool, True,
              "publish the loss map (model + accepted effects at their adapted coefficients, the map.* grid) on "
              "loss/map (transient-local) at start and when an adapted coefficient leaves its 95 % interval",
              read_only=True),
    ParamSpec("node.map_file", str, "", "also rewrite this VECTO .vtlm file (atomically) with each map ('' = off)",
              read_only=True),
    ParamSpec("node.map_oil_step_c", float, 5.0,
              "a model that follows the oil (an accepted effect needs its temperature): a new loss map when the oil "
              "temperature has moved this far from the last map's (0 = only when a coefficient moves)", "degC",
              low=0.0, high=500.0),
    ParamSpec("node.publish_float64", bool, True,
              "publish the four std_msgs/Float64 outputs (loss/torque, loss/power, efficiency, residual/torque) for "
              "plotting tools; off: one publication per sample", read_only=True),
    ParamSpec("node.expected_rate_hz", float, 1000.0,
              "the inputs' sample rate: diagnostics, the pairing tolerance, and the rate of the sequence sample clock "
              "(node.sample_clock; read at start there)", "Hz", low=0.0, low_open=True, high=1e6),
    ParamSpec("node.sample_clock", str, "arrival",
              "Float64 inputs' sample times: arrival (the times the node pairs them by: arrival, or publisher "
              "timestamps under single_threaded) or sequence (each topic's publisher numbers its messages at "
              "node.expected_rate_hz, one per sample, as a rig's acquisition loop does: the times are that grid, "
              "whatever delivery does; channel lags are applied on it as replay applies them on a recording's log "
              "times)", choices=("arrival", "sequence"), read_only=True),
    ParamSpec("node.learn_input_rate", bool, True,
              "diagnostics: an input is slow below 80 % of the rate its stream started at (a bag played at another "
              "rate is no warning); false: below 80 % of node.expected_rate_hz"),
    ParamSpec("node.efficiency_window_s", float, 10.0,
              "the measured efficiency (with measured output torque) is energy-weighted over this much of the latest "
              "sample time, published once a second with its uncertainty (sensors.*)", "s",
              low=1.0, high=86400.0, read_only=True),
    ParamSpec("node.min_efficiency_warn", float, 0.9, "WARN when the latest efficiency is below this", "",
              low=0.0, high=1.0),
    ParamSpec("node.hardware_id", str, "rollergear_gearbox", "hardware_id in /diagnostics"),
    ParamSpec("node.record_mcap", str, "",
              "record inputs, outputs, /diagnostics, the loss maps and traces to this MCAP file ('' = off); {start} "
              "in the name is each file's UTC start time (rig_{start}.mcap), {index} its number; a name that exists is "
              "refused unless it has a field or the recording is split (then the next free name is taken)",
              read_only=True),
    ParamSpec("node.rerun_rrd", str, "", "log to this rerun .rrd file ('' = off; {start}, {index} and splitting as "
              "node.record_mcap)", read_only=True),
    ParamSpec("node.record_max_mb", float, 0.0,
              "split node.record_mcap and node.rerun_rrd into files of about this size (as ros2 bag record "
              "--max-bag-size; 0 = one file): each file whole, with the provenance and parameters", "MB",
              low=0.0, high=1e7, read_only=True),
    ParamSpec("node.record_max_s", float, 0.0,
              "split them every this many seconds (as --max-bag-duration; 0 = off)", "s",
              low=0.0, high=1e9, read_only=True),
    ParamSpec("node.rerun_connect", str, "", "stream to a rerun viewer at this gRPC URL ('' = off)",
              read_only=True),
    ParamSpec("node.trace", bool, True,
              "trace the residual online: calibrate's discovery on the node's recent samples with measured output, "
              "in a worker process, after each change alarm (and every node.trace_period_s); the result on "
              "loss/traced and /diagnostics", read_only=True),
    ParamSpec("node.trace_window_s", float, 60.0,
              "the longest window of samples traced on each side of a change point (after it: the latest; and by a "
              "periodic trace)", "s",
              low=10.0, high=3600.0, read_only=True),
    ParamSpec("node.trace_min_after_s", float, 20.0,
              "samples needed after a change point before it is traced (the delay from onset to result)", "s",
              low=5.0, high=3600.0),
    ParamSpec("node.trace_period_s", float, 300.0,
              "also trace the last node.trace_window_s every this many seconds, for drift the change detector "
              "misses (0 = after alarms only)", "s", low=0.0, high=1e6),
    ParamSpec("node.accept_traced", str, "propose",
              "what a traced effect does: off (reported only), propose (also writes the candidate parameter file, "
              "atomically, to node.traced_params_file) or on (also takes the candidate's parameters in, as a "
              "run-time parameter change at a sample boundary, recorded; the parameter file on disk never changes)",
              choices=("off", "propose", "on")),
    ParamSpec("node.traced_params_file", str, "",
              "where 'propose' writes the candidate parameter file ('' = beside node.record_mcap as "
              "NAME.traced.yaml, else loss_estimator.traced.yaml in the working directory)", read_only=True),
)

def _s(name: str, unit: str, desc: str, high: float) -> ParamSpec:
    return ParamSpec("sensors." + name, float, 0.0, desc, unit, low=0.0, high=high)


#: the rig's sensors' stated accuracy (0 = not stated): the measured loss's and efficiency's
#: uncertainty (:mod:`.uncertainty`), and calibrate's practical minimum effect size
SENSOR_SPECS: tuple[ParamSpec, ...] = (
    _s("input_torque_full_scale_nm", "N*m", "drive torque sensor: its full scale (nominal torque)", 1e7),
    _s("input_torque_fs_pct", "%", "drive torque sensor: accuracy limit as % of its full scale (e.g. 0.05 for "
       "a class 0.05 flange)", 100.0),
    _s("input_torque_reading_pct", "%", "drive torque sensor: accuracy limit as % of the reading", 100.0),
    _s("output_torque_full_scale_nm", "N*m", "output torque sensor: its full scale", 1e7),
    _s("output_torque_fs_pct", "%", "output torque sensor: accuracy limit as % of its full scale", 100.0),
    _s("output_torque_reading_pct", "%", "output torque sensor: accuracy limit as % of the reading", 100.0),
    _s("input_speed_resolution_rad_s", "rad/s", "drive speed reading: its resolution (one step)", 1e3),
    _s("output_speed_resolution_rad_s", "rad/s", "output speed reading: its resolution (one step)", 1e3),
)

MAP_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("map.speed_min_rpm", float, 0.0, "loss map: first input speed", "rpm", low=0.0, high=1e6),
    ParamSpec("map.speed_max_rpm", float, 0.0, "loss map: last input speed; 0 = gearbox.rated_speed_rpm", "rpm",
              low=0.0, high=1e6),
    ParamSpec("map.speed_step_rpm", float, 100.0, "loss map: speed step", "rpm", low=0.0, low_open=True, high=1e6),
    ParamSpec("map.torque_min_nm", float, "auto", "loss map: first input torque (negative: regeneration); auto = "
              "-gearbox.rated_torque_nm", "N*m", low=-1e7, high=1e7, auto=True),
    ParamSpec("map.torque_max_nm", float, "auto", "loss map: last input torque; auto = gearbox.rated_torque_nm", "N*m",
              low=-1e7, high=1e7, auto=True),
    ParamSpec("map.torque_step_nm", float, 5.0, "loss map: torque step", "N*m", low=0.0, low_open=True, high=1e6),
    ParamSpec("map.both_directions", bool, False,
              "loss map: also reverse rotation, written to a second file (<name>_reverse.vtlm)"),
)

CALIBRATION_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("calibration.covariance", str, "",
              "written by calibrate: the covariance of what it fitted, in this file's keys (JSON: keys, matrix; "
              "core/covariance.py); predict propagates it ('' = none); a traced candidate taken in brings its own"),
    ParamSpec("calibration.model_form", str, "",
              "written by calibrate: what it left unresolved and the range it saw (JSON: verdict, alternatives, "
              "unresolved, seen; core/modelform.py); predict's band spans the alternatives, counts the effects "
              "beyond what was seen as unknown, or is refused ('' = none)"),
)

_specs_cache: dict[int, tuple[tuple[ParamSpec, ...], dict[str, ParamSpec]]] = {}


def parameter_specs() -> tuple[ParamSpec, ...]:
    """Every parameter of the package, effects from the registry as it is now."""
    return _spec_tables()[0]


def spec_by_name() -> dict[str, ParamSpec]:
    return _spec_tables()[1]


def _spec_tables() -> tuple[tuple[ParamSpec, ...], dict[str, ParamSpec]]:
    version = REGISTRY_VERSION[0]
    if version not in _specs_cache:
        _specs_cache.clear()
        specs = (GEARBOX_SPECS + effect_specs() + ESTIMATOR_SPECS + SENSOR_SPECS + NODE_SPECS + MAP_SPECS
                 + CALIBRATION_SPECS)
        _specs_cache[version] = (specs, {spec.name: spec for spec in specs})
    return _specs_cache[version]
