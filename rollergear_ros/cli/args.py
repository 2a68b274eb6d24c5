"""What every ``rollergear`` subcommand module shares: the parameter file from the command line and
argument types, and the options more than one verb takes (the parameter file, the channel map, the topic
names, ``--assume``).  The command table (:mod:`.main`) imports the verb modules; they import this module,
never the table nor each other."""

from __future__ import annotations

import argparse
import math
from dataclasses import fields
from pathlib import Path

from ..base.errors import UsageError
from ..base.instants import Instant, parse_iso_ns
from ..core.effects import EFFECTS
from ..core.params import Config, load_config
from ..recordings.messages import TopicMap

DEFAULT_PARAMS = Path(__file__).resolve().parents[2] / "config" / "gearbox.yaml"


def default_params_path() -> Path | None:
    """The package's ``config/gearbox.yaml``: source tree, or the installed ``share/`` copy."""
    if DEFAULT_PARAMS.exists():
        return DEFAULT_PARAMS
    try:
        from ament_index_python.packages import get_package_share_directory

        p = Path(get_package_share_directory("rollergear_ros")) / "config" / "gearbox.yaml"
        return p if p.exists() else None
    except Exception:  # noqa: BLE001 - no ament index: fall back to the built-in defaults
        return None


def config_from_args(args: argparse.Namespace) -> Config:
    path = getattr(args, "params", None)
    if path is None:
        path = default_params_path()
    elif not Path(path).exists():
        raise UsageError(f"parameter file {path} does not exist")
    return load_config(path)


def finite_float(s: str) -> float:
    """An argument that must be a finite number."""
    v = float(s)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{s!r} is not a finite number")
    return v


def oil_temperature_c(s: str) -> float:
    """An oil temperature in °C within :data:`core.oil.OIL_TEMPERATURE_RANGE_C`."""
    from ..core.oil import OIL_TEMPERATURE_RANGE_C

    v = finite_float(s)
    low, high = OIL_TEMPERATURE_RANGE_C
    if not low <= v <= high:
        raise argparse.ArgumentTypeError(f"{s!r} degC is no oil temperature (between {low:g} and {high:g} degC)")
    return v


def positive_float(s: str) -> float:
    """An argument that must be a finite number above 0."""
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{s!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{s!r} must be a finite number above 0")
    return v


def block_seconds(s: str) -> float:
    """A block length in seconds: within 1 ms … 1 h (a block holds samples, a recording holds blocks)."""
    v = positive_float(s)
    if not 1e-3 <= v <= 3600.0:
        raise argparse.ArgumentTypeError(f"{s!r} s is not a block length between 0.001 and 3600 s")
    return v


def window_time(s: str) -> float | Instant:
    """``--start/--end``: seconds after the first sample analysed (finite, at least 0), or an instant on the
    recording's own clock -- ISO 8601 to the nanosecond, as a trace names its window (:class:`Instant`)."""
    at = parse_iso_ns(s)
    if at is not None:
        return Instant(at)
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{s!r} is neither a number of seconds after the first sample analysed "
                                         "nor an ISO 8601 time (e.g. 2026-12-07T10:00:01.234567891Z)") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"{s!r} must be a finite number of seconds, at least 0")
    return v


def add_params_option(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``--params YAML``, the parameter file (every subcommand that evaluates the model)."""
    p.add_argument("--params", metavar="YAML", help="parameter file (default: config/gearbox.yaml)")
    return p


def add_channels_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--channels", metavar="MAP.yaml",
                   help="channel map for CSV, Parquet, MDF4 or TDMS inputs (format in docs/interface.md)")


def add_topic_options(p: argparse.ArgumentParser) -> None:
    """``--topic-<name>`` for every topic of :class:`TopicMap` (and the JointState joint names)."""
    g = p.add_argument_group("topic names (defaults from interface.md)")
    for f in fields(TopicMap):
        opt = f.name.replace("_", "-")
        prefix = "" if f.name.endswith("_joint") else "topic-"
        g.add_argument(f"--{prefix}{opt}", dest=f"topic_{f.name}", default=f.default, metavar="NAME",
                       help=f"default {f.default}")


def topics_from_args(args: argparse.Namespace) -> TopicMap:
    return TopicMap(**{f.name: getattr(args, f"topic_{f.name}") for f in fields(TopicMap)})


def add_assume_option(p: argparse.ArgumentParser, prefix: str = "") -> None:
    """``--assume EFFECT`` (repeatable), for ``calibrate`` and ``fleet calibrate``."""
    p.add_argument("--assume", action="append", default=[], metavar="EFFECT", choices=list(EFFECTS),
                   help=f"{prefix}when the data cannot tell EFFECT from another effect, take it as EFFECT and write "
                   "it (what you know of the rig, e.g. drag_constant when the torque sensors were zeroed at "
                   "standstill); repeatable")
