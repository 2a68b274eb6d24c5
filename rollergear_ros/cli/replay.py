"""Subcommands working on bags: ``simulate``, ``replay`` (``calibrate`` and ``play`` register too)."""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import fields
from pathlib import Path

from ..recordings.messages import TopicMap
from .args import config_from_args
from ..core.effects import viscosity_law
from ..outputs.exports import EXPORT_KINDS
from ..sources.paths import Output, check_outputs
from ..base.errors import UsageError, damaged_exit
from ..base.progress import TimedProgress


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


def cmd_simulate(args: argparse.Namespace) -> int:
    from ..calibration.simulate import DeclaredEffect, SimulationOptions, write_simulation

    check_outputs([args.params], [Output("--out", args.out, "folder" if args.fleet else "mcap")])
    config = config_from_args(args)
    if args.fleet:
        return _simulate_fleet(args, config)
    effects = [DeclaredEffect.parse(e) for e in args.effect]
    opts = SimulationOptions(profile=args.profile, rate_hz=args.rate, seed=args.seed, effects=effects,
                             torque_noise_nm=args.torque_noise, noise_ar1=args.noise_ar1,
                             output_lag_s=args.output_lag, joint_states=args.joint_states,
                             step_change_at_s=args.step_change_at, oil_nu40_nu100_mm2_s=_oil(args.oil, config),
                             start_ns=_start_ns(args.start) if args.start else time.time_ns() // 10**9 * 10**9)
    with TimedProgress("simulate", unit="sample") as bar:
        bar.stage = "the model along the profile, writing"
        if args.duration is not None:
            bar.set_total(int(args.duration * args.rate) + 1)
        written = write_simulation(config, opts, Path(args.out), args.duration, topics_from_args(args),
                                   progress=bar.update)
    names = [e.name for e in effects]
    if opts.oil_nu40_nu100_mm2_s and viscosity_law().name not in names:
        names.append(viscosity_law().name)
    passes = (f" (the profile {written.repeats} times, seeds {opts.seed}…{opts.seed + written.repeats - 1})"
              if written.repeats > 1 else "")
    print(f"wrote {args.out}: {written.messages:,} messages, {written.duration_s:.1f} s at {args.rate:g} Hz, "
          f"profile {args.profile}{passes}, effects: {', '.join(names) or 'none'}"
          + (" (oil: ASTM D341 through ν40 = {:g}, ν100 = {:g} mm²/s)".format(*opts.oil_nu40_nu100_mm2_s)
             if opts.oil_nu40_nu100_mm2_s else ""))
    return 0


def _oil(text: str | None, config) -> tuple[float, float] | None:
    """``--oil NU40,NU100``: two kinematic viscosities [mm²/s], ν40 > ν100 > 0, in the ranges of
    ``gearbox.oil_nu40_mm2_s`` and ``gearbox.oil_nu100_mm2_s`` (validated as those)."""
    if text is None:
        return None
    try:
        nu40, nu100 = (float(v) for v in text.split(","))
    except ValueError:
        raise UsageError(f"--oil takes NU40,NU100 (two viscosities in mm²/s, as on a data sheet), not {text!r}") \
            from None
    # the parameter file's rules (ν40 > ν100 > 0, the ranges): a ParameterError naming the violated one
    config.with_values({"gearbox.oil_nu40_mm2_s": nu40, "gearbox.oil_nu100_mm2_s": nu100})
    return nu40, nu100


def add_channels_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--channels", metavar="MAP.yaml",
                   help="channel map for CSV, Parquet, MDF4 or TDMS inputs (format in docs/interface.md)")


