"""``rollergear simulate``: a synthetic rig recording (MCAP) with declared effects, or a simulated fleet."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..base.errors import UsageError
from ..base.progress import TimedProgress
from ..core.effects import viscosity_law
from ..sources.paths import Output, check_outputs
from .args import add_params_option, add_topic_options, config_from_args, topics_from_args

EXAMPLE = "rollergear simulate --out rig.mcap --profile bidirectional_map --effect drag_speed:c=3e-4,p=1.4"


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


def register(sub) -> None:
    from ..calibration.simulate import PROFILES
    from ..core.effects import EFFECTS

    p = add_params_option(sub.add_parser(
        "simulate", help="write a synthetic rig recording (MCAP) with declared effects"))
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
