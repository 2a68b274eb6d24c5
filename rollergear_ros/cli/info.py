"""``rollergear info``: what a recording or table holds."""

from __future__ import annotations

import argparse
import json

from ..base.errors import BagError, damaged_exit

EXAMPLE = "rollergear info rig.mcap"


# ---------------------------------------------------------------------------------- info
def cmd_info(args: argparse.Namespace) -> int:
    from ..sources.info import describe

    info = describe(args.file, args.channels)
    print(json.dumps(info.as_dict(), indent=2) if args.json else info.text())
    if info.lost_share >= 1.0:  # the exit statuses of every command (docs/interface.md)
        raise BagError(f"{args.file}: nothing readable")
    return damaged_exit(args.file, info.lost_share, "described what was readable")


def register(sub) -> None:
    p = sub.add_parser("info", help="what a recording or table holds: topics, types, counts, rates, span, damage",
                       description="What FILE holds, as ros2 bag info / mcap info print it, for every format import "
                       "reads: topics (channels, columns) with types, counts and rates, the time span, the metadata "
                       "keys and the damaged spans.")
    p.add_argument("file", metavar="FILE", help="MCAP, rosbag2 folder or .db3, CSV, Parquet, MDF4, TDMS or .vtlm")
    p.add_argument("--channels", metavar="MAP.yaml",
                   help="channel map: a time-series file channel by channel as import reads it (else its columns)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(func=cmd_info)