def cmd_replay(args: argparse.Namespace) -> int:
    from ..sources.importer import as_mcap
    from ..replay.run import replay

    png = summary_png_path(args)
    exports = [(kind, getattr(args, kind)) for kind in EXPORT_KINDS if getattr(args, kind) is not None]
    check_outputs([args.bag, args.params, args.channels],
                  [Output("--out", args.out, "mcap"), Output("--rrd", args.rrd, "rrd"),
                   Output("--png" if args.png is not None else "the summary picture", png, "png"),
                   *(Output(f"--{kind}", path, kind) for kind, path in exports)])
    config = config_from_args(args)
    topics = topics_from_args(args)
    with as_mcap([args.bag], args.channels, topics, note=lambda m: print(m, file=sys.stderr)) as (bag,):
        summary, _ = replay(bag, config, topics, out_mcap=args.out, rrd=args.rrd,
                            show_progress=None if not args.no_progress else False,
                            warn=lambda m: print(f"rollergear: warning: {m}", file=sys.stderr), summary_png=png,
                            exports=exports, source=None if Path(bag) == Path(args.bag) else args.bag)
    print(summary.text())
    for label, path in (("estimates", args.out), ("rerun recording", args.rrd),
                        ("summary picture", summary.summary_png),
                        *((f"{EXPORT_KINDS[kind]} table", path) for kind, path in exports)):
        if path:
            print(f"{label}: {path}")
    if summary.interrupted:
        return 130
    return damaged_exit(args.bag, summary.lost_share, "the outputs hold what was readable")


def summary_png_path(args: argparse.Namespace) -> str | None:
    """``--png``, else beside ``--out`` (or ``--rrd``) with the suffix ``.png``; ``--no-png``: none."""
    if args.no_png:
        return None
    if args.png is not None:
        return args.png
    beside = args.out or args.rrd
    return str(Path(beside).with_suffix(".png")) if beside else None


def _start_ns(text: str) -> int:
    """``--start``: an ISO 8601 date or time (UTC unless it says otherwise) as ns since the epoch."""
    import datetime

    try:
        when = datetime.datetime.fromisoformat(text)
    except ValueError:
        raise UsageError(f"--start {text!r}: not an ISO 8601 date or time (e.g. 2026-11-27T08:00:00Z)") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=datetime.UTC)
    return int(round(when.timestamp())) * 10**9


def _simulate_fleet(args: argparse.Namespace, config) -> int:
    from ..fleet.simulated import DAY_NS, FleetScenario, simulate_fleet

    if args.fleet < 1 or args.days < 1:
        raise UsageError("--fleet and --days must be at least 1")
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise UsageError(f"{out} is not empty: a fleet goes into a new folder")
    with TimedProgress("simulate fleet", args.fleet * args.days, "log") as bar:
        today = time.time_ns() // DAY_NS * DAY_NS  # the logs are of the days before the run, unless --start
        first = _start_ns(args.start) // DAY_NS * DAY_NS if args.start else today - args.days * DAY_NS
        truth = simulate_fleet(config, out, FleetScenario(args.fleet, args.days, rate_hz=args.rate, seed=args.seed,
                                                          start_ns=first), progress=bar.update)
    print(f"wrote {args.fleet} gearboxes x {args.days} daily logs to {out} (truth: {out / 'fleet_truth.json'}; "
          f"{len(truth['gearboxes'])} drifting)")
    return 0


