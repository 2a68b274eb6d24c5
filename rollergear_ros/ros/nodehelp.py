"""``loss_estimator --help``: the node's usage, topics and parameters (from the one parameter table),
and where the interface contract is -- printed without starting ROS."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

from ..base.output_channels import OUTPUT_CHANNELS
from ..base.interface import NAMESPACE, Topic
from ..core.paramspecs import parameter_specs

#: the installed copy of the docs (``setup.py`` puts ``docs/*.md`` under ``share/rollergear_ros/docs``)
_SOURCE_DOCS = Path(__file__).resolve().parents[2] / "docs"


def doc_path(name: str) -> Path | None:
    """Where a document of ``docs/`` is on this machine: the source tree's, else the installed copy
    (the ament index, else ``<prefix>/share/rollergear_ros/docs``); None when neither exists."""
    candidates = [_SOURCE_DOCS / name, Path(sys.prefix) / "share" / "rollergear_ros" / "docs" / name]
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.insert(1, Path(get_package_share_directory("rollergear_ros")) / "docs" / name)
    except Exception:  # noqa: BLE001 - no ament index here: the other places
        pass
    return next((p for p in candidates if p.is_file()), None)


def contract_line() -> str:
    """The help's closing line: where the interface contract is on this machine."""
    path = doc_path("interface.md")
    where = str(path) if path is not None else "docs/interface.md in the rollergear_ros sources (not installed here)"
    return f"Topics, message types, the calibrate --json object and channel maps: {where}"


def wants_help(args: list[str]) -> bool:
    """``-h``/``--help`` among the node's own arguments (those before ``--ros-args``)."""
    own = args[: args.index("--ros-args")] if "--ros-args" in args else args
    return any(a in ("-h", "--help") for a in own)


def _parameter_lines(width: int) -> list[str]:
    lines, section = [], None
    for spec in parameter_specs():
        head = spec.name.split(".", 1)[0]
        if head != section:
            section = head
            lines.append(f"  {section}:")
        unit = f" [{spec.unit}]" if spec.unit else ""
        default = repr(spec.default) if spec.kind is str else str(spec.default).lower() if spec.kind is bool \
            else f"{spec.default:g}" if spec.kind is float and not isinstance(spec.default, str) else str(spec.default)
        ro = "; read-only: at start-up only" if spec.read_only else ""
        lines.append(f"    {spec.name} ({spec.kind.__name__}, default {default}{unit}{ro})")
        text = f"{spec.description}; {spec.allowed_text()}"
        lines += textwrap.wrap(text, width, initial_indent=" " * 8, subsequent_indent=" " * 8)
    return lines


def help_text(width: int = 100) -> str:
    """The whole ``--help`` text."""
    inputs = ", ".join(f"{NAMESPACE}/{t}" for t in (Topic.MOTOR_TORQUE, Topic.MOTOR_SPEED, Topic.OUTPUT_TORQUE,
                                                     Topic.OUTPUT_SPEED, Topic.OIL_TEMPERATURE))
    outputs = ", ".join(c.absolute_topic() for c in OUTPUT_CHANNELS.values())  # :mod:`base.output_channels`
    parts = [
        "usage: loss_estimator [-h] [--ros-args [--params-file YAML] [-p NAME:=VALUE ...] [-r __ns:=/NS]]",
        "",
        *textwrap.wrap("The live roller-gearing loss estimator: estimates the loss torque, loss power and efficiency "
                       "of every paired drive torque and speed sample with the model of the parameter file, the "
                       "residual against a measured output, reports /diagnostics at 1 Hz, and records to MCAP and "
                       "rerun on request.", width),
        "",
        "start:",
        "  loss_estimator --ros-args --params-file config/gearbox.yaml",
        "  ros2 run rollergear_ros loss_estimator --ros-args --params-file calibrated.yaml "
        "-p node.record_mcap:=live.mcap",
        "  ros2 launch rollergear_ros loss_estimator.launch.py params_file:=calibrated.yaml [namespace:=rollergear]",
        "",
        *textwrap.wrap(f"inputs: {inputs} (std_msgs/Float64; sensor_msgs/Temperature for the oil; "
                       f"{Topic.JOINT_STATES} with node.input_mode:=joint_state)", width, subsequent_indent="  "),
        *textwrap.wrap(f"outputs: {outputs}, {Topic.DIAGNOSTICS}", width, subsequent_indent="  "),
        "",
        *textwrap.wrap("parameters (in a --params-file under /**/loss_estimator: ros__parameters:, or -p NAME:=VALUE; "
                       "changed at run time with ros2 param set unless read-only):", width),
        *_parameter_lines(width),
        "",
        contract_line(),
    ]
    return "\n".join(parts) + "\n"
