"""The node's online tracer: when to trace, and where a result goes.

:class:`LiveTracer` keeps the inputs of the node's recent estimates, with a measured output or not
(:class:`~calibration.tracing.TraceBuffer`, appended on the input path), and from a timer on the
executor: hands a snapshot to the worker process after a new change alarm -- once
``node.trace_min_after_s`` of samples have come after it, and again each ``node.trace_min_after_s``
later while the result is inconclusive and the buffer still holds the change point (the latest
``node.trace_window_s`` after it analysed) -- and every ``node.trace_period_s``; and
takes a finished result out: published latched on ``loss/traced`` (a row of
:mod:`base.output_channels`), recorded in the node's MCAP on that topic, sent to rerun as an event,
logged, kept for ``/diagnostics``; with ``node.accept_traced: propose`` (or ``on``) its candidate
parameter file written atomically (never the file the node was started with), and with ``on`` its
parameters taken in as a run-time parameter change (recorded with its sample boundary, where replay
applies it: :mod:`replay.switches`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from ..base.atomic import write_text
from ..base.interface import MessageType
from ..calibration.traceworker import IDLE_PRIORITY_S, TraceWorker
from ..calibration.tracing import TraceBuffer, TraceRequest, TraceResult
from ..core.params import Config

__all__ = ["LiveTracer", "status_of"]

CHECK_S = 0.5  #: how often the timer looks for a result and for a trace to start
BUFFER_SPAN = 2.5  #: the buffer holds this many windows at node.expected_rate_hz


def status_of(result: TraceResult, name: str, hardware_id: str) -> DiagnosticStatus:
    """A trace result as one ``diagnostic_msgs/DiagnosticStatus`` (WARN when an effect was traced)."""
    level = DiagnosticStatus.WARN if result.verdict == "traced" else DiagnosticStatus.OK
    return DiagnosticStatus(level=level, name=name, message=result.message, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in result.key_values()])


def status_dict(status: DiagnosticStatus) -> dict:
    """``status`` as the message dict the MCAP recorder's encoder takes."""
    return {"level": int.from_bytes(status.level, "little") if isinstance(status.level, bytes) else int(status.level),
            "name": status.name, "message": status.message, "hardware_id": status.hardware_id,
            "values": [{"key": kv.key, "value": kv.value} for kv in status.values]}