def register_simulate(sub, with_params) -> None:
    from ..core.effects import EFFECTS
    from ..calibration.simulate import PROFILES

    p = with_params(sub.add_parser("simulate", help="write a synthetic rig recording (MCAP) with declared effects"))
    p.add_argument("--out", required=True, metavar="MCAP", help="the recording to write (with --fleet: a folder)")
    p.add_argument("--fleet", type=int, metavar="N", help="a fleet: N gearboxes x --days daily logs, a few drifting")
    p.add_argument("--days", type=int, default=8, help="days of a simulated fleet (default 8)")
    p.add_argument("--profile", choices=sorted(PROFILES), default="rig_map",
                   help="operating profile: a rig map (forward or both directions), a drive cycle, a warm-up")
    p.add_argument("--rate", type=float, default=200.0, help="sample rate [Hz] (default 200)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="the recording's length [s]: the profile repeats, its seed one more each pass, or is cut "
                        "(default: the profile once)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the sensor noise and the drive cycle")
    p.add_argument("--start", metavar="ISO8601",
                   help="when the recording starts (UTC unless given; default: now; with --fleet the first day, "
                        "default: the --days days before today)")
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME[:k=v,...]",
        help="declared extra effect, repeatable: "
        + "; ".join(
            f"{n}:{','.join(f'{k}={v:g}' for k, v in d.items())}"
            for n, d in ((n, e.simulated_defaults()) for n, e in EFFECTS.items())
        ),
    )
    p.add_argument("--torque-noise", type=float, default=0.01, help="torque sensor noise sigma [N·m]")
    p.add_argument("--noise-ar1", type=float, default=0.0, help="AR(1) coefficient of coloured noise (0 = white)")
    p.add_argument("--output-lag", type=float, default=0.0, help="delay of the output torque channel [s]")
    p.add_argument("--step-change-at", type=float, default=None, help="effects switch on at this time [s]")
    p.add_argument("--joint-states", action="store_true", help="write /joint_states instead of Float64 topics")
    p.add_argument("--oil", metavar="NU40,NU100",
                   help="the viscosity_temperature effect with a real oil's viscosity law (ASTM D341 through its "
                   "data-sheet viscosities at 40 and 100 degC, mm^2/s) instead of Vogel B and C; implies the effect")
    add_topic_options(p)
    p.set_defaults(func=cmd_simulate)


def register_replay(sub, with_params) -> None:
    p = with_params(sub.add_parser("replay", help="replay a recording through the estimator"))
    p.add_argument("bag", metavar="BAG", help="MCAP, rosbag2 folder or .db3, or CSV/Parquet/MDF4/TDMS with --channels")
    p.add_argument("--out", metavar="OUT.mcap", help="output MCAP (inputs + estimates)")
    p.add_argument("--rrd", metavar="OUT.rrd", help="rerun recording with a review blueprint")
    p.add_argument("--png", metavar="SUMMARY.png",
                   help="summary picture: loss, efficiency and residual over time, operating points over the "
                   "efficiency map (default: beside --out or --rrd, as .png)")
    p.add_argument("--no-png", action="store_true", help="no summary picture")
    for kind, what in EXPORT_KINDS.items():
        p.add_argument(f"--{kind}", metavar=f"OUT.{kind}", help=f"the estimates with their inputs as a {what} table, "
                       "a row per sample, units " + ("in the header" if kind == "csv" else "with each column"))
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_channels_option(p)
    add_topic_options(p)
    p.set_defaults(func=cmd_replay)


def cmd_import(args: argparse.Namespace) -> int:
    from ..sources.importer import import_source

    check_outputs([args.source, args.channels], [Output("--out", args.out, "mcap")])
    summary = import_source(args.source, args.out, args.channels, topics_from_args(args))
    print(summary.text())
    return 0


def register_import(sub, with_params) -> None:
    p = sub.add_parser("import", help="convert a rosbag2 bag or a CSV/Parquet/MDF4/TDMS file to a ROS 2 MCAP",
                       description="Convert a recording to a ROS 2 MCAP with the interface's topics, for play, the "
                       "node and anything that reads MCAP. Example: rollergear import rig.mf4 --channels rig.yaml "
                       "--out rig.mcap")
    p.add_argument("source", metavar="SRC", help="rosbag2 folder, metadata.yaml or .db3; or CSV/Parquet/MDF4/TDMS")
    p.add_argument("--out", required=True, metavar="OUT.mcap", help="the ROS 2 MCAP to write")
    add_channels_option(p)
    add_topic_options(p)
    p.set_defaults(func=cmd_import)


REGISTER = [register_simulate, register_replay, register_import]
