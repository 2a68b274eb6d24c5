"""``rollergear fleet replay|calibrate``: many recordings on Dask, the fleet table, the drift report."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..base.errors import UsageError
from ..fleet.logs import SLICE_MESSAGES
from ..sources.paths import Output, check_outputs
from .args import add_assume_option, add_params_option, config_from_args

EXAMPLE = "rollergear fleet calibrate fleet/ --out fleet_out/ --workers 2"


DAY_S = 86_400


MAX_WINDOW_DAYS = 100_000  #: about 270 years: a window's nanoseconds stay within 64 bits


MIN_SLICE_MESSAGES = 10_000


def cmd_fleet(args: argparse.Namespace) -> int:
    from ..fleet.cluster import dask_client
    from ..fleet.logs import discover
    from ..fleet.report import drift, write_fleet_report
    from ..fleet.run import FleetRun, run_calibrate, run_replay

    config = config_from_args(args)
    if args.workers is not None and args.workers < 1:
        raise UsageError("--workers must be at least 1")
    if args.window_hours is not None:
        if not (math.isfinite(args.window_hours) and 0 < args.window_hours <= MAX_WINDOW_DAYS * 24):
            raise UsageError(f"--window must be a number of hours in (0, {MAX_WINDOW_DAYS * 24:,}], "
                             f"not {args.window_hours:g}")
        args.window_days = args.window_hours / 24.0
    if not (math.isfinite(args.window_days) and 0 < args.window_days <= MAX_WINDOW_DAYS):
        raise UsageError(f"--window-days must be a number of days in (0, {MAX_WINDOW_DAYS:,}], "
                         f"not {args.window_days:g}")
    if args.slice_messages < MIN_SLICE_MESSAGES:
        raise UsageError(f"--slice-messages must be at least {MIN_SLICE_MESSAGES:,} (each slice is a task that also "
                         "reads a lead-in and a lead-out)")

    def note(msg: str) -> None:
        print(msg, file=sys.stderr)

    check_outputs([], [Output("--out", args.out, "folder")])
    recs = discover(args.logs, args.group_by, exclude=args.out)  # the fleet's own tables are no recordings
    out = Path(args.out)
    note(f"{len(recs)} recordings of {len({r.gearbox_id for r in recs})} gearboxes")
    with dask_client(args.scheduler, args.workers, note) as client:
        run = FleetRun(client, config, args.channels, progress=sys.stderr.isatty(), note=note)
        if args.action == "replay":
            rows, ran = run_replay(recs, out, run, slice_messages=args.slice_messages)
        else:
            rows, ran = run_calibrate(recs, out, run, int(round(args.window_days * DAY_S * 1e9)),
                                      assume=args.assume)
    failed = [r for r in rows if r.get("status") != "ok"]
    print(f"{args.action}: {ran} run now, {len(rows)} rows in {out}; {len(failed)} failed")
    for r in failed[:10]:
        print(f"  failed: {r.get('recording') or r.get('gearbox_id')}: {r.get('reason')}")
    if args.action == "calibrate":
        for r in [r for r in rows if r.get("warning")][:10]:
            print(f"  warning: {r.get('gearbox_id')} window {r.get('window')}: {r.get('warning')}")
        for g in drift(rows):
            if g.drifts:
                print(f"  drift: {g.sentence()}")
    print(f"report: {write_fleet_report(out)}")
    return 0


def _common_options(p: argparse.ArgumentParser) -> None:
    """The options ``fleet replay`` and ``fleet calibrate`` share: what to read, where, on which cluster."""
    p.add_argument("logs", nargs="+", metavar="LOGS", help="files, folders or globs, local or fsspec URLs "
                   "(s3://… where the filesystem package is installed)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the tables, the report and the maps")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler (default: a LocalCluster)")
    p.add_argument("--workers", type=int, metavar="N", help="LocalCluster worker processes (default: the cores)")
    p.add_argument("--channels", metavar="MAP.yaml", help="channel map for CSV/Parquet/MDF4/TDMS recordings")
    p.add_argument("--group-by", choices=("auto", "folder", "metadata"), default="auto",
                   help="gearbox identity: metadata gearbox_id, else the folder (auto); or only one of them")


def register(sub) -> None:
    p = sub.add_parser(
        "fleet", help="replay or calibrate a fleet's recordings on Dask: fleet table, drift, report",
        description="Many recordings on a Dask cluster (a LocalCluster of worker processes unless --scheduler), "
        "DIR/report.md and DIR/maps/<gearbox>.vtlm. A rerun with the same --out skips what is done. "
        "'rollergear fleet replay --help' and 'rollergear fleet calibrate --help' give each action's options.")
    actions = p.add_subparsers(dest="action", required=True, metavar="{replay,calibrate}",
                               help="what to run on each recording; each has its own --help")
    r = add_params_option(actions.add_parser(
        "replay", help="replay each recording: DIR/fleet.parquet, a row per recording",
        description="Replay each recording through the estimator on a Dask cluster: DIR/fleet.parquet (a row per "
        "recording: energy, efficiency, residual), DIR/report.md. Long recordings are replayed in time slices, "
        "a task each. A rerun with the same --out skips what is done.",
        epilog="example: rollergear fleet replay fleet/ --out fleet_out/ --workers 2"))
    _common_options(r)
    r.add_argument("--slice-messages", type=int, default=SLICE_MESSAGES, metavar="N",
                   help="replay a recording of more messages in time slices of about N, one task each "
                   f"(default {SLICE_MESSAGES:,}: ~10 s a task on a 2-core machine of 2026)")
    r.set_defaults(func=cmd_fleet, window_days=1.0, window_hours=None, assume=[])
    c = add_params_option(actions.add_parser(
        "calibrate", help="calibrate each gearbox per time window: DIR/fleet_calibrate.parquet, drift",
        description="Calibrate each gearbox per time window on a Dask cluster: DIR/fleet_calibrate.parquet (a row "
        "per gearbox and window), the drift ranking in DIR/report.md, DIR/maps/<gearbox>.vtlm. A rerun with the "
        "same --out skips what is done.",
        epilog="example: rollergear fleet calibrate fleet/ --out fleet_out/ --workers 2"))
    _common_options(c)
    span = c.add_mutually_exclusive_group()
    span.add_argument("--window-days", type=float, default=1.0, metavar="DAYS",
                      help="calibration window (default 1 day); a recording across windows is split between them")
    span.add_argument("--window", dest="window_hours", type=float, default=None, metavar="HOURS",
                      help="calibration window in hours (a rig's long recording: drift inside it)")
    add_assume_option(c)
    c.set_defaults(func=cmd_fleet, slice_messages=SLICE_MESSAGES)
