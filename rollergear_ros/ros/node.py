"""``loss_estimator``: the live node, an rclpy shell over :class:`~core.estimator.Estimator`.

The node wires topics, parameters and timers to its parts and publishes each estimate on the
output channels (:mod:`base.output_channels`: loss torque, loss power, efficiency, the residual when
the output is measured, the stamped estimate).  The parts: the input path (:mod:`.inputpath`: the
subscriptions, whose callbacks hand every message to the estimator and the recording, and the
input thread of the events executor, :mod:`.intake`), the recordings (:mod:`.recorder`: MCAP and
rerun, rolled by size and age), the status on ``/diagnostics`` (:mod:`.reporter`, from a thread of
its own), the measured efficiency's windows (:mod:`.efficiencywindow`), the live loss map
(:mod:`.livemaps`) and the online tracer (:mod:`.tracer`).  Parameters are the package's one
parameter set (``config/gearbox.yaml``), declared with descriptors; run-time changes go through
:func:`core.params.validate` and are refused with its reason.

Run: ``loss_estimator --ros-args --params-file config/gearbox.yaml`` (or ``ros2 run rollergear_ros
loss_estimator …``).
"""

from __future__ import annotations

import gc
import itertools
import struct
import sys
import threading
import time
from operator import attrgetter
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from ..recordings.messages import CDR_LE_HEADER, TopicMap
from ..recordings.rolling import free_name
from ..core.estimator import Estimate, Estimator
from ..base.errors import ParameterError, RollergearError
from .inputpath import InputPath
from .livemaps import LiveMapPublisher
from ..sources.paths import Output, check_outputs
from ..outputs.stamped import EstimateCodec, estimate_values
from ..base.interface import NAMESPACE, MessageType, Topic
from .nodehelp import help_text, wants_help
from ..base.output_channels import (OUTPUT_CHANNELS, float64_channels, map_channels, stamped_channels, trace_channels,
                                    window_channels)
from ..core.params import Config
from .parameters import (check_params_files, declare_parameters, package_parameter_names, parameter_event, params_files)
from .qos import output_qos
from .recorder import NodeRecording, check_recording_names
from .reporter import StatusReporter
from .spin import make_executor, stop_on_signals
from .efficiencywindow import CHECK_S as EFFICIENCY_CHECK_S
from .efficiencywindow import LiveEfficiencyWindow
from .tracer import CHECK_S, LiveTracer

#: message class of each output channel's type (:mod:`base.output_channels`)
_MESSAGE_CLASSES = {MessageType.FLOAT64: Float64, MessageType.JOINT_STATE: JointState,
                    MessageType.FLOAT64_MULTI_ARRAY: Float64MultiArray, MessageType.DIAGNOSTIC_STATUS: DiagnosticStatus}


MAP_CHECK_S = 1.0  #: how often the adapted coefficients are compared with those of the last map
_PACK = struct.Struct("<4sd").pack
HEARTBEAT_S = 0.1  #: period of the executor heartbeat timer (executor lag in /diagnostics)
_CDR = CDR_LE_HEADER


def _raw_publish(publisher):
    """``publisher.publish`` for serialized messages, without rclpy's per-call type check and
    destruction guard (half of its cost per call; four calls per sample).  Safe here: the node's
    publishers are destroyed only with the node, after the executor has stopped."""
    return getattr(publisher.handle, "publish_raw", None) or publisher.publish