class LiveTracer:
    """Schedules traces of the node's samples and delivers their results (see the module docstring).

    ``node``: the :class:`~.node.LossEstimatorNode` (its estimator, recorder, rerun log, logger,
    input lock and clock); ``publishers``: the trace channel's."""

    def __init__(self, node, config: Config, publishers: tuple) -> None:
        self.node = node
        self.publishers = publishers
        params = config.node
        self.buffer = TraceBuffer(int(BUFFER_SPAN * params.trace_window_s * params.expected_rate_hz))
        self.worker = TraceWorker()
        if params.trace:  # now, before the inputs: starting a process costs the interpreter milliseconds
            self.worker.start()
        self.name = f"{node.get_name()}: traced"
        self.latest: TraceResult | None = None  #: the last result (``/diagnostics``)
        self.latest_status: DiagnosticStatus | None = None
        self.traces = 0  #: results delivered
        self.traced = 0  #: ... that named an effect
        self.proposed: str | None = None  #: the candidate parameter file written last
        self.taken_in = 0  #: traced effects applied to the running estimator (``node.accept_traced: on``)
        self._detector = node.estimator.detector
        self._alarms_seen = 0
        #: the alarm to trace and the sample time it waits for (an inconclusive trace waits for more)
        self._pending: tuple[int, int] | None = None
        self._next_period = time.monotonic() + params.trace_period_s if params.trace_period_s > 0 else None

    def check(self) -> None:
        """The timer: deliver a finished trace, start a due one; a failure here is a warning, never
        the end of the estimation."""
        try:
            self._check()
        except Exception as exc:  # noqa: BLE001 - the tracer is an aside to the estimates
            self.node.get_logger().warn(f"online tracer: {type(exc).__name__}: {exc}")

    def _check(self) -> None:
        done = self.worker.result()
        if done is not None:
            self._deliver(done)
        elif (hurried := self.worker.hurry_if_late()) is not None:
            self.node.get_logger().info(f"online trace under way for {IDLE_PRIORITY_S:g} s at the idle priority "
                                        f"(the cores are busy): {hurried}")
        config = self.node.config
        detector = self.node.estimator.detector
        if detector is not self._detector:  # a parameter change made a new estimator: its alarms count anew
            self._detector, self._alarms_seen = detector, 0
        params = config.node
        if detector.alarms > self._alarms_seen:  # the latest alarm is the one to trace
            self._alarms_seen = detector.alarms
            if detector.alarm_times_ns:
                alarm = detector.alarm_times_ns[-1]
                self._pending = (alarm, alarm + int(params.trace_min_after_s * 1e9))
        with self.node.input_lock:
            self.buffer.trim()
        last_ns = self.buffer.last_ns()
        if self.worker.busy or last_ns is None:
            return
        if self._pending is not None and last_ns >= self._pending[1]:
            self._start("alarm", *self._pending)
            self._pending = None
        elif self._next_period is not None and time.monotonic() >= self._next_period:
            self._next_period = time.monotonic() + params.trace_period_s
            self._start("period", None, None)

    def hint(self) -> str:
        """Where the trace of the residual's alarm is, for the status: ``see loss/traced`` once a trace
        exists or is under way; when one will start; '' with tracing off."""
        if not self.node.config.node.trace:
            return ""
        if self.latest is not None or self.worker.busy:
            return "see loss/traced" if self.latest is not None else "a trace is under way: see loss/traced"
        last_ns = self.buffer.last_ns()
        if self._pending is not None and last_ns is not None:
            wait_s = max(self._pending[1] - last_ns, 0) * 1e-9
            return f"traced on loss/traced once {wait_s:.0f} s more samples have come"
        return "traced on loss/traced once samples have come after the alarm"

    def _start(self, reason: str, alarm_ns: int | None, end_ns: int | None) -> None:
        with self.node.input_lock:  # a memory copy: milliseconds
            samples = self.buffer.snapshot()
        if reason == "period" and not np.isfinite(samples["out_torque_nm"]).any():
            return  # no measured output to trace (an alarm's trace says what it lacks)
        config = self.node.config
        self.worker.submit(TraceRequest(samples, config.to_flat(), reason, alarm_ns,
                                        config.node.trace_window_s, config.node.trace_min_after_s, end_ns,
                                        tuple(self.node.estimator.speed_noise.learned)))

    def _deliver(self, done: TraceResult | Exception) -> None:
        node = self.node
        logger = node.get_logger()
        if isinstance(done, Exception):
            logger.warn(f"online trace failed: {type(done).__name__}: {done}")
            return
        self.traces += 1
        params = node.config.node
        if done.reason == "alarm" and done.verdict == "inconclusive" and self._pending is None and done.since_ns:
            # traced again with more samples (the window after the change grows, then slides on) for as
            # long as the buffer holds the change point: what tells two effects apart may come later
            first = self.buffer.first_ns()
            if first is not None and first < done.since_ns:
                self._pending = (done.alarm_ns, done.window_ns[1] + int(params.trace_min_after_s * 1e9))
                done.notes.append(f"traced again when {params.trace_min_after_s:g} s more samples have come")
        if done.verdict == "traced":
            self.traced += 1
            if params.accept_traced in ("propose", "on") and done.candidate_yaml is not None:
                done.message += f"; {self._propose(done)}"
            if params.accept_traced == "on" and done.candidate_changes:
                done.message += f"; {self._take_in(done)}"
        status = status_of(done, self.name, params.hardware_id)
        self.latest, self.latest_status = done, status
        for publisher in self.publishers:
            publisher.publish(status)
        if node.recorder is not None:
            with node.input_lock:
                node.recorder.write_message(node.traced_topic, MessageType.DIAGNOSTIC_STATUS,
                                            node.get_clock().now().nanoseconds, status_dict(status))
        if node.rerun is not None and done.since_ns is not None:
            node.rerun.events([done.since_ns], [f"traced ({done.reason}): {done.message}"],
                              "WARN" if done.verdict == "traced" else "INFO")
        if done.verdict == "traced":  # (an rclpy logger call site keeps one severity)
            logger.warn(f"trace ({done.reason}): {done.message}")
        else:
            logger.info(f"trace ({done.reason}): {done.message}")

    def _propose(self, done: TraceResult) -> str:
        """Write the candidate parameter file; the sentence that says so (or why not)."""
        path = self.node.traced_params_path
        if path is None or Path(path).resolve() in self.node.params_file_paths:
            return f"candidate not written: {path} is a parameter file the node was started with"
        try:
            write_text(path, done.candidate_yaml)
        except OSError as exc:
            return f"candidate not written: {path}: {exc.strerror or exc}"
        self.proposed = str(path)
        return f"candidate written: {path}" + ("" if self.node.config.node.accept_traced == "on" else " (not in use)")

    def _take_in(self, done: TraceResult) -> str:
        """Apply the candidate's parameters to the running node as a run-time parameter change (the
        parameter service's own path: validated, recorded on ``/parameter_events`` with its sample
        boundary, the estimator and the live loss map renewed); the sentence that says so."""
        from rclpy.parameter import Parameter

        node = self.node
        result = node.set_parameters_atomically([Parameter(k, value=v) for k, v in done.candidate_changes.items()])
        if not result.successful:
            return f"not taken in: {result.reason}"
        self.taken_in += 1
        return f"taken in after the input logged at {node.input_boundary_ns()} ns"

    def close(self) -> None:
        self.worker.close()
