"""The node's status on ``/diagnostics``, once a second from a thread of its own.

An executor flooded with input callbacks starves its timers exactly when the report matters, so
the report is not a timer: :class:`StatusReporter` runs beside the executor, asks
:func:`~.diagnostics.diagnose` for the status (inputs, skips and alarms since the last report, load,
measured efficiency, the tracer's hint), adds the latest online trace's verdict, publishes it, and
leaves it for the recording (:meth:`~.recorder.NodeRecording.write_later`).
"""

from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.serialization import serialize_message

from ..base.interface import MessageType, Topic
from .diagnostics import STATUS_NAME, DiagnosticLimits, InputsNow, NodeLoad, SinceLast, diagnose
from .qos import INPUT_QOS

REPORT_S = 1.0  #: period of the reports


class StatusReporter:
    """Publishes the ``loss_estimator`` node's status every :data:`REPORT_S` until :meth:`stop`."""

    def __init__(self, node) -> None:
        self._node = node
        self.publisher = node.create_publisher(DiagnosticArray, Topic.DIAGNOSTICS, 10)
        self._skips_reported = dict(node.estimator.counts)
        self._alarms_reported = 0
        self._busy_reported = (time.time_ns(), node.input_path.busy_ns)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="diagnostics", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(REPORT_S):
            try:
                self.publish()
            except Exception as exc:  # noqa: BLE001 - a report that fails must not end the reports
                if self._stop.is_set() or not self._node.context.ok():
                    return
                self._node.get_logger().warn(f"diagnostics: {type(exc).__name__}: {exc}")

    def publish(self) -> None:
        """One report: diagnose, publish, and leave it for the recording."""
        node = self._node
        now = time.time_ns()
        params = node.config.node
        then, busy_then = self._busy_reported
        busy = node.input_path.busy_ns
        self._busy_reported = (now, busy)
        estimator = node.estimator
        depth = INPUT_QOS[params.input_qos].depth if params.input_qos == "sensor_data" else None
        monitor = node.input_path.monitor
        report = diagnose(InputsNow(now, monitor, monitor.rates(now)), estimator,
                          DiagnosticLimits(params.expected_rate_hz, params.min_efficiency_warn, depth,
                                           params.learn_input_rate),
                          SinceLast(self._skips_reported, self._alarms_reported),
                          NodeLoad((busy - busy_then) / max(now - then, 1), node.executor_lag_s()),
                          node.efficiency_window.latest, node.tracer.hint())
        self._skips_reported = dict(estimator.counts)
        self._alarms_reported = estimator.detector.alarms
        status = DiagnosticStatus(level=bytes([report.level]), name=f"{node.get_name()}: {STATUS_NAME}",
                                  message=report.message, hardware_id=params.hardware_id,
                                  values=[KeyValue(key=k, value=v) for k, v in report.values]
                                  + [KeyValue(key="start-up backlog discarded [messages]",
                                              value=str(node.input_path.backlog_discarded))]
                                  + self._latest_trace_values())
        traced = node.tracer.latest_status
        arr = DiagnosticArray(status=[status] if traced is None else [status, traced])
        stamp = node.get_clock().now()
        arr.header.stamp = stamp.to_msg()
        self.publisher.publish(arr)
        if node.recorder is not None:  # written by the recording's timer, which holds the input lock
            node.recording.write_later(Topic.DIAGNOSTICS, MessageType.DIAGNOSTIC_ARRAY, stamp.nanoseconds,
                                       serialize_message(arr))

    def _latest_trace_values(self) -> list[KeyValue]:
        """The latest online trace's verdict and sentence, in the node's own status (also whole as
        the ``loss/traced`` entry beside it)."""
        tracer = self._node.tracer
        latest = tracer.latest
        running = tracer.worker.running_s()
        priority = "at the lowest nice level" if tracer.worker.hurried else "at the idle priority"
        under_way = [] if running is None else [
            KeyValue(key="trace under way [s]", value=f"{running:.0f} ({priority})")]
        if latest is None:
            return [KeyValue(key="latest trace", value="none yet" if self._node.config.node.trace
                             else "tracing off")] + under_way
        return [KeyValue(key="latest trace", value=latest.message),
                KeyValue(key="latest trace verdict", value=latest.verdict),
                KeyValue(key="latest trace window [ns]", value=f"{latest.window_ns[0]}..{latest.window_ns[1]}")] \
            + under_way

    def stop(self) -> None:
        """No report after this (waits for one under way; safe from the reporting thread itself)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=10)
