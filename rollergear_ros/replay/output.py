"""Where replay's estimates go: the output MCAP (the output channels and the inputs, with the
recording's provenance), the rerun log, the exported tables, the summary's sums and the caller.
No rclpy import."""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np

from ..outputs import stamped
from ..recordings.baginfo import BagInfo
from ..recordings.bagwriter import BagWriter, offered_qos_yaml
from ..recordings.messages import TopicMap
from ..core.batchpath import BatchEstimate
from ..core.estimator import Estimator
from ..base.interface import MessageType, Metadata
from ..base.output_channels import float64_channels, stamped_channels, window_channels
from ..core.measured import WindowValue
from ..core.params import Config
from .inputs import InputBatch
from .summary import Accumulator

__all__ = ["ReplayOutputs", "output_writer", "write_outputs", "write_windows"]


class ReplayOutputs:
    """The destinations of one replay's estimates, opened by :meth:`open`, closed by :meth:`close`.

    Every batch of estimates goes to the running sums and, where asked for, to the caller's list
    (``collect``), the output MCAP, the rerun log and the exported tables.
    """

    def __init__(self, topics: TopicMap, acc: Accumulator, collect: bool) -> None:
        self.topics = topics
        self.acc = acc
        self.collected: list[BatchEstimate] = []  #: every batch, with ``collect``
        self._sink = self.collected if collect else None
        self.writer: BagWriter | None = None
        self.rlog = None  #: a :class:`outputs.review.RerunLog`
        self.tables: list = []  #: the :class:`outputs.exports.Export` tables being written
        self._skip_events = None
        self._sensors = acc.config.sensors
        self._window: WindowValue | None = None  # the measured efficiency's window published last

    def open(self, out_mcap, rrd, exports, info: BagInfo, config: Config, estimator: Estimator,
             source: str | Path | None = None) -> None:
        """Open the outputs asked for (``None`` / empty: not that one); ``source``: the user's file when
        ``info`` is its import's."""
        self.writer = output_writer(out_mcap, info, config, self.topics, source) if out_mcap else None
        if exports:
            from ..outputs.exports import Export

            self.tables = [Export(kind, path) for kind, path in exports]
        if rrd:
            from ..outputs.review import RerunLog, SkipEvents

            self.rlog = RerunLog("rollergear_replay", rrd, breakdown_terms=estimator.model.nonzero_terms(),
                                 with_effects=bool(config.effects.enabled()), replace_atomically=True)
            self._skip_events = SkipEvents()

    def emit(self, b: BatchEstimate | None) -> None:
        """Hand one batch of estimates to the writers, the summary and the caller."""
        if b is None or not len(b.t_ns):  # every sample of the batch skipped (e.g. implausible)
            return
        self.acc.add(b)
        windows = self._measured_windows(b)
        if self.acc.trace is not None:
            self.acc.trace.add(b)
        if self._sink is not None:
            self._sink.append(b)
        if self.writer:
            write_outputs(self.writer, b, self.topics)
            write_windows(self.writer, windows, self.topics)
        if self.rlog:
            self.rlog.send_estimates(b)
            self.rlog.send_windows(windows)
        for table in self.tables:
            table.add(b)

    def _measured_windows(self, b: BatchEstimate) -> list[WindowValue]:
        """The measured efficiency's windows completed by this batch (as the node publishes them, once
        per second of sample time), and each sample's window value and uncertainty in ``b``."""
        tally = self.acc.measured
        if tally.last_ns is None:
            return []
        due = tally.boundaries(None if self._window is None else self._window.end_ns // 1_000_000_000)
        windows = [tally.window_value(k, self._sensors) for k in due]
        if due:
            tally.forget(due[-1])
        by_second = {w.end_ns // 1_000_000_000: w for w in ([self._window] if self._window else []) + windows}
        second = np.asarray(b.t_ns, dtype=np.int64) // 1_000_000_000
        keys, index = np.unique(second, return_inverse=True)
        nan = WindowValue(0, np.nan, np.nan, 0, tally.window_s)
        chosen = [by_second.get(int(k), nan) for k in keys]
        b.efficiency_measured_window = np.array([w.efficiency for w in chosen])[index]
        b.efficiency_measured_uncertainty = np.array([w.uncertainty for w in chosen])[index]
        if windows:
            self._window = windows[-1]
        return [w for w in windows if np.isfinite(w.efficiency)]

    def inputs_done(self, batch: InputBatch, estimator: Estimator, release_lag_ns: int) -> None:
        """After a batch's estimates: its skips as a rerun event, its inputs into the output MCAP,
        and what can no longer be followed by an older estimate released to the file."""
        if self.rlog and len(batch.t_ns):
            self.skip_event(estimator, int(batch.t_ns.max()))
        if self.writer:
            batch.write_inputs(self.writer)
            if len(batch.t_ns):  # no later estimate can be older than its inputs' hold
                self.writer.release(int(batch.t_ns.max()) - release_lag_ns)

    def skip_event(self, estimator: Estimator, t_ns: int) -> None:
        """The samples skipped since the last event, as a warning on the rerun timeline at ``t_ns``."""
        text = self._skip_events.since_last(estimator.counts)
        if text:
            self.rlog.events([t_ns], [text], "WARN")

    def close(self, commit: bool) -> None:
        """Close every output, each one also when another failed; inside :func:`base.atomic.together`
        (replay's), in place together (``commit``), or none in place of an existing one."""
        closers = [*([lambda ok: self.writer.close(commit=ok)] if self.writer else []),
                   *([lambda ok: self.rlog.close(commit=ok)] if self.rlog else []),
                   *(lambda ok, t=table: t.close(commit_file=ok) for table in self.tables)]
        failed: BaseException | None = None
        for close in closers:
            try:
                close(commit and failed is None)
            except BaseException as exc:  # the rest are closed (and removed) before it is raised
                failed = failed or exc
        if failed is not None:
            raise failed


def output_writer(path: str | Path, info: BagInfo, config: Config, topics: TopicMap,
                  source_file: str | Path | None = None) -> BagWriter:
    """The estimates' MCAP: in log-time order, the outputs with the QoS the node offers them with,
    and its provenance (metadata ``rollergear_provenance``: package version, source recording -- the
    user's file, not a temporary import of it (``source_file``) --, parameters with the accepted
    effects, command line)."""
    import datetime

    from ..base.interface import package_version
    from ..core.params import config_to_yaml

    offered = {topics.output(c.name): offered_qos_yaml(reliable=c.reliable, depth=c.depth)
               for c in (*float64_channels(), *stamped_channels(), *window_channels())}
    writer = BagWriter(path, offered_qos=offered, background=True)
    source = Path(source_file if source_file is not None else info.path)
    writer.add_metadata(Metadata.PROVENANCE, {
        "package": "rollergear_ros", "version": package_version(),
        "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "source": str(source.resolve()),
        "source_bytes": str(source.stat().st_size if source_file is not None else info.bytes_total),
        "source_messages": str(info.message_count),
        "accepted_effects": ", ".join(config.effects.enabled()) or "none",
        "parameters": config_to_yaml(config), "command": " ".join(sys.argv)})
    return writer


def write_windows(writer: BagWriter, windows: list[WindowValue], tm: TopicMap) -> None:
    """The measured efficiency's windows on the window channels, at the second boundary each ends at."""
    if not windows:
        return
    t_ns = np.array([w.end_ns for w in windows], dtype=np.int64)
    for channel in window_channels():
        writer.write_float64_series(tm.output(channel.name), t_ns,
                                    np.array([getattr(w, channel.value) for w in windows]))


def write_outputs(writer: BagWriter, b: BatchEstimate, tm: TopicMap) -> None:
    """One batch of estimates on every output channel (:mod:`base.output_channels`), as the node publishes them."""
    for channel in float64_channels():
        t_ns, values = b.t_ns, getattr(b, channel.value)
        if channel.measured_only:  # only the samples with measured output
            measured = np.isfinite(values)
            if not measured.any():
                continue
            t_ns, values = t_ns[measured], values[measured]
        writer.write_float64_series(tm.output(channel.name), t_ns, values)
    if stamped_channels():
        values = np.column_stack(stamped.estimate_values(b))
        payloads = functools.cache(lambda: stamped.codec().payloads(b.t_ns, values))  # encoded once, by the writer
        for channel in stamped_channels():
            writer.write_fixed(tm.output(channel.name), MessageType.JOINT_STATE, b.t_ns, payloads)
