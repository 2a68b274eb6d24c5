"""``rollergear play``: a recorded bag published over ROS 2 with its original timing (rclpy imported when it runs)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..base.errors import BagError, UsageError, damaged_exit
from ..ros.player import GRAPH_WAIT_S, MIN_MATCHED_WAIT_S, SUBSCRIBER_SETTLE_S, PlayOptions, init_for_command_line, play

EXAMPLE = "rollergear play rig.mcap --rate 5 --loop"


def cmd_play(args: argparse.Namespace) -> int:
    import rclpy

    from ..sources.formats import input_format

    if not (args.rate > 0):
        raise UsageError("--rate must be > 0")
    fmt = input_format(args.bag)
    if fmt.family not in ("mcap", "rosbag2"):  # what was given, and the way to a recording play can publish
        raise UsageError(f"{args.bag} is a {fmt.name} {'folder' if Path(args.bag).is_dir() else 'file'}: play "
                         f"publishes ROS 2 recordings (MCAP, rosbag2); convert it first: rollergear import "
                         f"{args.bag} --out REC.mcap" + (" --channels MAP.yaml" if fmt.family == "timeseries" else ""))
    options = PlayOptions(args.rate, args.loop, args.clock, args.topics, args.wait_for_subscribers, args.delay,
                          not args.best_effort, wait_for_graph_s=0.0 if args.no_wait else GRAPH_WAIT_S,
                          show_progress=not args.no_progress, label=args.bag,
                          min_subscribers=max(args.min_subscribers, 0))
    with _as_mcap_recording(Path(args.bag), fmt.family) as bag:
        init_for_command_line()
        try:
            stats = play(bag, options)
        finally:
            rclpy.try_shutdown()
    if stats.damaged and not stats.messages:  # as replay: nothing readable is exit 2, not a damaged play
        raise BagError(f"{args.bag}: nothing readable: {len(stats.damaged)} damaged span(s); nothing played")
    return damaged_exit(args.bag, stats.lost_share, f"played what was readable ({stats.messages:,} messages)")


@contextmanager
def _as_mcap_recording(bag: Path, family: str) -> Iterator[Path]:
    """The MCAP to publish: the bag itself, or a rosbag2 bag (MCAP or SQLite storage, split or not)
    with every topic copied into a temporary MCAP in log-time order, removed afterwards."""
    if family == "mcap":
        yield bag
        return
    import tempfile

    from ..sources.importer import copy_rosbag2

    with tempfile.TemporaryDirectory(prefix="rollergear-play-") as tmp:
        copy = Path(tmp) / "bag.mcap"
        counts = copy_rosbag2(bag, copy)
        print(f"play: read the rosbag2 bag {bag}: {sum(counts.values()):,} messages on {len(counts)} topics",
              file=sys.stderr)
        yield copy


def register(sub) -> None:
    p = sub.add_parser("play", help="publish a recorded bag over ROS 2 with its original timing")
    p.add_argument("bag", metavar="BAG", help="ROS 2 recording: MCAP, or a rosbag2 folder (metadata.yaml; MCAP or "
                   "SQLite storage); rollergear import converts other formats")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    p.add_argument("--loop", action="store_true", help="play again and again")
    p.add_argument("--clock", action="store_true", help="publish /clock with the bag's time (use_sim_time)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics")
    p.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="S",
                   help="wait up to S seconds until every topic has a subscriber (for a node started after "
                        "the player), then " f"{SUBSCRIBER_SETTLE_S:g} s for them to discover the player")
    p.add_argument("--min-subscribers", type=int, default=0, metavar="N",
                   help=f"wait (at most {MIN_MATCHED_WAIT_S:g} s) until every topic has N matched subscribers "
                        "(several consumers that must all get the first message)")
    p.add_argument("--no-wait", action="store_true",
                   help=f"start at once; by default the player first waits (at most {GRAPH_WAIT_S:g} s) until the "
                        "subscribers already running have matched, so that they get the first message")
    p.add_argument("--delay", type=float, default=0.0, metavar="S", help="sleep S seconds before playing")
    p.add_argument("--best-effort", action="store_true", help="publish best effort instead of reliable")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_play)
