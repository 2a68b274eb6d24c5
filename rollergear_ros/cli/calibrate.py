"""``rollergear calibrate``: residual analysis, effect discovery, error before/after on held-out data."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
from pathlib import Path

from ..base.errors import damaged_exit
from ..base.progress import TimedProgress
from ..sources.paths import Output, check_outputs
from .args import (
    add_assume_option,
    add_channels_option,
    add_params_option,
    add_topic_options,
    block_seconds,
    config_from_args,
    positive_float,
    topics_from_args,
    window_time,
)

EXAMPLE = "rollergear calibrate rig.mcap --out calibrated.yaml --report report/"


def _log(msg: str) -> None:
    print(msg, file=sys.stderr)


def _warn(msg: str) -> None:
    _log(f"rollergear: warning: {msg}")


def cmd_calibrate(args: argparse.Namespace) -> int:
    from ..base.atomic import together, write_text
    from ..calibration.report import REPORT_FILES, write_report
    from ..calibration.written import calibrated_yaml

    check_outputs([*args.bags, args.params, args.channels],  # now, not after the whole analysis
                  [Output("--out", args.out, "yaml"), Output("--report", args.report, "folder", REPORT_FILES)])
    config = config_from_args(args)
    if args.oil:  # the oil's data sheet: the viscosity law's start and range
        config = config.with_values(dict(zip(("gearbox.oil_nu40_mm2_s", "gearbox.oil_nu100_mm2_s",
                                              "gearbox.oil_density15_kg_m3"), args.oil)))
    with _stdout_kept_for_json(args.json):  # what C libraries print (LAPACK's DLASCL) goes to stderr
        data = _load(args, config)
        result = _analyse(args, data, config)
    for line in _error_after_warnings(result, args.assume):
        _warn(line)
    with together():  # the parameter file and the report's files are put in place together, or none
        if args.out and result.written:
            write_text(args.out, calibrated_yaml(result, args.bags))
        report = write_report(result, data, Path(args.report), args.bags) if args.report else None
    if args.json:
        sys.stdout.write(json.dumps(result.to_json()) + "\n")
        damaged = damaged_exit(", ".join(args.bags), data.lost_share, "calibrated on what was readable")
        return damaged or (0 if result.written else 1)
    _print_result(result)
    if args.out:
        print(f"calibrated parameters: {args.out}" if result.written else
              f"calibrated parameters: {args.out} not written ({_what_would_settle(result)})")
    if report:
        print(f"report: {report}")
    damaged = damaged_exit(", ".join(args.bags), data.lost_share, "calibrated on what was readable")
    return damaged or (0 if result.written else 1)


def _load(args: argparse.Namespace, config):
    """The samples with measured output of the recordings, or the rows of the steady-state tables."""
    from ..base.errors import UsageError
    from ..calibration.samples import load_samples, power_balance_warning, table_samples
    from ..replay.run import imported_table
    from ..sources.channelmap import load_channel_map
    from ..sources.importer import as_mcap
    from ..sources.tables import is_table

    cmap = load_channel_map(args.channels) if args.channels else None
    # a table's import is its rows again: calibrated as the table, as replay estimates them
    tables = [is_table(p, cmap) or imported_table(p) is not None for p in args.bags]
    if any(tables) and not all(tables):
        raise UsageError("give either recordings or steady-state tables (.vtlm, or their import), not both: a "
                         "table's rows are dwell means, a recording's samples are not")
    if not args.json:
        _log(f"reading {len(args.bags)} {'table' if all(tables) else 'recording'}(s) …")
    topics = topics_from_args(args)
    if all(tables):
        data = table_samples(args.bags, config, warn=_warn, cmap=cmap)
    else:
        with as_mcap(args.bags, args.channels, topics, note=None if args.json else _log) as bags:
            data = load_samples(bags, config, topics, warn=_warn, progress=not args.json and sys.stderr.isatty())
    balance = power_balance_warning(data)
    if balance:
        _warn(balance)
    return data


@contextlib.contextmanager
def _stdout_kept_for_json(json_output: bool):
    """With ``--json``, file descriptor 1 points at stderr inside the block: stdout carries the one
    JSON line and nothing a library writes there (LAPACK's messages) can break it."""
    if not json_output:
        yield
        return
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def _analyse(args: argparse.Namespace, data, config):
    """:func:`~calibration.calibrate.calibrate` with a progress bar of its stages; a fit the data
    cannot carry (a singular system) is one line."""
    import numpy as np

    from ..base.errors import InputFileError
    from ..calibration.calibrate import CalibrationSettings, calibrate

    if not args.json:
        _log(f"{len(data.t_ns):,} {'rows' if data.steady_state else 'samples with measured output'}; analysing …")
    with TimedProgress("analysis", unit=" steps", unit_scale=False,
                       enabled=not args.json and sys.stderr.isatty()) as bar:

        def stage(text: str) -> None:
            bar.stage = text
            bar.update(1)

        try:
            return calibrate(data, config, CalibrationSettings(args.delta, args.block_s, stage=stage,
                                                               assume=args.assume, segments=args.segments,
                                                               start_s=args.start, end_s=args.end))
        except np.linalg.LinAlgError as exc:
            raise InputFileError(f"{', '.join(args.bags)}: the samples admit no fit ({exc}): too few distinct "
                                 "operating points (a direction that flips every sample, one speed only)") from None


def _print_result(result) -> None:
    """The verdict, what was found and not (every candidate, with its reason), the rig's nuisances, the
    held-out error before and after."""
    eb, ea = result.error_before, result.error_after
    print(f"verdict: {result.verdict}")
    if result.stretch and result.changes:
        print(f"fitted: {result.stretch}")
    for e in result.effects:
        params = ", ".join(f"{k}={v:.4g}" for k, v in e.params.items())
        ci = ", ".join(f"{k} in [{lo:.4g}, {hi:.4g}]" for k, (lo, hi) in e.ci95.items())
        print(f"  effect {e.name}: {params}  (95 %: {ci}; RMS contribution {e.rms_contribution_nm:.4g} N·m)")
        if e.bound_note():
            print(f"    note: {e.bound_note()}")
        line = next((d.note for d in result.decisions if d.name == e.name and "its line" in d.note), "")
        if line:  # a law held at its line: why not its curve
            print(f"    note: {line[line.index('its line'):]}")
    for prm in result.parameters:
        print(f"  parameter {prm.sentence()}")
    _print_not_found(result)
    print(
        f"held-out error ({result.samples:,} samples): RMSE of "
        f"{result.blocks.block_s if result.blocks else 0.25:g} s block means {eb.rmse_nm:.4g} -> "
        f"{ea.rmse_nm:.4g} N·m, per sample (sensor noise included) "
        f"{result.sample_level['before'].rmse_nm:.4g} -> "
        f"{result.sample_level['after'].rmse_nm:.4g} N·m; "
        f"of the block means: MAE {eb.mae_nm:.4g} -> {ea.mae_nm:.4g} N·m, "
        f"max {eb.max_abs_nm:.4g} -> {ea.max_abs_nm:.4g} N·m, {eb.rel_rmse_pct:.2f} % -> {ea.rel_rmse_pct:.2f} % "
        "of the measured loss"
    )
    if result.from_file:
        print(f"before: the parameter file as given (its {', '.join(result.from_file)}, not refitted)")
    print(f"held out: {result.holdout}")
    if result.groups:
        worst = result.groups[0]
        print(f"worst held-out operating point: {worst['operating_point']} ({worst['heldout_rmse_nm']:.4g} N·m RMS "
              f"over {worst['samples']:,} samples, mean {worst['heldout_mean_nm']:+.4g}); best "
              f"{result.groups[-1]['heldout_rmse_nm']:.4g} N·m ({len(result.groups)} operating points: --json "
              "heldout_by_operating_point)")
    if result.hand_fit:
        h = result.hand_fit
        print(f"hand fit: {h['text']} held out {h['heldout_rmse_nm']:.4g} N·m against the selection's "
              f"{h['selection_heldout_rmse_nm']:.4g}: {'written' if h['written'] else 'not written'} ({h['reason']})")
    if result.minimum:
        print(f"minimum effect size: {result.minimum.text}")
    for line in _nuisance_lines(result):
        print(f"rig: {line}")
    if result.adequacy:
        print(f"adequacy: {result.adequacy.statement}")
    if result.structure and result.verdict != "no_missing_effect":
        print(f"residual left: {result.structure['statement']}")
    for note in result.notes:
        print(f"note: {note}")


def _nuisance_lines(result) -> list[str]:
    """The speed reading's noise, each channel's lag that matters, the inertia, said."""
    lines = [f"speed reading's noise: {result.speed_noise}"] if result.speed_noise else []
    lines += [lag.sentence() for lag in result.lags if lag.applied or lag.why_not]
    if result.inertia is not None and result.inertia["ci95"][0] * result.inertia["ci95"][1] > 0:
        lines.append(result.inertia["text"])
    return lines


def _print_not_found(result) -> None:
    """Every candidate not accepted and why, the sets the data cannot tell apart, the bounds on the rest."""
    from ..calibration.report import reading_choice

    for d in result.decisions:
        if not d.accepted and d.name not in result.unavailable:
            print(f"  {d.sentence()}")
    if result.unavailable:
        print("  not testable here: " + "; ".join(f"{d.name} ({d.reasons[0]})" for d in result.decisions
                                                 if d.name in result.unavailable and d.reasons))
    for a in result.ambiguous:
        if a.taken is not None:
            errors = "; ".join(f"{' + '.join(r['effects'])} held-out RMSE {r['heldout_rmse_nm']:.4g} N·m"
                               + (" (written)" if r["written"] else "") for r in a.readings)
            how = reading_choice(a)
            other = [e for e in a.effects if e not in a.taken.split(" + ")]
            print(f"  two readings of one part of the loss: {' / '.join(a.effects)} -- taken as {a.taken}, {how} "
                  f"({errors}); record {a.needs} to tell them apart"
                  + ("" if a.assumed else f", or --assume {' or '.join(other)}"))
        elif a.assumed:
            print(f"  cannot tell apart: {' / '.join(a.effects)} — taken as {a.assumed}, as assumed (record {a.needs} "
                  "to separate them)")
        else:
            print(f"  cannot tell apart: {' / '.join(a.effects)} — record {a.needs} to separate them, or say which it "
                  f"is with --assume ({' or '.join(a.effects)})")
    if result.verdict == "no_missing_effect":
        bounds = ", ".join(f"{r.name} <= {r.upper_rms_nm:.3g}" for r in result.rejected)
        print(f"  no missing effect larger than delta = {result.delta_nm:.4g} N·m (upper 95 % bounds: {bounds})")


def _what_would_settle(result) -> str:
    """What data or assumption would let a calibration that was not written be one."""
    open_sets = [a for a in result.ambiguous if a.assumed is None and a.taken is None]
    if open_sets:
        return "; ".join(f"{' / '.join(a.effects)} cannot be told apart: record {a.needs}, or --assume one of them"
                         for a in open_sets)
    return "record a wider range of speed, torque, direction and oil temperature"


def _error_after_warnings(result, assume: list[str]) -> list[str]:
    """Lines for what a user would otherwise misread: an assumption the data did not need."""
    lines = []
    in_sets = {e for a in result.ambiguous for e in a.effects}
    for name in assume:
        if name not in in_sets:
            lines.append(f"--assume {name}: not needed, the data did not leave {name} indistinguishable from another "
                         "effect (nothing assumed)")
    return lines


def register(sub) -> None:
    p = add_params_option(
        sub.add_parser(
            "calibrate",
            help="find effects the model lacks from recordings with measured "
            "output torque; error before/after on held-out data",
        )
    )
    p.add_argument("bags", nargs="+", metavar="BAG",
                   help="recordings with measured output torque (MCAP, rosbag2, or CSV/Parquet/MDF4/TDMS with "
                   "--channels), or steady-state tables (VECTO .vtlm, or CSV/Parquet with a steady_state map)")
    p.add_argument("--out", metavar="CALIBRATED.yaml", help="parameter file with the accepted effects")
    p.add_argument("--report", metavar="DIR", help="Markdown report with plots")
    p.add_argument("--json", action="store_true", help="print exactly the interface.md JSON object on stdout")
    p.add_argument(
        "--delta",
        type=positive_float,
        default=None,
        metavar="NM",
        help="practical minimum effect size (RMS N·m); default from the data",
    )
    p.add_argument("--block-s", type=block_seconds, default=0.25, help="averaging block length [s]")
    add_assume_option(p)
    p.add_argument("--segments", choices=("latest", "each", "off"), default="latest",
                   help="changes inside the recordings: calibrate the latest stretch after the last one (default), "
                   "also each stretch (each), or all samples at once (off)")
    p.add_argument("--start", type=window_time, default=None, metavar="S|ISO",
                   help="analyse from S seconds after the first sample analysed, or from an instant on the "
                   "recording's clock (ISO 8601 to the ns, as a trace names its window; with --end: a window)")
    p.add_argument("--end", type=window_time, default=None, metavar="S|ISO",
                   help="analyse up to S seconds after the first sample analysed (before it), or up to an instant "
                   "(ISO 8601: the samples at it included)")
    p.add_argument("--oil", type=_datasheet, metavar="NU40,NU100[,RHO15]",
                   help="the oil's data sheet: kinematic viscosities at 40 and 100 degC [mm^2/s] and the density at "
                   "15 degC [kg/m^3, default 880]; the viscosity law (ASTM D341) starts from it and stays near it "
                   "(also gearbox.oil_* in the parameter file)")
    add_channels_option(p)
    add_topic_options(p)
    p.set_defaults(func=cmd_calibrate)


def _datasheet(text: str) -> tuple[float, ...]:
    """``--oil NU40,NU100[,RHO15]``: ν40 > ν100 > 0 mm²/s, ρ15 in kg/m³."""
    import math

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: NU40,NU100[,RHO15] are numbers") from None
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values) or not values[0] > values[1] > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: need NU40 > NU100 > 0 mm^2/s (an oil is thinner when warm) "
                                         "and optionally RHO15 kg/m^3")
    return values
