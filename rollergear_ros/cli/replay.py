"""``rollergear replay``: a recording through the estimator, its summary and outputs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..base.errors import damaged_exit
from ..outputs.exports import EXPORT_KINDS
from ..sources.paths import Output, check_outputs
from .args import add_channels_option, add_params_option, add_topic_options, config_from_args, topics_from_args

EXAMPLE = "rollergear replay rig.mcap --params calibrated.yaml --out estimates.mcap --rrd review.rrd"


def cmd_replay(args: argparse.Namespace) -> int:
    from ..replay.run import replay
    from ..sources.importer import as_mcap

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


def register(sub) -> None:
    p = add_params_option(sub.add_parser("replay", help="replay a recording through the estimator"))
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
