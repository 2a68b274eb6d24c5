"""``rollergear watch``: a running node's estimates and status, a line per period (rclpy imported when it runs)."""

from __future__ import annotations

import argparse

from ..base.errors import UsageError
from ..base.interface import NAMESPACE
from ..ros.player import init_for_command_line
from ..ros.watch import watch

EXAMPLE = "rollergear watch --period 1"


def cmd_watch(args: argparse.Namespace) -> int:
    import rclpy

    if not (args.period > 0):
        raise UsageError("--period must be > 0")
    if not (args.until_silent >= 0):
        raise UsageError("--until-silent must be >= 0 s")
    init_for_command_line()
    try:
        fmt = "json" if args.json else "csv" if args.csv else "text"
        return watch(args.namespace, args.period, args.count, fmt=fmt, until_silent_s=args.until_silent)
    finally:
        rclpy.try_shutdown()


def register(sub) -> None:
    p = sub.add_parser("watch", help="print a running loss_estimator's estimates and status once a second")
    p.add_argument("--namespace", default=NAMESPACE, help=f"the node's namespace (default {NAMESPACE})")
    p.add_argument("--period", type=float, default=1.0, metavar="S", help="seconds per line (default 1)")
    p.add_argument("--count", type=int, default=0, metavar="N", help="stop after N lines (default: until Ctrl-C)")
    p.add_argument("--until-silent", type=float, default=0.0, metavar="S",
                   help="end with exit status 3 once the node has said nothing on /diagnostics for S seconds "
                        "(it ended, was killed or hangs; default: watch on)")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--csv", action="store_true", help="a CSV header, then one row per period (for a logger)")
    fmt.add_argument("--json", action="store_true", help="one JSON object per period and line (JSON Lines)")
    p.set_defaults(func=cmd_watch)