class LossEstimatorNode(Node):
    """The ``loss_estimator`` node (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("namespace", NAMESPACE)
        super().__init__("loss_estimator", **kwargs)
        self.config: Config = declare_parameters(self)  # ParameterError: refused with the reason
        # the single-threaded executor gives publisher timestamps; the events executor keeps arrival order
        node = self.config.node
        if node.executor == "single_threaded" or node.sample_clock == "sequence":
            # the publisher timestamps, or the sequence clock's times: paired by time, as replay pairs a bag
            self.pairing = "timestamp"
        else:  # a reliable, keep-all input loses nothing; over best effort the publishers'
            # sequence numbers tell what was lost (filled in with placeholders: :mod:`.inputpath`)
            self.pairing = "arrival_reliable" if node.input_qos == "reliable" else "arrival_sequenced"
        self.estimator = Estimator(self.config, self.pairing, 1.0 / self.config.node.expected_rate_hz)
        self._package_parameters = package_parameter_names()
        self.parameter_changes = 0  #: accepted run-time changes
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._published = 0
        self._every = self.config.node.publish_every_n
        self.executor_kind = node.executor
        # the events executor's input thread delivers under this lock, which a parameter change takes too
        self.input_lock = threading.Lock()
        self._closed = False
        # Float64 inputs are recorded at the very times the estimator paired them by (publisher
        # timestamps, or arrival times), so that replay of the recording pairs them as the node did
        # (``rollergear_recording`` metadata); under sim time the recording keeps one clock: ROS time
        record_pairing_time = node.input_mode == "float64" and not self.get_parameter("use_sim_time").value
        #: the input subscriptions and what each message does (:mod:`.inputpath`)
        self.input_path = InputPath(self, self.input_lock, self.pairing, record_pairing_time)
        self._create_outputs()
        # the live loss map (transient-local: an energy manager that starts later gets the last one)
        self.live_map = LiveMapPublisher(self._map_publishers, self.get_fully_qualified_name(), self.get_logger())
        self.params_file_paths = {Path(p).resolve() for p in params_files(sys.argv)}
        self._open_recordings()
        # the online tracer: its buffer is filled on the input path, its timer starts traces in a worker
        self.tracer = LiveTracer(self, self.config, self._trace_publishers)
        buffer = self.tracer.buffer  # also the measured efficiency's
        self._trace_time, self._trace_values = buffer.add_time, buffer.add_values
        if node.trace:
            self.create_timer(CHECK_S, self.tracer.check)
        self.efficiency_window = LiveEfficiencyWindow(self, {
            c.name: (_raw_publish(self.output_publishers[c.name]), self.out_topics[c.name])
            for c in window_channels() if c.name in self.output_publishers})
        self.create_timer(EFFICIENCY_CHECK_S, self.efficiency_window.update)
        self.input_path.subscribe()
        # executor lag: a heartbeat timer queued behind the input events fires as late as they are
        # taken (single_threaded; the events node's input thread measures how long inputs waited)
        self._heartbeat_ns = time.time_ns()
        self.create_timer(HEARTBEAT_S, self._heartbeat)
        if self._map_publishers or node.map_file:
            self.create_timer(MAP_CHECK_S, self._update_map)
        self.status = StatusReporter(self)  # /diagnostics, from a thread of its own
        self.get_logger().info(
            f"estimating from {'Float64 topics' if node.input_mode == 'float64' else TopicMap().joint_states}; "
            f"effects: {', '.join(self.config.effects.enabled()) or 'none'}; executor: {self.executor_kind}; "
            f"input QoS: {node.input_qos}"
            + (f"; recording {node.record_mcap}" if self.recorder else ""))

    def _open_recordings(self) -> None:
        """Check every output file before any is opened, publish the first loss map, and open the
        recordings the parameters ask for (:class:`~.recorder.NodeRecording`)."""
        node = self.config.node
        # every output is checked before any is opened: a refused one leaves no half-written file
        check_recording_names(self.config)
        # the files rewritten during the run: an existing file is never replaced, the next free name is taken
        self.live_map.path = self._free_output("node.map_file", node.map_file)
        self.traced_params_path = self._free_output("node.traced_params_file", node.traced_params_path()) \
            if node.trace else None
        check_outputs(sorted(self.params_file_paths),  # of their kinds, apart, none a parameter file
                      [Output("node.record_mcap", node.record_mcap or None, "mcap"),
                       Output("node.rerun_rrd", node.rerun_rrd or None, "rrd"),
                       Output("node.map_file", self.live_map.path, "vtlm"),
                       Output("node.traced_params_file", self.traced_params_path, "yaml")])
        if self._map_publishers or node.map_file:
            self._update_map()  # before the inputs are subscribed: nothing waits for it
        self.recording = NodeRecording(self, self.config, self.out_topics, self.input_lock, self.pairing,
                                       self.input_path.record_pairing_time, lambda: self.estimator)
        #: the MCAP recorder the input and output paths write into (None: not recording)
        self.recorder = self.recording.mcap
        self._rerun_estimates = self.recording.estimates
        self._record_map()  # the first map, published before the recorder opened

    def _record_map(self) -> None:
        """The live map last published, into the recording (``loss/map``)."""
        topic = self.out_topics.get(next((c.name for c in map_channels()), ""), "")
        self.recording.record_map(self.live_map.last_message, topic)

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params if p.name in self._package_parameters}
        if not changes:
            return SetParametersResult(successful=True)
        with self.input_lock:  # never between two messages of one sample's push
            return self._change_parameters(changes)

    def _change_parameters(self, changes: dict[str, Any]) -> SetParametersResult:
        try:
            if self.input_path.clock is not None and "node.expected_rate_hz" in changes:
                raise ParameterError("node.expected_rate_hz", changes["node.expected_rate_hz"],
                                     "it is the sequence sample clock's rate (node.sample_clock: sequence), read "
                                     "at start")
            new = self.config.with_values(changes)
        except ParameterError as exc:
            self.get_logger().warn(f"refused: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        old = self.estimator
        self.config = new
        self._every = new.node.publish_every_n
        self.estimator = Estimator(new, self.pairing, 1.0 / new.node.expected_rate_hz)
        self.estimator.take_over_inputs(old)
        self.live_map.renew()  # the next map check publishes the new parameters' map
        self.parameter_changes += 1
        if self.recorder is not None:  # as it happens: a killed node's recording keeps it
            # logged now; stamped with the sample boundary the change applies at, where replay applies it
            self.recorder.write_message(Topic.PARAMETER_EVENTS, MessageType.PARAMETER_EVENT,
                                        self.get_clock().now().nanoseconds,
                                        parameter_event(self.get_fully_qualified_name(), self.input_boundary_ns(),
                                                        changes))
        self.get_logger().info(f"parameters changed: {', '.join(f'{k}={v}' for k, v in changes.items())}")
        return SetParametersResult(successful=True)

    def input_boundary_ns(self) -> int:
        """The log time of the last input message the recording holds (0: none yet): a change made
        now applies after it, where replay, which takes the inputs in log-time order, applies it
        (:mod:`replay.switches`)."""
        return self.input_path.log_ns

    @property
    def rerun(self):
        """The rerun log (None: none), for the tracer's and the efficiency window's events."""
        return self.recording.rerun

    # ------------------------------------------------------------------ outputs
    def _update_map(self) -> None:
        """The map timer: a new loss map when the adapted coefficients moved (:class:`LiveMapPublisher`),
        published and recorded."""
        made = self.live_map.published
        self.live_map.update(self.config, self.estimator)
        if self.live_map.published > made and getattr(self, "recording", None) is not None:
            self._record_map()

    @property
    def maps_published(self) -> int:
        """Loss maps made so far."""
        return self.live_map.published

    def _create_outputs(self) -> None:
        """A publisher for each output channel the parameters switch on (:mod:`base.output_channels`:
        ``node.publish_float64``, ``node.publish_stamped``, ``node.publish_map``), and the per-sample
        publishing plan."""
        node = self.config.node
        #: output channel -> its resolved topic, for the channels published
        self.out_topics: dict[str, str] = {}
        self.output_publishers: dict[str, Any] = {}
        for channel in OUTPUT_CHANNELS.values():
            if channel.per == "map":
                published = node.publish_map
            elif channel.per == "trace":
                published = node.trace
            else:
                published = node.publish_stamped if channel.stamped else node.publish_float64
            if published:
                self.out_topics[channel.name] = self.resolve_topic_name(channel.topic)
                self.output_publishers[channel.name] = self.create_publisher(
                    _MESSAGE_CLASSES[channel.message_type], channel.topic, output_qos(channel, node.output_depth))
        # (value of the estimate, raw publish, topic, published only with measured output), per channel
        self._float64_plan = tuple(
            (attrgetter(c.value), _raw_publish(self.output_publishers[c.name]), self.out_topics[c.name],
             c.measured_only) for c in float64_channels() if c.name in self.out_topics)
        self._stamped_plan = tuple((_raw_publish(self.output_publishers[c.name]), self.out_topics[c.name])
                                   for c in stamped_channels() if c.name in self.out_topics)
        self._stamped = EstimateCodec() if self._stamped_plan else None
        #: the loss map's publishers (one message per map, not per estimate)
        self._map_publishers = tuple(self.output_publishers[c.name] for c in map_channels()
                                     if c.name in self.output_publishers)
        #: the online trace's publishers, and the topic its results are recorded on
        self._trace_publishers = tuple(self.output_publishers[c.name] for c in trace_channels()
                                       if c.name in self.output_publishers)
        self.traced_topic = next((self.out_topics[c.name] for c in trace_channels() if c.name in self.out_topics), "")

    def publish_estimate(self, est: Estimate, send: bool = True) -> None:
        """Publish one estimate (``send=False``: record it only) and buffer its inputs for rerun and the
        online tracer (every sample, with a measured output or not: a trace steps an effect's memory
        over each, as ``calibrate`` does over the recording)."""
        self._trace_time(est.t_ns)
        self._trace_values((est.torque_nm, est.speed_rad_s, est.out_torque_nm, est.out_speed_rad_s,
                            est.temperature_c, est.measured_loss_nm))
        self._published += 1
        if self._every > 1 and self._published % self._every:
            return
        recorder = self.recorder
        stamp = self.get_clock().now().nanoseconds if recorder is not None else 0
        for value_of, publish, topic, measured_only in self._float64_plan:
            value = value_of(est)
            if measured_only and value != value:  # NaN: no measured output
                continue
            raw = _PACK(_CDR, value)
            if send:
                publish(raw)
            if recorder is not None:
                recorder.write_raw(topic, MessageType.FLOAT64, stamp, raw)
        if self._stamped is not None:
            raw = self._stamped.encode(est.t_ns, estimate_values(est))
            for publish, topic in self._stamped_plan:
                if send:
                    publish(raw)
                if recorder is not None:
                    recorder.write_raw(topic, MessageType.JOINT_STATE, stamp, raw)
        if self._rerun_estimates is not None:
            self._rerun_estimates.append(est)

    def _heartbeat(self) -> None:
        self._heartbeat_ns = time.time_ns()

    def executor_lag_s(self) -> float:
        """How far the node is behind: the heartbeat's age beyond its period, or (input thread) how
        long the last message taken in the past second had waited since the middleware received it."""
        now = time.time_ns()
        return max(0.0, (now - self._heartbeat_ns) * 1e-9 - HEARTBEAT_S, self.input_path.waited_s(now))

    # ------------------------------------------------------------------ shutdown
    def destroy_node(self) -> None:
        """Stop the input and diagnostics threads before their subscriptions and publisher go away,
        then destroy the node."""
        self.input_path.destroy()
        self.status.stop()
        super().destroy_node()

    def _finish_pending(self) -> None:
        """Samples paired but still held for a measured output (and inputs the sequence clock held) when
        the node stops: estimated as replay estimates them at the end of a recording, so that replay of
        the recording gives exactly what the node published; sent while the middleware still runs,
        recorded either way."""
        send = self.context.ok()
        try:  # inputs the sequence clock held, before the estimator's last
            held = self.input_path.release_held()
        except Exception as exc:  # noqa: BLE001 - nothing may keep close() from closing the files
            self.get_logger().warn(f"the inputs held in time order at shutdown were not all recorded: {exc}")
            held = []
        for est in itertools.chain(held, self.estimator.finish()):
            try:
                self.publish_estimate(est, send)
                continue
            except Exception as exc:  # noqa: BLE001 - nothing may keep close() from closing the files
                self._published -= 1
                problem = exc
            if send:  # the context went down meanwhile (a second signal): record this one and the rest
                send = False
                try:
                    self.publish_estimate(est, False)
                    continue
                except Exception as exc:  # noqa: BLE001
                    self._published -= 1
                    problem = exc
            self.get_logger().warn(f"the samples held for an output at shutdown were not recorded: {problem}")
            return

    def close(self) -> None:
        """Flush and close the recordings, the MCAP first (safe to call twice), then log one summary
        line.  A rerun viewer that cannot be reached costs its data, with a warning, never the MCAP
        or a traceback."""
        self.input_path.stop()  # no input is taken after this
        self.status.stop()
        if self._closed:
            return
        self._closed = True
        self.tracer.close()
        self._finish_pending()
        self.recorder = None
        self.recording.close()
        self.get_logger().info(self.summary_line())

    def _free_output(self, name: str, path: str) -> Path | None:
        """The file the node rewrites for ``name`` (None: off): ``path``, or the next free name beside
        it when a file is there (said in the log)."""
        if not path:
            return None
        free = free_name(Path(path))
        if free != Path(path):
            self.get_logger().warn(f"{name}: {path} exists and is left as it is; writing {free}")
        return free

    def summary_line(self) -> str:
        """What the run did, in one line: samples estimated of those received, skips by reason,
        change alarms, parameter changes, loss maps and the files written."""
        est = self.estimator
        skips = ", ".join(f"{reason.replace('_', ' ')} {n}" for reason, n in est.counts.items() if n) or "none"
        files = [str(p) for p in self.recording.files] + [str(p) for p in self.recording.rerun_files]
        files += [str(self.live_map.path)] if self.live_map.path and self.maps_published else []
        files += [self.tracer.proposed] if self.tracer.proposed else []
        return (f"stopped: {est.estimated:,} samples estimated of {est.motor_messages:,} received; skipped: {skips}; "
                f"change alarms: {est.detector.alarms}; traces: {self.tracer.traces} (effects traced in "
                f"{self.tracer.traced}, taken in {self.tracer.taken_in}); "
                f"parameter changes: {self.parameter_changes}; "
                f"loss maps: {self.maps_published}; wrote: {', '.join(files) or 'no file'}")



def main(args: list[str] | None = None) -> int:
    """Entry point of ``loss_estimator``: spin until Ctrl-C/SIGTERM, then close the files cleanly."""
    from rclpy.impl.implementation_singleton import rclpy_implementation
    from rclpy.signals import SignalHandlerOptions

    if wants_help(sys.argv[1:] if args is None else list(args)):
        sys.stdout.write(help_text())
        return 0
    stop = stop_on_signals()
    try:
        check_params_files(sys.argv if args is None else args)
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except (ParameterError, rclpy_implementation.RCLError) as exc:
        # rcl's own message ends with its source locations: not the user's business
        print(f"loss_estimator: error: {str(exc).split(', at /')[0].strip()}", file=sys.stderr)
        return 2
    node = None
    code = 0
    try:
        # the modules loaded so far live as long as the process: keep them out of the garbage
        # collector's full passes, which otherwise stall the callbacks for milliseconds at high
        # input rates (collected before the node subscribes: the inputs wait for no collection)
        gc.collect()
        gc.freeze()
        node = LossEstimatorNode()
        executor = make_executor(node.executor_kind)
        executor.add_node(node)
        gc.freeze()  # and the node's own objects (no collection: it would delay the first take)
        node.input_path.start()
        # spin_once with a timeout: EventsExecutor.spin() never returns on this rclpy version
        while rclpy.ok() and not stop.is_set():
            if node.input_path.error is not None:
                raise node.input_path.error
            try:
                executor.spin_once(timeout_sec=0.1)
            except RuntimeError:
                # the context was shut down (from outside) under an executor busy with a backlog:
                # the EventsExecutor then fails to hand it a callback's argument; that is the end
                if rclpy.ok():
                    raise
                break
    except RollergearError as exc:  # a parameter, an output file refused at start-up
        print(f"loss_estimator: error: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
