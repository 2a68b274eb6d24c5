"""``rollergear import``: a rosbag2 bag or a CSV/Parquet/MDF4/TDMS file as a ROS 2 MCAP."""

from __future__ import annotations

import argparse

from ..sources.paths import Output, check_outputs
from .args import add_channels_option, add_topic_options, topics_from_args

EXAMPLE = "rollergear import rig.mf4 --channels rig.yaml --out rig.mcap"


def cmd_import(args: argparse.Namespace) -> int:
    from ..sources.importer import import_source

    check_outputs([args.source, args.channels], [Output("--out", args.out, "mcap")])
    summary = import_source(args.source, args.out, args.channels, topics_from_args(args))
    print(summary.text())
    return 0


def register(sub) -> None:
    p = sub.add_parser("import", help="convert a rosbag2 bag or a CSV/Parquet/MDF4/TDMS file to a ROS 2 MCAP",
                       description="Convert a recording to a ROS 2 MCAP with the interface's topics, for play, the "
                       "node and anything that reads MCAP. Example: rollergear import rig.mf4 --channels rig.yaml "
                       "--out rig.mcap")
    p.add_argument("source", metavar="SRC", help="rosbag2 folder, metadata.yaml or .db3; or CSV/Parquet/MDF4/TDMS")
    p.add_argument("--out", required=True, metavar="OUT.mcap", help="the ROS 2 MCAP to write")
    add_channels_option(p)
    add_topic_options(p)
    p.set_defaults(func=cmd_import)
