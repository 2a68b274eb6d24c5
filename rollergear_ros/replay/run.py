"""Offline replay: a recorded bag through the same estimator the node runs.

Reads any ROS 2 MCAP with the input topics (Float64 channels or a JointState topic), pairs and
estimates with :class:`~core.estimator.Estimator`, writes an output MCAP (inputs +
``interface.md`` outputs) and a rerun recording, and summarises.  Everything is written in
batches, so an interrupt (Ctrl-C, SIGTERM) leaves valid files holding all processed samples.
No rclpy import.

The rooms: :mod:`.inputs` (which topics, decoding, batching), :mod:`.window` (a
time slice), :mod:`.output` (where the estimates go), :mod:`.summary` (the sums and
the summary), :mod:`base.stopping` (signals between batches); this module runs them in order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable, Iterator, Sequence

from ..base.text import printable
from ..recordings.baginfo import BagInfo, inspect_bag, read_metadata
from ..recordings.messages import TopicMap
from ..base import atomic
from ..base.errors import UsageError
from ..base.interface import Metadata
from ..core.batchpath import BatchEstimate
from ..core.estimator import Estimator
from ..core.operating_points import rows_config
from ..core.params import Config
from ..base.progress import TimedProgress
from .inputs import InputBatch, InputProblems, damaged_share, input_batches, paired_plan
from .output import ReplayOutputs
from .skew import ChannelSpans
from .switches import ParameterSwitch, apply_switch, recorded_switches, split_at
from .summary import Accumulator, ReplaySummary
from .window import MEMORY_LEAD_NS, TimeWindow
from ..base.stopping import GracefulStop

__all__ = ["GracefulStop", "ReplayRequest", "ReplaySummary", "replay"]


@dataclass(frozen=True)
class ReplayRequest:
    """What :func:`replay` is asked to do (its arguments, documented there)."""

    bag: str | Path
    config: Config
    topics: TopicMap = TopicMap()
    out_mcap: str | Path | None = None
    rrd: str | Path | None = None
    show_progress: bool | None = None
    batch_size: int = 100_000
    warn: Callable[[str], None] | None = None
    collect: bool = False
    window_ns: tuple[int | None, int | None] | None = None
    summary_png: str | Path | None = None
    exports: Sequence[tuple[str, str | Path]] = ()
    parameter_changes: bool = True
    source: str | Path | None = None

    @property
    def label(self) -> str:
        """The recording as the user named it (an imported file's, not its temporary MCAP's)."""
        return str(self.source if self.source is not None else self.bag)


def replay(
    bag: str | Path,
    config: Config,
    topics: TopicMap = TopicMap(),
    *,
    out_mcap: str | Path | None = None,
    rrd: str | Path | None = None,
    show_progress: bool | None = None,
    batch_size: int = 100_000,
    warn: Callable[[str], None] | None = None,
    collect: bool = False,
    window_ns: tuple[int | None, int | None] | None = None,
    summary_png: str | Path | None = None,
    exports: Sequence[tuple[str, str | Path]] = (),
    parameter_changes: bool = True,
    source: str | Path | None = None,
) -> tuple[ReplaySummary, list[BatchEstimate]]:
    """Replay ``bag`` through the estimator; returns the summary (and all estimates if ``collect``).

    The options after ``topics`` are keywords, the fields of the :class:`ReplayRequest` they make.

    ``summary_png``: draw the summary picture there (:mod:`.plot`), also of an interrupted
    replay (what was processed).  ``exports``: ``(kind, path)`` tables of the estimates with their
    inputs, a row per sample (:mod:`outputs.exports`: ``csv``, ``parquet``, ``mf4``).

    ``window_ns``: a time slice ``[start, end)`` of the recording (``None``: open): only its samples
    are estimated and summed up, so that the slices of a long recording, replayed apart, add up to
    it (:class:`~.window.TimeWindow`).  Not with outputs (``out_mcap``, ``rrd``).

    ``parameter_changes``: apply the run-time parameter changes a live recording holds where the node
    applied them (:mod:`.switches`); off for an analysis that wants ``config`` throughout (calibration's
    bare model).

    ``source``: the file the user gave when ``bag`` is its import (a CSV's temporary MCAP): what the
    summary, the picture and the outputs' provenance name.
    """
    if window_ns is not None and (out_mcap or rrd or summary_png or exports):
        raise UsageError("a time slice of a recording is replayed without outputs")
    request = ReplayRequest(bag, config, topics, out_mcap, rrd, show_progress, batch_size, warn, collect, window_ns,
                            summary_png, exports, parameter_changes, source)
    stop = GracefulStop()  # first: from here on a signal leaves complete files
    try:
        with atomic.together():  # the outputs replace their files together, or none does
            return _replay(request, stop)
    finally:
        stop.restore()


def _replay(req: ReplayRequest, stop: GracefulStop) -> tuple[ReplaySummary, list[BatchEstimate]]:
    warnings: list[str] = []

    def _warn(msg: str) -> None:
        warnings.append(msg)
        if req.warn:
            req.warn(msg)

    info = inspect_bag(req.bag)
    _warn_unindexed(info, _warn)
    plan, pairing, period_s = paired_plan(info, req.topics)
    rows = table_rows(info)  # a table's rows: each an operating point, as calibrate estimates them
    estimator = Estimator(rows_config(req.config) if rows else req.config, pairing=pairing, sample_period_s=period_s,
                          operating_points=rows)
    # the node's run-time parameter changes, where it applied them
    switches = recorded_switches(info) if req.parameter_changes else []
    problems = InputProblems(estimator.counts, plan)
    window = None if req.window_ns is None else _time_window(req.window_ns, estimator)
    if window is not None and estimator.speed_noise.learning and window.start_ns is not None:
        _learn_speed_noise(estimator, info, plan, req.batch_size)
    summary = ReplaySummary(
        req.label, sync_tolerance_s=estimator.sync_tolerance_s, sample_period_s=period_s, pairing=pairing
    )
    acc = Accumulator(req.config, estimator.sample_period_s)
    if req.summary_png:
        from .plot import SummaryTrace

        acc.trace = SummaryTrace(info.counts.get(plan.joint_states or req.topics.motor_torque, 0))
    outputs = ReplayOutputs(req.topics, acc, req.collect)
    bar = None
    spans = ChannelSpans()
    completed = False  # an error (not an interrupt) leaves no output in place of an existing one
    try:
        with stop.critical():  # outputs are opened whole
            outputs.open(req.out_mcap, req.rrd, req.exports, info, req.config, estimator, req.source)
        total = sum(info.counts.get(t, 0) for t in plan.all_topics)
        bar = TimedProgress("replay", total, "msg", enabled=req.show_progress).start()
        batches = input_batches(info, plan, req.batch_size, _warn, problems, window.read_range() if window else None)
        run = _Pass(estimator, outputs, window, summary, stop, switches, spans)
        try:
            _estimate(batches, run, bar)
        finally:
            estimator = run.estimator  # the last one: after the recorded parameter changes
        completed = True
    except KeyboardInterrupt:
        summary.interrupted = completed = True  # what was processed so far is a whole output
    finally:
        with stop.critical(raise_after=False):  # outputs are closed whole, whatever comes
            if bar:
                bar.close()
            outputs.close(commit=completed)
    # the share of the recording its damage cost; nothing readable at all: no output replaces a file
    summary.lost_share = damaged_share(info, problems, nothing_read=summary.input_messages == 0
                                       and not summary.interrupted)
    if stop.requested and not summary.interrupted:  # the whole recording was read: the outputs are whole
        _warn("a stop signal came after the whole recording was processed: every output is complete")
    _count(summary, estimator, window, acc, _warn, spans)
    summary.warnings = warnings
    if acc.trace is not None and acc.n and stop.requested:  # asked to stop: the files, not a picture
        _warn(f"interrupted: no summary picture {req.summary_png}")
    elif acc.trace is not None and acc.n:
        from .plot import plot_summary

        try:  # a picture of what was processed; an interrupt while it is drawn abandons it
            summary.summary_png = str(plot_summary(acc.trace, req.config, req.summary_png,
                                                   f"replay of {Path(req.label).name}"))
        except KeyboardInterrupt:
            _warn(f"interrupted: no summary picture {req.summary_png}")
    return summary, outputs.collected


def table_rows(info: BagInfo) -> bool:
    """Whether the recording is a steady-state table's import (``import`` says so in its metadata): one
    operating point per sample, each estimated on its own (:func:`~core.operating_points.rows_config`)."""
    return imported_table(info.path) is not None


def imported_table(path: str | Path) -> dict[str, str] | None:
    """The ``import`` metadata of an MCAP that ``import`` made of a steady-state table (one sample per
    row); None for any other file (a recording, a CSV, a file that is not there)."""
    record = read_metadata(path, Metadata.IMPORT) if Path(path).is_file() else None
    return record if record and record.get(Metadata.IMPORT_ROWS) == "true" else None


def _warn_unindexed(info: BagInfo, warn: Callable[[str], None]) -> None:
    """A recording without its index: read linearly, and how much of it could not be read."""
    if info.truncated or not info.indexed:
        lost = info.bytes_total - info.bytes_readable
        warn(
            f"{info.path} has no index (summary/footer): a recording cut short? Readable: "
            f"{info.message_count:,} messages; {lost:,} trailing bytes ({100 * lost / max(info.bytes_total, 1):.1f} %) "
            "could not be read"
            if info.truncated
            else f"{info.path} has no index; read linearly"
        )


def _learn_speed_noise(estimator: Estimator, info: BagInfo, plan, batch_size: int) -> None:
    """A time slice's estimator takes the speed noise (``auto``) as a replay of the whole recording
    does: learned from the recording's first samples (through an estimator of their own), applied from
    each checkpoint's time on -- so that the slices of a recording add up to its replay."""
    first = Estimator(estimator.config, pairing=estimator.pairing, sample_period_s=estimator.sample_period_s)
    for batch in input_batches(info, plan, batch_size, lambda text: None, InputProblems(first.counts, plan)):
        first.push_many(batch.codes, batch.t_ns, batch.values, batch.source_ns)
        if not first.speed_noise.learning:
            break
    else:
        first.flush()
    estimator.follow_speed_noise(first)


def _time_window(window_ns: tuple[int | None, int | None], estimator: Estimator) -> TimeWindow:
    """The slice with a lead-in and -out twice the longest the estimator holds anything."""
    sync = estimator.sync
    lead_ns = 2 * max(sync.hold_ns, sync.temperature_hold_ns)
    if estimator.has_memory:  # an effect with memory: its state settles in the lead-in's motion
        lead_ns = max(lead_ns, MEMORY_LEAD_NS)
    return TimeWindow(*window_ns, lead_ns=lead_ns)


@dataclass
class _Pass:
    """One pass of a replay through its inputs: the estimator (replaced at each recorded parameter
    change), where its estimates go, the time slice (None: the whole recording), the summary, the
    signal guard and the recorded parameter changes still to come."""

    estimator: Estimator
    outputs: ReplayOutputs
    window: TimeWindow | None
    summary: ReplaySummary
    stop: GracefulStop
    switches: list[ParameterSwitch]
    spans: ChannelSpans  #: each channel's first and last stamp (a whole recording; none of a time slice)

    def push(self, codes, t_ns, values, source_ns, log_ns=None) -> Iterator[BatchEstimate]:
        """The inputs through the estimator; at a recorded parameter change within them, the
        estimates before it, then those of the estimator after it.  The change's boundary is a log
        time: ``log_ns`` gives each input's where it is not its sample time (a JointState's stamp)."""
        clock = t_ns if log_ns is None else log_ns
        while self.switches and len(clock) and clock[-1] > self.switches[0].at_ns:
            switch = self.switches.pop(0)
            k = split_at(clock, switch.at_ns)
            if k:
                yield self.estimator.push_many(codes[:k], t_ns[:k], values[:k],
                                               None if source_ns is None else source_ns[:k])
                codes, t_ns, values, clock = codes[k:], t_ns[k:], values[k:], clock[k:]
                source_ns = None if source_ns is None else source_ns[k:]
            self.estimator = apply_switch(self.estimator, switch)
            self.summary.parameter_changes.append(
                f"{', '.join(f'{k}={v}' for k, v in switch.changes.items())} after {switch.at_ns} ns")
        if len(t_ns):
            yield self.estimator.push_many(codes, t_ns, values, source_ns)


def _estimate(batches: Iterator[InputBatch], run: _Pass, bar: TimedProgress) -> None:
    """Every batch of inputs through the estimator, its estimates to the outputs (a signal stops
    between batches: ``summary.interrupted``)."""
    outputs, window, summary, stop = run.outputs, run.window, run.summary, run.stop
    release_lag_ns = 2 * max(run.estimator.sync.hold_ns, run.estimator.sync.tolerance_ns)  # output held back
    acc = outputs.acc
    for batch in batches:
        if stop.requested:
            summary.interrupted = True
            break
        if window is not None:  # a time slice (no outputs): its lead-in, its samples, its lead-out
            for codes, t, v, source in window.split(batch, run.estimator):
                for estimates in run.push(codes, t, v, source):
                    outputs.emit(window.keep(estimates, acc))
        else:
            with stop.critical():  # one batch's estimates and inputs, both or neither
                summary.input_messages += batch.message_count
                run.spans.add(batch.codes, batch.t_ns)
                for estimates in run.push(batch.codes, batch.t_ns, batch.values, batch.source_ns,
                                          batch.event_log_ns):
                    outputs.emit(estimates)
                outputs.inputs_done(batch, run.estimator, release_lag_ns)
        bar.update(len(batch.codes))
        if window is not None and window.done:
            break
    else:
        with stop.critical():
            estimator = run.estimator
            outputs.emit(window.keep(estimator.flush(), acc) if window else estimator.flush())
            if outputs.rlog and acc.last_t is not None:
                outputs.skip_event(estimator, acc.last_t)


def _count(summary: ReplaySummary, estimator: Estimator, window: TimeWindow | None, acc: Accumulator,
           warn: Callable[[str], None], spans: ChannelSpans) -> None:
    """The estimator's counts and the sums in ``summary``; a warning when many samples of a channel went
    unpaired, or a channel's stream is shifted against the drive torque's (``spans``: the streams' ends,
    taken of a whole recording only)."""
    summary.samples = estimator.motor_messages
    summary.estimated = estimator.estimated
    summary.skipped = dict(estimator.counts)
    detector = estimator.detector
    summary.alarms = detector.alarms
    summary.alarm_times_ns, summary.alarm_from_start = list(detector.alarm_times_ns), list(detector.alarm_from_start)
    if window is not None:
        window.finish(summary, estimator, acc)
    sync = estimator.sync
    unpaired = {c: n for c, n in sync.unpaired.items() if n > 0.05 * max(sync.received[c], 1)}
    if unpaired:
        counts = ", ".join(f"{c.replace('_', ' ')} {n:,} of {sync.received[c]:,}" for c, n in unpaired.items())
        warn(
            f"input messages without a partner within the pairing tolerance of {1e3 * estimator.sync_tolerance_s:.2g} "
            f"ms: {counts}: do the input topics share one time base? "
            "Set estimator.sync_tolerance_s (below half the sample period) if they are logged further apart"
        )
    skewed = spans.text(estimator.sample_period_s)
    if skewed:
        warn(skewed)
    if summary.samples and not summary.estimated:
        reasons = ", ".join(f"{k.replace('_', ' ')} {v:,}" for k, v in summary.skipped.items() if v)
        warn(f"no sample was estimated: every one of the {summary.samples:,} was skipped ({reasons}); "
             "the outputs hold no estimate (implausible: the estimator.max_abs_* limits)")
    acc.fill(summary)
    summary.coefficients = estimator.coefficients()
    summary.speed_noise_rad_s = estimator.speed_noise.value
    summary.speed_noise_text = estimator.speed_noise.describe()
    summary.resampled_text = estimator.resampler.describe() or ""
    summary.resampled = {c: dict(made) for c, made in estimator.resampler.made.items()}
    if estimator.aligner is not None:
        summary.lags_text = estimator.aligner.text()
    summary.describes = _describes(estimator.config)
    summary.beyond_text = estimator.beyond_text()
    summary.adaptation_text = estimator.adaptation_text()


def _describes(config: Config) -> str:
    """The stretch of the recordings the parameter file describes, where its calibration found the
    gearbox changed inside them ('': all of them, or not calibrated)."""
    from ..core.modelform import ModelForm

    form = ModelForm.from_text(config.calibration.model_form)
    return printable(form.segment) if form else ""
