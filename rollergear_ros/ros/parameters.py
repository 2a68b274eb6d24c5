"""The node's parameter bridge: the package's one parameter set (:mod:`core.params`) as ROS parameters.

Declares each parameter with a descriptor built from its spec (description, unit, range, allowed
values), validates what the node was given in the one place the CLI does too
(:func:`core.params.validate`), reads ``--params-file`` arguments as the CLI reads parameter files
before rcl parses them, and checks the files the node is asked to write.
"""

from __future__ import annotations

from pathlib import Path

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from ..base.errors import ParameterError
from ..core.effects import viscosity_law
from ..core.params import Config, validate
from ..core.paramspecs import parameter_specs

__all__ = ["check_new_output", "check_params_files", "declare_parameters", "live_provenance",
           "package_parameter_names", "params_files", "parameter_event"]


def check_new_output(name: str, path: str) -> None:
    """Refuse (:class:`ParameterError`) an output file that exists -- the node never overwrites a
    recording, as ``ros2 bag record`` does not -- or that cannot be created."""
    target = Path(path)
    if target.exists() or target.is_symlink():
        raise ParameterError(name, path, "exists; the node does not overwrite a recording: "
                                         "move it or choose another name")
    try:  # by doing: root may write where os.access says so and still fail (e.g. in /proc)
        target.parent.mkdir(parents=True, exist_ok=True)
        with target.open("xb"):
            pass
        target.unlink()
    except OSError as exc:
        raise ParameterError(name, path, f"cannot be created: {exc.strerror or exc}") from None


def _ros_standard_parameter(name: str) -> bool:
    """Parameters rclpy itself declares or reads (not the package's)."""
    return name in ("use_sim_time", "start_type_description_service") or name.startswith("qos_overrides.")


def params_files(args: list[str]) -> list[str]:
    """The ``--params-file`` arguments of a command line's ROS arguments."""
    files, in_ros = [], False
    for i, a in enumerate(args):
        if a == "--ros-args":
            in_ros = True
        elif a == "--":
            in_ros = False
        elif in_ros and a == "--params-file" and i + 1 < len(args):
            files.append(args[i + 1])
    return files


def check_params_files(args: list[str]) -> None:
    """Read each ``--params-file`` as the CLI does (:func:`~core.params.load_config`)
    before rcl parses it: what rcl refuses gets one line naming file, line and column, and what rcl
    drops silently (``dw_m: []``, a typo'd key, a file without this node's section) is refused
    instead of starting the node on the defaults."""
    from ..core.params import load_config

    for path in params_files(args):
        if not Path(path).exists():
            raise ParameterError("--params-file", path, "does not exist")
        load_config(path)


def _descriptor(spec) -> ParameterDescriptor:
    d = ParameterDescriptor(description=f"{spec.description} [{spec.unit}]" if spec.unit else spec.description,
                            read_only=spec.read_only, additional_constraints=spec.allowed_text())
    if spec.auto:  # a number or the string auto: validated by the spec (core.params)
        d.dynamic_typing = True
    elif spec.kind is float and spec.low is not None and spec.high is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    elif spec.kind is int and spec.low is not None and spec.high is not None:
        d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
    return d


def package_parameter_names() -> frozenset[str]:
    """The names of the package's parameters (the rest a node has are rclpy's own)."""
    return frozenset(spec.name for spec in parameter_specs())


def declare_parameters(node) -> Config:
    """Declare the package's parameters on ``node`` (with descriptors) and validate what it was
    given; :class:`ParameterError` names a refused one with the reason."""
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
    from rclpy.parameter import Parameter

    overrides = node._parameter_overrides  # what --ros-args gave, before rclpy applies it
    for spec in parameter_specs():
        override = overrides.get(spec.name)
        if spec.kind is float and override is not None and override.type_ == Parameter.Type.INTEGER:
            # ``expected_rate_hz: 500`` means 500.0, as the CLI reads it
            overrides[spec.name] = Parameter(spec.name, Parameter.Type.DOUBLE, float(override.value))
        elif spec.kind is str and override is not None and override.type_ == Parameter.Type.BOOL:
            # ``node.accept_traced:=on`` reaches rclpy as a boolean (YAML 1.1): the spec reads it back
            overrides[spec.name] = Parameter(spec.name, Parameter.Type.STRING, spec.check(override.value))
        try:
            node.declare_parameter(spec.name, spec.default, _descriptor(spec))
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            override = overrides.get(spec.name)
            value = override.value if override is not None else spec.default
            raise ParameterError(spec.name, value, f"{spec.allowed_text()} ({exc})") from None
    # the oil's law as the files state it: none stated (only its declared defaults), the data sheet's
    law = f"effects.{viscosity_law().name}."
    stated = any(name.startswith(law) for name in overrides)
    flat = {spec.name: node.get_parameter(spec.name).value for spec in parameter_specs()
            if stated or not spec.name.startswith(law)}
    # an override of no declared parameter (``-p gearbox.dw_mm:=0.1``) would be ignored by
    # rclpy, the node running on the default: validate() refuses it with "did you mean"
    flat.update({name: p.value for name, p in overrides.items()
                 if name not in flat and not _ros_standard_parameter(name)})
    return validate(flat)


def live_provenance(node_name: str, config: Config, argv: list[str]) -> dict[str, str]:
    """What a live recording says made it (metadata ``rollergear_provenance``): package version,
    host, start time, node, command line, the parameters as validated (YAML and its SHA-256) and
    each ``--params-file`` as it was loaded (path, text, SHA-256; numbered from 1 when several)."""
    import datetime
    import hashlib
    import socket

    from ..base.interface import package_version
    from ..core.params import config_to_yaml

    parameters = config_to_yaml(config)
    record = {"package": "rollergear_ros", "version": package_version(), "host": socket.gethostname(),
              "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "node": node_name, "command": " ".join(argv), "accepted_effects": ", ".join(config.effects.enabled())
              or "none", "parameters": parameters,
              "parameters_sha256": hashlib.sha256(parameters.encode()).hexdigest()}
    files = params_files(argv)
    for i, path in enumerate(files, 1):
        suffix = f"_{i}" if len(files) > 1 else ""
        try:
            data = Path(path).read_bytes()
        except OSError as exc:  # read at start-up; gone since: said, not guessed
            record[f"params_file{suffix}"] = f"{path} (not readable now: {exc.strerror or exc})"
            continue
        record[f"params_file{suffix}"] = str(Path(path).resolve())
        record[f"params_file{suffix}_text"] = data.decode("utf-8", errors="replace")
        record[f"params_file{suffix}_sha256"] = hashlib.sha256(data).hexdigest()
    return record


def parameter_event(node_name: str, stamp_ns: int, changes: dict) -> dict:
    """``rcl_interfaces/msg/ParameterEvent`` of a run-time change, as rclpy publishes it on
    ``/parameter_events`` (the node's recording keeps one per accepted change), as a message dict
    for :func:`~recordings.messages.encoder_for` -- whose CDR every reader takes (rclpy's own
    serialisation pads the empty sequences of ``ParameterValue``, which rosbags refuses)."""
    from rclpy.parameter import Parameter

    changed = []
    for name, value in changes.items():
        msg = Parameter(name, value=value).to_parameter_msg().value  # rclpy's type and field for the value
        fields = {}
        for field in msg.get_fields_and_field_types():
            v = getattr(msg, field)
            fields[field] = v if isinstance(v, str | int | float | bool) else list(v)
        changed.append({"name": name, "value": fields})
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "node": node_name, "changed_parameters": changed}
