"""The live node's input path: each input message to the estimator and the recording.

:class:`InputPath` subscribes the inputs (the four Float64 channels or the joint states, and the
oil temperature) and makes the callbacks that hand every message to the node's estimator -- paired
by the publishers' timestamps (``single_threaded``), by arrival (``events``), or by their times on
the sequence clock (``node.sample_clock: sequence``: :mod:`core.seqclock`, handed on in that clock's
time order) -- and to its recording, at the very times the estimator paired them by, so that replay
of the recording pairs them as the node did.  Over best effort, a gap in a publisher's sequence numbers becomes
placeholders (:meth:`InputPath._push_lost`), and the messages queued before the node first takes
from its subscriptions are judged as a whole (:meth:`InputPath.take_start_up_backlog`).

It reads the node's ``estimator``, ``recorder`` and ``config`` at each message (a parameter change
replaces the estimator; closing ends the recording) and hands each estimate to the node's
``publish_estimate``.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from typing import Any

from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64
from rclpy.serialization import serialize_message

from ..base.interface import MessageType, Topic
from ..core.pairing import ARRIVAL_PAIRINGS, OIL_TEMPERATURE, OUT_SPEED, OUT_TORQUE, SPEED, TORQUE
from ..core.lostmarks import LOST_VALUE, SequenceGaps
from ..core.seqclock import ClockMerge, SequenceClock
from ..recordings.messages import CDR_LE_HEADER, TopicMap, decode_float64, float64_problem
from .diagnostics import InputMonitor
from .intake import InputTaker
from .qos import INPUT_QOS

__all__ = ["MAX_PLACEHOLDERS", "InputPath"]

#: a gap in a publisher's sequence numbers longer than this is not filled with placeholders message
#: by message (a node frozen for minutes): the pairing restarts as for a new stream instead
MAX_PLACEHOLDERS = 100_000
_LOST_RAW = struct.Struct("<4sd").pack(CDR_LE_HEADER, LOST_VALUE)


class InputPath:
    """The node's input subscriptions and what each message does (see the module docstring).

    ``lock`` is the node's input lock: the input thread (events executor) holds it while it hands
    messages over, and a parameter change takes it too.  ``record_pairing_time``: Float64 inputs
    are recorded at the time they were paired by (else at the node's clock)."""

    def __init__(self, node, lock: threading.Lock, pairing: str, record_pairing_time: bool) -> None:
        self._node = node
        self._lock = lock
        self.pairing = pairing
        self.record_pairing_time = record_pairing_time
        self.monitor = InputMonitor(time.time_ns())  #: counts, rates and losses by channel (/diagnostics)
        self.busy_ns = 0  #: time spent in input callbacks (saturation: /diagnostics)
        #: log time of the last input recorded (the sample boundary a parameter change applies at)
        self.log_ns = 0
        #: while the start-up backlog is taken: where the input callbacks hold what they are given
        self._backlog: list[tuple[str, Any, bytes, dict]] | None = None
        self.backlog_discarded = 0  #: input messages queued before the first take, discarded
        self.backlog_kept = 0  #: ... and estimated (the start of their publishers' streams)
        # the events executor gives no message info: the inputs are taken in a thread of their own
        self.taker = InputTaker(node, lock) if node.config.node.executor == "events" else None
        self._sequence_gaps = {c: SequenceGaps() for c in Topic.OF_CHANNEL}
        self._last_input_ns: dict[str, int] = {}
        self._handles: dict[str, Any] = {}  # input thread's subscriptions, by channel
        self._interleaved_warned = False
        #: (when, how long the message taken then had waited since the middleware received it)
        self.lag = (0, 0)
        #: ``node.sample_clock: sequence`` (Float64 inputs only: the parameters refuse it for joint states):
        #: the inputs' times from their publishers' numbers
        params = node.config.node
        self.clock = SequenceClock(1.0 / params.expected_rate_hz) if params.sample_clock == "sequence" else None
        self.monitor.sample_clock = self.clock
        #: ... whose messages are handed on in the clock's time order (one topic's backlog may come first)
        self._merge = ClockMerge() if self.clock is not None else None

    # ------------------------------------------------------------------ subscriptions
    def subscribe(self) -> None:
        """The input subscriptions: the four Float64 channels or the joint states, and the oil temperature."""
        node = self._node
        params = node.config.node
        qos = INPUT_QOS[params.input_qos]
        if params.input_mode == "float64":
            for channel, rel in Topic.OF_CHANNEL.items():
                self._handles[channel] = self._subscribe(
                    Float64, rel, self._float_callback(channel, node.resolve_topic_name(rel)), qos, raw=True)
        else:
            self._subscribe(JointState, TopicMap().joint_states, lambda msg, _info=None: self._joint_state(msg), qos)
        self._subscribe(Temperature, Topic.OIL_TEMPERATURE, lambda msg, _info=None: self._temperature(msg), qos)

    def _subscribe(self, msg_type, topic: str, callback, qos, raw: bool = False):
        """One subscription: ``callback(message, info)``, on the input thread (events executor;
        returns its handle) or on the executor."""
        if self.taker is not None:
            return self.taker.subscribe(msg_type, topic, qos, callback, raw=raw)
        return self._node.create_subscription(msg_type, topic, callback, qos, raw=raw)

    def start(self) -> int:
        """Take the start-up backlog (:meth:`take_start_up_backlog`), then start the input thread
        (events executor); returns how many messages were discarded.

        Under sim time the inputs are stamped with the ROS clock, which the executor sets from
        ``/clock``: the thread takes nothing, the backlog included, before that has happened (the
        inputs wait in the middleware's queues meanwhile), and this returns at once."""
        if self.taker is None:
            return 0
        node = self._node
        if node.get_parameter("use_sim_time").value:
            self.taker.start(ready=lambda: node.get_clock().now().nanoseconds > 0, first=self.take_start_up_backlog)
            return 0
        discarded = self.take_start_up_backlog()
        self.taker.start()
        return discarded

    def take_start_up_backlog(self) -> int:
        """Take the Float64 inputs queued before the node first takes from its subscriptions
        (arrival pairing only): estimate them when they are the start of their publishers' streams,
        else discard them.  Returns how many were discarded.

        A node that joins a running stream finds up to a queue's depth of messages waiting, its
        subscriptions having matched a few samples apart; taken in one burst, their arrival order
        says nothing about which torque belongs to which speed, so they are discarded and live
        messages pair by their arrival.  But a stream that began after the node subscribed -- a
        player started as soon as the node's subscriptions matched it, while the node was still
        starting up -- queues the same way and is no backlog to lose: the publishers' sequence
        numbers tell the two apart.  When every input topic's first queued message is its
        publisher's first (number 1), each topic is there from the first sample on and first-in
        first-out pairs them.  Publisher timestamps (``single_threaded``) and JointState header
        stamps pair any backlog exactly, so it is kept there (and nothing is taken here).
        """
        if self.pairing not in ARRIVAL_PAIRINGS or self._node.config.node.input_mode != "float64":
            return 0
        log = self._node.get_logger()
        held: list[tuple[str, Any, bytes, dict]] = []
        with self._lock:
            self._backlog = held
            try:
                idle = 0
                while idle < 3:  # a few empty takes in a row: the queues are drained
                    before = len(held)
                    self.taker.take_round_robin()  # the callbacks hold what they are given
                    idle = idle + 1 if len(held) == before else 0
            finally:
                self._backlog = None
            first: dict[str, int | None] = {}
            for channel, _, _, info in held:
                first.setdefault(channel, info.get("publication_sequence_number"))
            if held and all(n == 1 for n in first.values()):
                self.backlog_kept = len(held)
                for _, callback, raw, info in held:
                    callback(raw, info)
                log.info(f"took {len(held)} input messages queued at start-up: every topic from its publisher's "
                         "first message on (a stream that started with the node)")
                return 0
            for channel, _, _, info in held:  # the next live message after them is no loss
                self._sequence_gaps[channel].lost_before(info.get("publication_sequence_number"))
            self.backlog_discarded += len(held)
        if self.backlog_discarded:
            log.info(f"discarded {self.backlog_discarded} input messages queued before start-up "
                     "(a running stream: their arrival order cannot pair them)")
        return self.backlog_discarded

    def stop(self) -> None:
        """No input is taken after this (the input thread finishes the round it is in)."""
        if self.taker is not None:
            self.taker.stop()

    def destroy(self) -> None:
        """Stop the input thread and release its subscriptions (before the node is destroyed)."""
        if self.taker is not None:
            self.taker.destroy()

    @property
    def error(self) -> BaseException | None:
        """What ended the input thread, if a callback raised (the main thread re-raises it)."""
        return self.taker.error if self.taker is not None else None

    def waited_s(self, now_ns: int) -> float:
        """How long the last message taken in the past second had waited since the middleware
        received it (input thread; 0 otherwise)."""
        taken_ns, waited_ns = self.lag
        return waited_ns * 1e-9 if now_ns - taken_ns < 1_000_000_000 else 0.0

    # ------------------------------------------------------------------ callbacks
    def _float_callback(self, channel: str, topic: str):
        """The hot path: one Float64 message (raw CDR bytes) -> estimator -> outputs.

        Paired by the publisher's timestamp (``single_threaded``) or by arrival (``events``; the
        messages the middleware lost, told by the gaps in the publisher's sequence numbers, are
        pushed as placeholders in their place: :meth:`_push_lost`)."""
        node = self._node
        counts, last = self.monitor.counts, self.monitor.last_ns
        clock = self.clock
        unpack = struct.Struct("<d").unpack_from
        time_ns = time.time_ns
        record_pairing_time = self.record_pairing_time

        def take(raw: bytes, t_ns: int, source_ns: int | None = None) -> list:
            """Record the message and push it to the estimator: the estimates it completes."""
            recorder = node.recorder
            if recorder is not None:
                log_ns = self.log_ns = t_ns if record_pairing_time else node.get_clock().now().nanoseconds
                recorder.write_raw(topic, MessageType.FLOAT64, log_ns, raw, publish_time_ns=source_ns)
            if len(raw) >= 12 and raw[1] == 1 and raw[0] == 0:
                value = unpack(raw, 4)[0]
            elif float64_problem(raw) is None:
                value = float(decode_float64([raw])[0])
            else:  # not a Float64 payload: counted (diagnostics warn), never decoded as garbage
                node.estimator.counts["malformed"] += 1
                return []
            return node.estimator.push(channel, t_ns, value, source_ns)

        def handle(raw: bytes, t_ns: int, wall_ns: int, source_ns: int | None = None) -> None:
            counts[channel] += 1
            last[channel] = wall_ns
            for est in take(raw, t_ns, source_ns):
                node.publish_estimate(est)

        if self.pairing not in ARRIVAL_PAIRINGS:
            merge = self._merge

            def cb_timestamp(raw: bytes, info) -> None:
                wall = time_ns()
                t_ns = info["source_timestamp"] or wall
                if clock is None:
                    handle(raw, t_ns, wall)
                else:  # the slot of its publisher's number, handed on in the clock's time order
                    counts[channel] += 1
                    last[channel] = wall
                    reference_ns, t_ns = t_ns, clock.time_ns(channel, info.get("publication_sequence_number"), t_ns)
                    self.monitor.lost[channel] += clock.gap
                    for held in merge.push(channel, t_ns, reference_ns, (take, raw, t_ns)):
                        for est in held[0](*held[1:]):
                            node.publish_estimate(est)
                self.busy_ns += time_ns() - wall
            return cb_timestamp

        lost_before = self._sequence_gaps[channel].lost_before
        last_input = self._last_input_ns

        def cb_arrival(raw: bytes, info) -> None:
            if self._backlog is not None:  # queued before start-up: held until the backlog is judged
                self._backlog.append((channel, cb_arrival, raw, info))
                return
            wall = t_ns = time_ns()
            self.lag = (wall, wall - (info["received_timestamp"] or wall))
            lost = lost_before(info["publication_sequence_number"])
            if lost:
                t_ns = self._push_lost(channel, topic, lost, wall)
            last_input[channel] = t_ns
            handle(raw, t_ns, wall, info["source_timestamp"] or None)
            self.busy_ns += time_ns() - wall
        return cb_arrival

    def release_held(self) -> list:
        """The inputs the sequence clock still holds for a topic behind (the node stops): recorded and
        pushed to the estimator in time order; returns the estimates they complete, to be published."""
        if self._merge is None:
            return []
        return [est for take, *args in self._merge.drain() for est in take(*args)]

    def _push_lost(self, channel: str, topic: str, lost: int, t_ns: int) -> int:
        """``lost`` messages of ``channel`` were lost just before the one taken at ``t_ns``: push
        (and record) a placeholder for each (:data:`~core.pairing.LOST_VALUE`), 1 ns
        apart just before it, so that first-in first-out pairing stays aligned.  Returns the time
        for the message itself (moved on by at most ``lost`` ns where the channel's previous message
        leaves no room: the times on a topic must grow for replay to keep this order)."""
        node = self._node
        handle = self._handles.get(channel)
        if handle is not None and handle.get_publisher_count() > 1:
            # two publishers' numbers interleave: a gap between them is no loss
            if not self._interleaved_warned:
                self._interleaved_warned = True
                node.get_logger().warn(f"{topic} has {handle.get_publisher_count()} publishers: messages "
                                       "lost in delivery cannot be told (one publisher per input topic)")
            return t_ns
        self.monitor.lost[channel] += lost
        if lost > MAX_PLACEHOLDERS:
            node.estimator.sync.restart()
            return t_ns
        t_ns = max(t_ns, self._last_input_ns.get(channel, t_ns) + lost + 1)
        for t_i in range(t_ns - lost, t_ns):
            recorder = node.recorder
            if recorder is not None:
                log_ns = self.log_ns = t_i if self.record_pairing_time else node.get_clock().now().nanoseconds
                recorder.write_raw(topic, MessageType.FLOAT64, log_ns, _LOST_RAW)
            for est in node.estimator.push(channel, t_i, LOST_VALUE):
                node.publish_estimate(est)
        return t_ns

    def _joint_state(self, msg: JointState) -> None:
        """One JointState: the input joint's effort and velocity, and the output joint's, paired by
        the header stamp; recorded whole."""
        node = self._node
        wall = time.time_ns()
        t_ns = (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec) or wall
        names = list(msg.name)
        params = node.config.node
        if node.recorder is not None:
            log_ns = self.log_ns = node.get_clock().now().nanoseconds
            node.recorder.write_raw(Topic.JOINT_STATES, MessageType.JOINT_STATE, log_ns, serialize_message(msg))
        for joint, ch_t, ch_w in ((params.input_joint, TORQUE, SPEED), (params.output_joint, OUT_TORQUE, OUT_SPEED)):
            if joint in names:
                k = names.index(joint)
                effort = msg.effort[k] if k < len(msg.effort) else float("nan")
                velocity = msg.velocity[k] if k < len(msg.velocity) else float("nan")
                self.monitor.record(ch_t, wall)
                self.monitor.record(ch_w, wall)
                for channel, value in ((ch_t, effort), (ch_w, velocity)):
                    for est in node.estimator.push(channel, t_ns, float(value)):
                        node.publish_estimate(est)
        self.busy_ns += time.time_ns() - wall

    def _temperature(self, msg: Temperature) -> None:
        """One oil temperature: to the estimator (on the inputs' clock) and the live map's oil."""
        node = self._node
        wall = time.time_ns()
        self.monitor.record(OIL_TEMPERATURE, wall)
        # on the sequence clock, the time of the latest input taken: it holds from the samples after it
        on_clock = self.clock.latest_ns() if self.clock is not None else None
        if node.recorder is not None:
            node.recorder.write_raw(node.resolve_topic_name(Topic.OIL_TEMPERATURE), MessageType.TEMPERATURE,
                                    (on_clock or wall) if self.record_pairing_time
                                    else node.get_clock().now().nanoseconds, serialize_message(msg))
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        # the stamp keeps the temperature on the inputs' clock in JointState mode (header stamps)
        t_ns = stamp if (stamp and node.config.node.input_mode == "joint_state") else (on_clock or wall)
        node.estimator.push(OIL_TEMPERATURE, t_ns, float(msg.temperature))
        if math.isfinite(msg.temperature):
            node.live_map.oil_temperature_c = float(msg.temperature)
