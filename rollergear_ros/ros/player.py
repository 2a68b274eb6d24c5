"""The bag player behind ``rollergear play`` (:mod:`cli.play`): a recorded bag over ROS 2 with its original timing.

Stands in for ``ros2 bag play`` (rosbag2 has no PyPI wheels).  Messages are published as the
bag's serialized bytes (no decode/encode), in log-time order, at ``--rate`` times real time;
``--clock`` also publishes ``/clock`` so nodes with ``use_sim_time`` see the bag's time.  The bag
is read a few chunks ahead in a thread; the summary line says how closely the timing was kept.
"""

from __future__ import annotations

import importlib
import queue
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..base.errors import UsageError, lost_share
from ..base.progress import TimedProgress
from ..recordings.baginfo import inspect_bag
from ..recordings.fastmcap import ReadState, preload_summary
from ..recordings.logorder import iter_log_time_order


def message_class(type_name: str):
    """``std_msgs/msg/Float64`` -> the rclpy message class."""
    try:
        pkg, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise UsageError(f"message type {type_name!r} is not available in this ROS installation") from None


def _available_class(type_name: str):
    """The rclpy message class of ``type_name``, or None where this installation has none."""
    try:
        return message_class(type_name)
    except UsageError:
        return None


class _Prefetch:
    """Reads and orders the bag in a background thread, a few chunks ahead of the publishing loop,
    so decoding a chunk never holds up the timing of the messages being published."""

    def __init__(self, bag: Path, state: ReadState, depth: int = 4) -> None:
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(bag, state), daemon=True)
        self._thread.start()

    def _run(self, bag: Path, state: ReadState) -> None:
        try:
            for batch in iter_log_time_order(bag, state):
                while not self._stop.is_set():
                    try:
                        self._queue.put(batch, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if self._stop.is_set():
                    return
            self._queue.put(None)
        except Exception as exc:  # noqa: BLE001 - handed to the publishing thread
            self._queue.put(exc)

    def __iter__(self):
        while True:
            item = self._queue.get()
            if item is None:
                return
            if isinstance(item, Exception):
                raise item
            yield item

    def close(self) -> None:
        self._stop.set()


@dataclass
class PlayStats:
    """What a play published and how closely it kept the bag's timing."""

    messages: int = 0
    max_late_ms: float = 0.0  #: worst delay of a publish behind its scheduled time
    late_over_5ms: int = 0  #: publishes more than 5 ms behind
    held_back: int = 0  #: publishes that waited for a reliable keep-all subscriber to catch up
    refused: int = 0  #: messages the middleware would not publish (not its type: a damaged record's bytes)
    damaged: list[str] = field(default_factory=list)  #: the damaged spans the read skipped (one line each)
    lost_share: float = 0.0  #: the share of the recording they cost (:func:`base.errors.lost_share`)

    def text(self) -> str:
        held = f"; held back {self.held_back} times by a subscriber that fell behind" if self.held_back else ""
        refused = (f"; {self.refused:,} not published: the middleware refused them (a damaged record's bytes, not "
                   "its topic's message)" if self.refused else "")
        return (f"{self.messages:,} messages; timing: max {self.max_late_ms:.1f} ms late, "
                f"{self.late_over_5ms} more than 5 ms late{held}{refused}")


#: a publish to a keep-all subscriber whose queue is full fails after blocking this long or longer; one that
#: fails sooner was refused for what it is (bytes that are not its topic's message), never retried
FULL_QUEUE_BLOCK_S = 0.01
#: a message still held back after this long is given up (said): a subscriber that never catches up
MAX_HELD_BACK_S = 30.0
#: after the subscribers have matched, before the first message: they must discover the player as
#: well (a best-effort subscription drops what a publisher it has not matched yet sends)
SUBSCRIBER_SETTLE_S = 1.0
#: by default, how long the player waits for the subscribers already in the ROS graph to match
GRAPH_WAIT_S = 5.0
#: ``--min-subscribers``: the longest wait for that many to match each topic
MIN_MATCHED_WAIT_S = 120.0
#: at the end: how long reliable subscribers may take to acknowledge the last messages
FINAL_ACK_TIMEOUT_S = 60.0


def wait_for_graph(node, pubs: dict, bound_s: float, every_topic_s: float = 0.0, min_matched: int = 0) -> str:
    """Wait until every subscriber the ROS graph shows on the played topics has matched the
    player's publishers (a node started first then gets the first message), then
    :data:`SUBSCRIBER_SETTLE_S` for the subscribers to match the player in turn; at most
    ``bound_s`` (with ``every_topic_s`` > 0: until every topic has a subscriber, at most that
    long; with ``min_matched`` > 0: until every topic has that many matched subscribers, at most
    ``max(bound_s, every_topic_s, MIN_MATCHED_WAIT_S)``).  Returns what it found, for the user.

    The graph fills as discovery proceeds: a node that is running is in it within about 0.3 s
    (sometimes ~3 s), so an empty graph is waited on for the whole bound.
    """
    bound = max(bound_s, every_topic_s, MIN_MATCHED_WAIT_S if min_matched > 0 else 0.0)
    deadline = time.monotonic() + bound
    while time.monotonic() < deadline:
        graph = {t: node.count_subscribers(t) for t in pubs}
        matched = {t: p.get_subscription_count() for t, p in pubs.items()}
        all_matched = all(matched[t] >= graph[t] for t in pubs)
        if min_matched > 0:
            if all(n >= min_matched for n in matched.values()) and all_matched:
                break
        elif every_topic_s > 0:
            if all(matched.values()):
                break
        elif any(graph.values()) and all_matched:
            break
        time.sleep(0.02)
    else:
        missing = [t for t, p in pubs.items() if p.get_subscription_count() == 0]
        return (f"no subscriber matched {', '.join(sorted(missing))} within {bound:g} s"
                if len(missing) < len(pubs) else f"no subscriber within {bound:g} s")
    time.sleep(SUBSCRIBER_SETTLE_S)
    n = sum(p.get_subscription_count() for p in pubs.values())
    return f"{n} subscription(s) matched"


@dataclass(frozen=True)
class PlayOptions:
    """How :func:`play` publishes a bag (``rollergear play``'s options)."""

    rate: float = 1.0  #: times real time
    loop: bool = False  #: again and again
    clock: bool = False  #: publish ``/clock`` with the bag's time
    topics: list[str] | None = None  #: only these (None: all)
    #: > 0: wait up to this long until every topic has a subscriber (a node started after the player)
    wait_for_subscribers: float = 0.0
    start_delay: float = 0.0  #: seconds to sleep before playing
    reliable: bool = True  #: reliable, keep-all publishers (else best effort)
    quiet: bool = False  #: nothing on stderr
    wait_for_graph_s: float = GRAPH_WAIT_S  #: bound on the wait for the subscribers already running (0: none)
    show_progress: bool = True  #: a progress bar (on a terminal)
    label: str | None = None  #: what the bag is called in what play prints (None: its path)
    min_subscribers: int = 0  #: > 0: wait until every topic has this many matched subscribers


def play(bag: Path, options: PlayOptions = PlayOptions()) -> PlayStats:
    """Publish the bag in log-time order at ``options.rate`` times real time.

    First waits (:func:`wait_for_graph`, at most ``wait_for_graph_s``; 0: not at all) for the
    subscribers already running to match, or with ``wait_for_subscribers`` > 0 until every topic
    has one.

    Reliable publishers keep every message until each reliable subscriber has it: a subscriber
    that keeps all (``node.input_qos: reliable``) and falls behind holds the player back
    (counted in :attr:`PlayStats.held_back`) instead of losing messages; best-effort subscribers
    never hold it back.
    """
    import rclpy
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    o = options
    info = inspect_bag(bag)
    selected = _playable(info, o.topics)
    if info.truncated:
        print(f"warning: {o.label or bag}: {info.problem}; playing what is readable", file=sys.stderr)
    if not rclpy.ok():
        rclpy.init()
    node = Node("rollergear_player")
    qos = (QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE) if o.reliable
           else QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
    pubs = {t: node.create_publisher(cls, t, qos) for t, cls in selected.items()}
    clock_pub = node.create_publisher(Clock, "/clock", 10) if o.clock else None
    stats = PlayStats()
    bar = None
    try:
        _wait_to_start(node, pubs, o)
        total = sum(info.counts.get(t, 0) for t in selected)
        if not o.quiet:
            print(f"play: publishing {total:,} messages on {len(selected)} "
                  f"topics at {o.rate:g}x{' (looping)' if o.loop else ''}", file=sys.stderr, flush=True)
        # the bar reads the count from a thread of its own: the publishing loop only counts
        bar = TimedProgress("play", None if o.loop else total, "msg", read=lambda: stats.messages,
                            enabled=not o.quiet and o.show_progress and sys.stderr.isatty()).start()
        while True:
            _play_once(bag, pubs, o.rate, clock_pub, stats)
            if not o.loop:
                break
        # every reliable subscriber has the last messages before the publishers go away (bounded);
        # best-effort ones get a moment for the delivery
        for pub in pubs.values():
            pub.wait_for_all_acked(Duration(seconds=FINAL_ACK_TIMEOUT_S))
        time.sleep(0.3)
    except KeyboardInterrupt:
        pass
    finally:
        if bar is not None:
            bar.close()
        node.destroy_node()
    if not o.quiet:
        print(f"played {o.label or bag}: {stats.text()}", file=sys.stderr)
    return stats


def _valid_topic_name(name: str) -> bool:
    """Whether rcl takes ``name`` as a fully qualified topic name (``/spam/0`` it does not)."""
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_full_topic_name import validate_full_topic_name

    try:
        return bool(validate_full_topic_name(name))
    except InvalidTopicNameException:
        return False


def _playable(info, topics: list[str] | None) -> dict:
    """Topic -> message class of the topics to play: those asked for (all: None) whose message type
    this ROS installation has; the others are named in a warning (none left: :class:`UsageError`)."""
    selected = {t: ty for t, ty in info.topics.items() if topics is None or t in topics}
    if not selected:
        raise UsageError(f"nothing to play: the bag has {info.describe_topics()}")
    invalid = sorted(t for t in selected if not _valid_topic_name(t))
    if len(invalid) == len(selected):
        raise UsageError(f"nothing to play: no topic of the bag is a valid ROS 2 topic name "
                         f"({', '.join(repr(t) for t in invalid[:5])}{' …' if len(invalid) > 5 else ''})")
    if invalid:
        print(f"warning: not played (not valid ROS 2 topic names): {', '.join(repr(t) for t in invalid)}",
              file=sys.stderr)
        selected = {t: ty for t, ty in selected.items() if t not in invalid}
    classes = {ty: _available_class(ty) for ty in set(selected.values())}
    missing = sorted(t for t, ty in selected.items() if classes[ty] is None)
    if len(missing) == len(selected):
        raise UsageError(f"nothing to play: no message type of the bag is available in this ROS installation "
                         f"({', '.join(sorted(set(selected.values())))})")
    if missing:
        print(f"warning: not played (their message types are not available in this ROS installation): "
              f"{', '.join(f'{t} ({selected[t]})' for t in missing)}", file=sys.stderr)
    return {t: classes[ty] for t, ty in selected.items() if classes[ty] is not None}


def _wait_to_start(node, pubs: dict, o: PlayOptions) -> None:
    """Wait for the subscribers (:func:`wait_for_graph`) and the start delay, as the options say."""
    if o.wait_for_subscribers > 0 or o.wait_for_graph_s > 0 or o.min_subscribers > 0:
        found = wait_for_graph(node, pubs, o.wait_for_graph_s, o.wait_for_subscribers, o.min_subscribers)
        if not o.quiet:
            print(f"play: {found}", file=sys.stderr)
    if o.start_delay > 0:
        time.sleep(o.start_delay)


def _play_once(bag: Path, pubs: dict, rate: float, clock_pub, stats: PlayStats) -> None:
    """One pass through the bag: each selected message published at its log time scaled by
    ``rate`` (and the bag's clock on ``clock_pub``), counted in ``stats``."""
    from rclpy.impl.implementation_singleton import rclpy_implementation
    from rosgraph_msgs.msg import Clock

    publish_failed = rclpy_implementation.RCLError
    late_5ms = 5_000_000
    state = ReadState()
    preload_summary(bag, state)  # channels whose records stood in a damaged chunk
    reader = _Prefetch(bag, state)
    publisher_of: dict[int, object] = {}
    t0_bag = t0_wall = None
    last_clock = None
    try:
        for log_times, channel_ids, payloads in reader:
            for t_bag, cid, data in zip(log_times.tolist(), channel_ids.tolist(), payloads):
                pub = publisher_of.get(cid)
                if pub is None:
                    channel = state.channels.get(cid)  # None: its record was lost with a damaged chunk
                    pub = publisher_of[cid] = pubs.get(channel[0], False) if channel else False
                if pub is False:
                    continue  # a topic not selected
                if t0_bag is None:
                    t0_bag, t0_wall = t_bag, time.monotonic_ns()
                target = t0_wall + int((t_bag - t0_bag) / rate)
                while True:
                    wait = target - time.monotonic_ns()
                    if wait <= 0:
                        break
                    time.sleep(wait * 1e-9 if wait > 2_000_000 else 0.0002)
                if -wait > late_5ms:
                    stats.late_over_5ms += 1
                if -wait > stats.max_late_ms * 1e6:
                    stats.max_late_ms = -wait / 1e6
                if clock_pub is not None and t_bag != last_clock:
                    c = Clock()
                    c.clock.sec, c.clock.nanosec = divmod(t_bag, 1_000_000_000)
                    clock_pub.publish(c)
                    last_clock = t_bag
                if _publish(pub, data, publish_failed, stats):
                    stats.messages += 1
    finally:
        reader.close()
        if state.damaged and not stats.damaged:  # said once (a loop reads the file again)
            stats.damaged = state.damage_report()
            info = inspect_bag(bag)
            stats.lost_share = lost_share(state.damaged, info.bytes_total, info.message_count)
            for line in stats.damaged:
                print(f"warning: {bag}: {line}", file=sys.stderr)


def _publish(pub, data: bytes, publish_failed: type, stats: PlayStats) -> bool:
    """Publish one message, waiting while a keep-all subscriber's queue is full (a failure after blocking,
    :data:`FULL_QUEUE_BLOCK_S`) for at most :data:`MAX_HELD_BACK_S`; a failure at once is a refusal of the
    bytes themselves (a damaged record's): counted, not retried.  Whether it was published."""
    import rclpy

    first = time.monotonic()
    while True:
        tried = time.monotonic()
        try:
            pub.publish(data)
            return True
        except publish_failed:
            if not rclpy.ok():
                raise
            now = time.monotonic()
            if now - tried < FULL_QUEUE_BLOCK_S or now - first > MAX_HELD_BACK_S:
                stats.refused += 1
                return False
            stats.held_back += 1


def init_for_command_line() -> None:
    """``rclpy.init`` for a command-line tool: Ctrl-C and SIGTERM raise ``KeyboardInterrupt``.

    The main thread takes it as the tool's normal end.  (rclpy's own handler shuts the context down
    under a running ``publish``, which then fails with ``RCLError: publisher's context is invalid``.)
    """
    import signal

    import rclpy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=None, signal_handler_options=SignalHandlerOptions.NO)
    # also where the shell started us with SIGINT ignored (a background job without job control)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.default_int_handler)
