"""``rollergear play BAG``: publish a recorded bag over ROS 2 with its original timing.

Stands in for ``ros2 bag play`` (rosbag2 has no PyPI wheels).  Messages are published as the
bag's serialized bytes (no decode/encode), in log-time order, at ``--rate`` times real time;
``--clock`` also publishes ``/clock`` so nodes with ``use_sim_time`` see the bag's time.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

from .bag import BagError, inspect_bag
from .cli import UserError


def message_class(type_name: str):
    """``std_msgs/msg/Float64`` -> the rclpy message class."""
    try:
        pkg, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise UserError(f"message type {type_name!r} is not available in this ROS installation") from None


def play(bag: Path, rate: float = 1.0, loop: bool = False, clock: bool = False, topics: list[str] | None = None,
         wait_for_subscribers: float = 0.0, start_delay: float = 0.0, reliable: bool = True,
         quiet: bool = False) -> int:
    """Publish the bag; returns the number of messages published."""
    import rclpy
    from mcap.reader import make_reader
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    info = inspect_bag(bag)
    selected = {t: ty for t, ty in info.topics.items() if topics is None or t in topics}
    if not selected:
        raise UserError(f"nothing to play: the bag has {info.describe_topics()}")
    if not rclpy.ok():
        rclpy.init()
    node = Node("rollergear_player")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT)
    pubs = {t: node.create_publisher(message_class(ty), t, qos) for t, ty in selected.items()}
    clock_pub = node.create_publisher(Clock, "/clock", 10) if clock else None
    if wait_for_subscribers > 0:
        deadline = time.monotonic() + wait_for_subscribers
        while time.monotonic() < deadline and any(p.get_subscription_count() == 0 for p in pubs.values()):
            time.sleep(0.02)
        # give discovery of the reverse direction a moment as well
        time.sleep(0.2)
    if start_delay > 0:
        time.sleep(start_delay)
    sent = 0
    try:
        while True:
            with bag.open("rb") as fh:
                reader = make_reader(fh)
                t0_bag = None
                t0_wall = time.monotonic_ns()
                last_clock = None
                for _schema, channel, message in reader.iter_messages(topics=list(selected), log_time_order=True):
                    if t0_bag is None:
                        t0_bag = message.log_time
                    target = t0_wall + int((message.log_time - t0_bag) / rate)
                    while True:
                        wait = target - time.monotonic_ns()
                        if wait <= 0:
                            break
                        time.sleep(wait * 1e-9 if wait > 2_000_000 else 0.0002)
                    if clock_pub is not None and message.log_time != last_clock:
                        c = Clock()
                        c.clock.sec, c.clock.nanosec = divmod(message.log_time, 1_000_000_000)
                        clock_pub.publish(c)
                        last_clock = message.log_time
                    pubs[channel.topic].publish(message.data)
                    sent += 1
            if not loop:
                break
        # let the middleware deliver the last messages before the publisher goes away
        time.sleep(0.3)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
    if not quiet:
        print(f"played {sent:,} messages from {bag}", file=sys.stderr)
    return sent


def cmd_play(args: argparse.Namespace) -> int:
    import rclpy

    if not (args.rate > 0):
        raise UserError("--rate must be > 0")
    rclpy.init(args=None)
    try:
        play(Path(args.bag), args.rate, args.loop, args.clock, args.topics, args.wait_for_subscribers,
             args.delay, not args.best_effort)
    except BagError as exc:
        raise UserError(str(exc)) from None
    finally:
        rclpy.try_shutdown()
    return 0


def register_play(sub, with_params) -> None:  # noqa: ARG001
    p = sub.add_parser("play", help="publish a recorded bag over ROS 2 with its original timing")
    p.add_argument("bag", metavar="BAG")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    p.add_argument("--loop", action="store_true", help="play again and again")
    p.add_argument("--clock", action="store_true", help="publish /clock with the bag's time (use_sim_time)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics")
    p.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="S",
                   help="wait up to S seconds until every topic has a subscriber")
    p.add_argument("--delay", type=float, default=0.0, metavar="S", help="sleep S seconds before playing")
    p.add_argument("--best-effort", action="store_true", help="publish best effort instead of reliable")
    p.set_defaults(func=cmd_play)


REGISTER = [register_play]
