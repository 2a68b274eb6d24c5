"""The node's measured efficiency over a rolling window, once a second (rclpy).

Every estimate's inputs and measured loss are kept in the online tracer's buffer
(:class:`~calibration.tracing.TraceBuffer`, appended on the input path); a timer on the executor
takes the samples with a measured loss added since its last look (as replay's window takes them)
into a :class:`~core.measured.MeasuredEfficiency` and, for each whole second of sample time
completed since, publishes the energy-weighted efficiency of the last ``node.efficiency_window_s``
and its uncertainty (the window channels of
:mod:`base.output_channels`), records them in the node's MCAP and keeps the latest for
``/diagnostics``.  Replay computes the same windows of the same samples (:mod:`replay.output`): a
replay of the node's recording writes the values the node published.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from ..base.interface import MessageType
from ..base.output_channels import window_channels
from ..core.measured import MeasuredEfficiency, WindowValue
from ..recordings.messages import CDR_LE_HEADER

__all__ = ["CHECK_S", "LiveEfficiencyWindow"]

CHECK_S = 1.0  #: how often the timer looks at the buffer
_PACK = struct.Struct("<4sd").pack


class LiveEfficiencyWindow:
    """Publishes the measured efficiency's window channels (see the module docstring).

    ``node``: the :class:`~.node.LossEstimatorNode` (its buffer, input lock, config, recorder and
    clock); ``publishers``: channel name -> (raw publish, topic) of the window channels published."""

    def __init__(self, node, publishers: dict[str, tuple]) -> None:
        self.node = node
        self.publishers = publishers
        config = node.config
        self.tally = MeasuredEfficiency(config.gearbox.ratio_effective, node.estimator.sample_period_s or 1e-3,
                                        config.node.efficiency_window_s)
        self.latest: WindowValue | None = None  #: the last window published (``/diagnostics``)
        self.published = 0  #: windows published
        self._seen_ns: int | None = None  # the last buffered sample taken
        self._boundary_s: int | None = None  # the last second boundary published

    def update(self) -> None:
        """The timer: take the new samples, publish each second completed since the last look."""
        node = self.node
        buffer = node.tracer.buffer
        with node.input_lock:  # the buffer is appended under it
            fresh = buffer.since(self._seen_ns)
            if not node.config.node.trace:  # the tracer trims it otherwise
                buffer.trim()
        if len(fresh["t_ns"]) == 0:
            return
        self._seen_ns = int(fresh["t_ns"][-1])
        # the samples with a measured loss, as replay's window takes them (replay.summary)
        out = np.where(np.isfinite(fresh["measured_loss_nm"]), fresh["out_torque_nm"], np.nan)
        self.tally.add(fresh["t_ns"], fresh["torque_nm"], fresh["speed_rad_s"], out, fresh["out_speed_rad_s"])
        due = self.tally.boundaries(self._boundary_s)
        sensors = node.config.sensors
        windows = [self.tally.window_value(k, sensors) for k in due[-60:]]  # a stalled timer: the last minute
        windows = [w for w in windows if math.isfinite(w.efficiency)]  # NaN: nothing supplied in the window
        for value in windows:
            self._publish(value)
        if windows and node.rerun is not None:
            try:
                node.rerun.send_windows(windows)
            except Exception as exc:  # noqa: BLE001 - a viewer that went away costs its data, not the node
                node.get_logger().warn(f"rerun: {exc}")
        if len(due):
            self._boundary_s = due[-1]
            self.tally.forget(due[-1])

    def _publish(self, value: WindowValue) -> None:
        self.latest = value
        self.published += 1
        recorder = self.node.recorder
        stamp = self.node.get_clock().now().nanoseconds if recorder is not None else 0
        for channel in window_channels():
            if channel.name not in self.publishers:
                continue
            publish, topic = self.publishers[channel.name]
            raw = _PACK(CDR_LE_HEADER, getattr(value, channel.value))
            publish(raw)
            if recorder is not None:
                with self.node.input_lock:  # the recorder is written under it
                    recorder.write_raw(topic, MessageType.FLOAT64, stamp, raw)
