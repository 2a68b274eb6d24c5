"""The node's recordings: the MCAP files (``node.record_mcap``) and the rerun log (``node.rerun_rrd``,
``node.rerun_connect``), started anew by size and age (``node.record_max_mb``, ``node.record_max_s``).

:class:`NodeRecording` is what the node sees of them: the MCAP recorder the input and output paths
write into as messages come (:attr:`NodeRecording.mcap`, written under the node's input lock), a queue
for what other threads have for it (:meth:`~NodeRecording.write_later`: ``/diagnostics``), the live
loss map (:meth:`~NodeRecording.record_map`), the estimates buffered for rerun and sent by a timer
(:attr:`~NodeRecording.estimates`), and :meth:`~NodeRecording.close`.  A kill keeps what came: the
MCAP is written in place, durable (:mod:`recordings.rolling`).
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.serialization import serialize_message

from ..base.errors import ParameterError
from ..base.interface import MessageType, Metadata
from ..base.output_channels import OUTPUT_CHANNELS, map_channels, trace_channels
from ..core.pairing import ARRIVAL_PAIRINGS
from ..recordings.bagwriter import BagWriter, offered_qos_yaml
from ..recordings.rolling import RollingRecorder, is_template, next_file, roll_due, splits, template_problem
from .parameters import check_new_output, live_provenance

ROLL_CHECK_S = 1.0  #: how often the recordings are looked at (size, age) and queued messages written
RERUN_FLUSH_S = 0.5  #: how often the buffered estimates go to rerun


def first_file(path: str, split: bool) -> Path:
    """The first file a recording named ``path`` writes, as start-up checks it: with a field in the
    name or split, the next free name (never an existing file); a plain name as it is (refused when
    it exists: :func:`~.parameters.check_new_output`)."""
    if is_template(path) or split:
        return next_file(path, time.time_ns(), 0, split)
    return Path(path)


def check_recording_names(config) -> None:
    """Refuse (:class:`ParameterError`) a recording name that is no usable template or whose first
    file exists -- before any output is opened."""
    node = config.node
    split = splits(int(node.record_max_mb * 1e6), node.record_max_s)
    for name, path, suffix in (("node.record_mcap", node.record_mcap, ".mcap"),
                               ("node.rerun_rrd", node.rerun_rrd, ".rrd")):
        if path:
            problem = template_problem(path, suffix)
            if problem:
                raise ParameterError(name, path, problem)
            check_new_output(name, str(first_file(path, split)))


class NodeRecording:
    """The MCAP recorder and the rerun log of one ``loss_estimator`` run (see the module docstring).

    ``out_topics``: the output channels published, by name (their offered QoS is recorded);
    ``pairing`` and ``record_pairing_time``: how the inputs are paired and whether they are recorded at
    their pairing times (the ``rollergear_recording`` metadata replay pairs by); ``estimator``: the
    node's current estimator, asked when estimates go to rerun (their breakdown is its model's)."""

    def __init__(self, node: Node, config, out_topics: dict[str, str], lock, pairing: str,
                 record_pairing_time: bool, estimator: Callable[[], Any]) -> None:
        self._node = node
        self._config = config
        self._lock = lock
        self._estimator = estimator
        self.mcap: RollingRecorder | None = None
        self.files: list[Path] = []  #: the MCAP files of the run, in order
        self.rerun = None
        self.rerun_files: list[Path] = []  #: the .rrd files of the run, in order
        #: the estimates since the last flush to rerun (None: no rerun log)
        self.estimates: list | None = None
        self._queue: deque[tuple[str, str, int, bytes]] = deque()
        params = config.node
        if params.record_mcap:
            self.mcap = self._open_mcap(out_topics, pairing, record_pairing_time)
            self.files = self.mcap.files
        if params.rerun_rrd or params.rerun_connect:
            from ..outputs.review import SkipEvents

            self.rerun = self._open_rerun()
            self.estimates = []
            self._skips = SkipEvents()
            node.create_timer(RERUN_FLUSH_S, self.flush_rerun)
        if self.mcap is not None or self.rerun_files:
            node.create_timer(ROLL_CHECK_S, self.roll)

    def _open_mcap(self, out_topics: dict[str, str], pairing: str, record_pairing_time: bool) -> RollingRecorder:
        """The MCAP recorder: written as the messages come (in arrival order), in place (a kill keeps what
        came), with the QoS the outputs are offered with and the latched outputs repeated in each file."""
        params = self._config.node
        offered = {out_topics[c.name]: offered_qos_yaml(c.reliable, c.offered_depth(params.output_depth),
                                                        c.transient_local)
                   for c in OUTPUT_CHANNELS.values() if c.name in out_topics}

        def open_file(path: Path) -> BagWriter:
            return BagWriter(path, chunk_size=256 * 1024, time_ordered=False, offered_qos=offered,
                             replace_atomically=False, durable=True)

        latched = tuple(out_topics[c.name] for c in (*map_channels(), *trace_channels()) if c.name in out_topics)
        name = self._node.get_fully_qualified_name()
        recording = {
            "recorded_by": name, "executor": params.executor,
            "pairing": pairing if record_pairing_time else "timestamp",
            "input_log_time": ("sequence_clock" if params.sample_clock == "sequence"
                               else "arrival" if pairing in ARRIVAL_PAIRINGS else "source_timestamp")
            if record_pairing_time else "receive",
            "sample_period_s": repr(1.0 / params.expected_rate_hz)}
        provenance = live_provenance(name, self._config, sys.argv)
        return RollingRecorder(params.record_mcap, open_file, time.time_ns, int(params.record_max_mb * 1e6),
                               params.record_max_s, latched,
                               ((Metadata.RECORDING, recording), (Metadata.PROVENANCE, provenance)))

    def _open_rerun(self):
        """The rerun log: to the next ``.rrd`` file of the run (and/or the viewer)."""
        from ..outputs.review import RerunLog

        params = self._config.node
        path = None
        if params.rerun_rrd:
            split = splits(int(params.record_max_mb * 1e6), params.record_max_s)
            path = next_file(params.rerun_rrd, time.time_ns(), len(self.rerun_files), split)
            self.rerun_files.append(path)
            self._rerun_opened_ns = time.time_ns()
        estimator = self._estimator()
        return RerunLog("rollergear_live", path, params.rerun_connect or None,
                        breakdown_terms=estimator.model.nonzero_terms(),
                        with_effects=bool(self._config.effects.enabled()))

    def write_later(self, topic: str, type_name: str, log_time_ns: int, raw: bytes) -> None:
        """A message from a thread other than the executor's: written by the next :meth:`roll`."""
        if self.mcap is not None:
            self._queue.append((topic, type_name, log_time_ns, raw))

    def _write_queued(self) -> None:
        while self._queue:
            self.mcap.write_raw(*self._queue.popleft())

    def record_map(self, msg, topic: str) -> None:
        """A loss map just published, into the recording."""
        if self.mcap is not None and msg is not None and topic:
            with self._lock:
                self.mcap.write_raw(topic, MessageType.FLOAT64_MULTI_ARRAY, time.time_ns(), serialize_message(msg))

    def roll(self) -> None:
        """The timer: write what other threads left for the recording, and start the next MCAP and
        ``.rrd`` file when the current one has reached ``node.record_max_mb`` or ``node.record_max_s``."""
        params = self._config.node
        logger = self._node.get_logger()
        if self.mcap is not None:
            with self._lock:
                self._write_queued()
                closed = self.mcap.roll_if_due()
            if closed is not None:
                logger.info(f"recording: {closed} complete; now {self.mcap.path}")
        if self.rerun is not None and self.rerun_files:
            path = self.rerun_files[-1]
            size = path.stat().st_size if path.exists() else 0
            if roll_due(size, time.time_ns() - self._rerun_opened_ns, int(params.record_max_mb * 1e6),
                        int(params.record_max_s * 1e9)):
                self.flush_rerun()
                old, self.rerun = self.rerun, self._open_rerun()
                try:
                    old.close()
                except Exception as exc:  # noqa: BLE001 - a viewer that went away costs its data, not the node
                    logger.warn(f"rerun logging incomplete: {exc}")

    def flush_rerun(self) -> None:
        """The estimates since the last flush to rerun, with the samples skipped meanwhile as an event."""
        if not self.estimates or self.rerun is None:
            return
        import numpy as np

        from ..core.batchpath import BatchEstimate

        with self._lock:
            buf = list(self.estimates)
            self.estimates.clear()
            estimator = self._estimator()  # the breakdown is the current model's (a parameter change makes another)
            skipped = self._skips.since_last(estimator.counts)
            alarms = list(estimator.detector.alarm_times_ns)

        def column(name: str) -> np.ndarray:
            return np.array([getattr(e, name) for e in buf], dtype=np.float64)

        t = np.array([e.t_ns for e in buf], dtype=np.int64)
        torque, speed, temperature, loss = (column("torque_nm"), column("speed_rad_s"), column("temperature_c"),
                                            column("loss_torque_nm"))
        breakdown, effects = estimator.breakdown(torque, speed, temperature, loss, column("sign"))  # off the input path
        self.rerun.send_estimates(BatchEstimate(
            t, torque, speed, loss, column("loss_power_w"), column("efficiency"), column("measured_loss_nm"),
            column("residual_nm"), temperature, breakdown_nm=breakdown, effects_nm=effects, alarms_t_ns=alarms,
            out_torque_nm=column("out_torque_nm"), out_speed_rad_s=column("out_speed_rad_s"),
            efficiency_measured=column("efficiency_measured")))
        if skipped:
            self.rerun.events([int(t[-1])], [skipped], "WARN")

    def close(self) -> None:
        """Close the MCAP first (what is queued written), then the rerun log.  A rerun viewer that cannot
        be reached costs its data, with a warning, never the MCAP or a traceback.  Safe to call twice."""
        if self.mcap is not None:
            self._write_queued()
            self.mcap.close()
            self.mcap = None
        if self.rerun is not None:
            try:
                self.flush_rerun()
                self.rerun.close()
            except Exception as exc:  # noqa: BLE001 - rerun raises RuntimeError when its gRPC sink never connected
                self._node.get_logger().warn(f"rerun logging incomplete: {exc}")
            finally:
                self.rerun = None
