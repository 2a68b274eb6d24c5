"""What the node reports on ``/diagnostics``: input rates, staleness, skips, efficiency, residual.

Pure Python (no rclpy): :func:`diagnose` turns an :class:`InputMonitor` and the estimator's state
into a level, a message and key/value pairs; the node only copies them into a
``diagnostic_msgs/DiagnosticStatus``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..core.estimator import Estimator
from ..core.measured import NO_OUTPUT_SHARE, WindowValue
from ..core.pairing import CHANNELS, OUT_TORQUE, SKIP_REASONS, SPEED, TORQUE
from ..core.seqclock import SequenceClock

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
#: the node's ``/diagnostics`` status is named ``<node name>: STATUS_NAME``
STATUS_NAME = "roller gearbox losses"
STARTUP_GRACE_S = 5.0
#: an executor lag beyond this share of what the input queue holds is an overload (WARN)
OVERLOAD_QUEUE_SHARE = 0.5
#: the lag taken as "holding" a reliable keep-all input (no queue to overflow; its publisher waits)
RELIABLE_LAG_S = 1.0
#: a stream's rate is learned as the median of its first this many whole report windows
RATE_LEARN_WINDOWS = 3
#: below this share of the expected rate an input is reported as slow (WARN)
SLOW_RATE_SHARE = 0.8


@dataclass
class InputMonitor:
    """Counts and last arrival (wall clock, ns) of each input channel, and the rate each stream
    started at.

    A stream starts with the first report window (:meth:`rates`) in which its channel has messages
    after one without any (a bag played at another rate, a restarted player).  That first window is
    partial; the median rate of the next :data:`RATE_LEARN_WINDOWS` whole windows is the stream's
    learned rate (:meth:`learned_rate_hz`), so a stream that slows down later is still reported.
    """

    start_ns: int
    counts: dict[str, int] = field(default_factory=lambda: {c: 0 for c in CHANNELS})
    last_ns: dict[str, int | None] = field(default_factory=lambda: {c: None for c in CHANNELS})
    #: messages the middleware lost (gaps in the publishers' sequence numbers; arrival pairing only)
    lost: dict[str, int] = field(default_factory=lambda: {c: 0 for c in CHANNELS})
    _window_counts: dict[str, int] = field(default_factory=lambda: {c: 0 for c in CHANNELS})
    _window_start_ns: int = 0
    _active_windows: dict[str, int] = field(default_factory=lambda: {c: 0 for c in CHANNELS})
    _learning: dict[str, list[float]] = field(default_factory=lambda: {c: [] for c in CHANNELS})
    _learned_hz: dict[str, float | None] = field(default_factory=lambda: {c: None for c in CHANNELS})
    #: ``node.sample_clock: sequence``: the clock the Float64 inputs are timed by (None: their arrival)
    sample_clock: SequenceClock | None = None

    def __post_init__(self) -> None:
        self._window_start_ns = self.start_ns

    def record(self, channel: str, wall_ns: int) -> None:
        self.counts[channel] += 1
        self.last_ns[channel] = wall_ns

    def rates(self, now_ns: int) -> dict[str, float]:
        """Messages per second per channel since the previous call (then a new window starts)."""
        dt = max((now_ns - self._window_start_ns) * 1e-9, 1e-9)
        out = {c: (self.counts[c] - self._window_counts[c]) / dt for c in CHANNELS}
        self._window_counts = dict(self.counts)
        self._window_start_ns = now_ns
        for c, rate in out.items():
            if rate == 0.0:  # silent for a whole window: what comes next is a new stream
                self._active_windows[c] = 0
                self._learning[c] = []
                self._learned_hz[c] = None
                continue
            self._active_windows[c] += 1
            if self._active_windows[c] > 1 and self._learned_hz[c] is None:  # a whole window of the stream
                self._learning[c].append(rate)
                if len(self._learning[c]) == RATE_LEARN_WINDOWS:
                    self._learned_hz[c] = sorted(self._learning[c])[RATE_LEARN_WINDOWS // 2]
        return out

    def learned_rate_hz(self, channel: str) -> float | None:
        """The rate the channel's current stream started at (None: not learned yet)."""
        return self._learned_hz[channel]


@dataclass
class DiagnosticReport:
    level: int
    message: str
    values: list[tuple[str, str]]


@dataclass(frozen=True)
class InputsNow:
    """The inputs as a report sees them: at ``now_ns``, their monitor and their rates over the
    window that just ended (:meth:`InputMonitor.rates`)."""

    now_ns: int
    monitor: InputMonitor
    rates: dict[str, float]


@dataclass(frozen=True)
class DiagnosticLimits:
    """What a report judges against (the node's parameters)."""

    expected_rate_hz: float
    min_efficiency_warn: float
    #: messages a best-effort input queue holds (None: a reliable keep-all input, whose publisher waits)
    queue_depth: int | None = None
    #: judge an input's rate against the rate its stream started at (else ``expected_rate_hz``)
    learn_rate: bool = False


@dataclass(frozen=True)
class SinceLast:
    """What the previous report counted: skips by reason and change alarms (the new ones are WARNs)."""

    skips: dict[str, int]
    alarms: int


@dataclass(frozen=True)
class NodeLoad:
    """How busy the node is: the share of time in input callbacks, and how far its executor lags."""

    busy_fraction: float = 0.0
    executor_lag_s: float = 0.0


def _fmt(x: float, digits: int = 4) -> str:
    return "nan" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}g}"


def _slow_input(channel: str, rate_hz: float, expected_hz: float | None, learned: bool) -> list[tuple[int, str]]:
    """A WARN when ``channel`` runs below :data:`SLOW_RATE_SHARE` of ``expected_hz`` (None: not known yet)."""
    if expected_hz is None or rate_hz >= SLOW_RATE_SHARE * expected_hz:
        return []
    against = "its stream started at" if learned else "expected"
    return [(WARN, f"{channel} at {rate_hz:.0f} Hz, {against} {expected_hz:.0f} Hz")]


def diagnose(inputs: InputsNow, estimator: Estimator, limits: DiagnosticLimits, since: SinceLast,
             load: NodeLoad = NodeLoad(), measured: WindowValue | None = None,
             trace_hint: str = "") -> DiagnosticReport:
    """Level (worst reason wins), one-line message and the key/value pairs of the status.

    ``trace_hint``: where the online trace of a residual alarm is (``see loss/traced`` once a trace
    exists or is under way, when it will start, or '' with tracing off), said beside the alarm.

    Overload: ``load.executor_lag_s`` is how long the executor takes to reach an event queued behind
    the inputs (``load.busy_fraction`` the share of time spent in input callbacks).  A best-effort
    input queue of ``limits.queue_depth`` messages holds ``queue_depth / expected_rate_hz`` seconds;
    an executor running half of that behind is about to lose the oldest of them, so that is a WARN
    (by arrival, the node counts what was lost, from the publishers' sequence numbers: ``lost in
    delivery``).  ``None``: a reliable keep-all input (the publisher waits instead).  Nothing is said of it
    before the first input message: no queue holds anything to lose.

    Stale: an input silent for longer than ``estimator.staleness_s`` (at least ten expected periods)
    plus the executor lag -- an overloaded or starved node is behind, its rig not idle.

    Input rates: with ``limits.learn_rate`` an input is slow below :data:`SLOW_RATE_SHARE` of the
    rate its stream started at (:meth:`InputMonitor.learned_rate_hz`; nothing is said while it is
    learned), so a bag played at another rate is not a warning for ever; otherwise below that share
    of ``expected_rate_hz``.
    """
    est = estimator.config.estimator
    expected_rate_hz = limits.expected_rate_hz
    stale_after_s = max(est.staleness_s, 10.0 / expected_rate_hz)
    reasons: list[tuple[int, str]] = []
    values: list[tuple[str, str]] = []
    busy_fraction, executor_lag_s, queue_depth = load.busy_fraction, load.executor_lag_s, limits.queue_depth
    # an input is stale when its silence is more than the node's own lag explains: messages waiting in
    # a queue the node has not reached (or a node the machine has not run) are no idle rig
    _input_status(inputs, estimator, limits, stale_after_s + executor_lag_s, reasons, values)
    values.append(("input callbacks busy [%]", _fmt(100 * busy_fraction, 3)))
    values.append(("executor lag [s]", _fmt(executor_lag_s, 3)))
    limit_s = OVERLOAD_QUEUE_SHARE * (queue_depth / expected_rate_hz if queue_depth else RELIABLE_LAG_S)
    # before any input came there is no queue to overflow (a node's start-up lags its first timers)
    if executor_lag_s > limit_s and any(inputs.monitor.counts.values()):
        lost = " its input queues overflow: the oldest messages are lost" if queue_depth else \
            " the publishers are slowed down"
        reasons.append((WARN, f"overloaded: the node runs {executor_lag_s:.2f} s behind its inputs "
                              f"(callbacks busy {100 * busy_fraction:.0f} %);{lost}"))
    values.append(("expected rate [Hz]", _fmt(expected_rate_hz)))
    values.append(("stale after [s]", _fmt(stale_after_s, 3)))
    values.append(("samples estimated", str(estimator.estimated)))
    _skip_status(estimator, since.skips, reasons, values)
    spin = measured is not None and math.isfinite(measured.efficiency) and abs(measured.efficiency) <= NO_OUTPUT_SHARE
    # a spin test: no power leaves the output, so no efficiency -- nor a low one to warn of
    _estimate_status(estimator, -math.inf if spin else limits.min_efficiency_warn, since.alarms, reasons, values,
                     trace_hint)
    headline = _measured_status(measured, estimator.config.sensors.stated, values)
    level = max((lv for lv, _ in reasons), default=OK)
    message = "; ".join(m for lv, m in sorted(reasons, key=lambda r: -r[0])) if reasons else "estimating"
    if headline:
        message += f"; {headline}"
    return DiagnosticReport(level, message, values)


def _input_status(inputs: InputsNow, estimator: Estimator, limits: DiagnosticLimits, stale_after_s: float,
                  reasons: list[tuple[int, str]], values: list[tuple[str, str]]) -> None:
    """Each input's rate, age, counts and losses; a missing, stale or slow drive input."""
    now_ns, monitor, rates = inputs.now_ns, inputs.monitor, inputs.rates
    since_start = (now_ns - monitor.start_ns) * 1e-9
    for ch in CHANNELS:
        last = monitor.last_ns[ch]
        age = math.inf if last is None else (now_ns - last) * 1e-9
        values.append((f"{ch} rate [Hz]", _fmt(rates.get(ch, 0.0))))
        values.append((f"{ch} age [s]", "never" if last is None else _fmt(age, 3)))
        values.append((f"{ch} messages", str(monitor.counts[ch])))
        values.append((f"{ch} lost in delivery", str(monitor.lost[ch])))
        required = ch in (TORQUE, SPEED)
        if required:  # each estimate takes one message of each: the rest were not estimated
            values.append((f"{ch} not estimated", str(max(monitor.counts[ch] - estimator.estimated, 0))))
            learned = monitor.learned_rate_hz(ch)
            if limits.learn_rate:
                values.append((f"{ch} learned rate [Hz]", "learning" if learned is None else _fmt(learned)))
            if last is None:  # nothing yet: after the start-up grace the node is idle, not broken
                level = WARN if since_start < STARTUP_GRACE_S else STALE
                reasons.append((level, f"no input on {ch} yet: idle"))
            elif age > stale_after_s:
                reasons.append((STALE, f"stale input: {ch} silent for {age:.2f} s: idle"))
            else:
                expected = learned if limits.learn_rate else limits.expected_rate_hz
                reasons += _slow_input(ch, rates.get(ch, 0.0), expected, limits.learn_rate)
        elif ch == OUT_TORQUE and last is not None and age > stale_after_s:
            reasons.append((WARN, f"measured output stale ({age:.2f} s): no residual"))
    clock = monitor.sample_clock
    if clock is not None:
        values.append(("sample clock", f"publishers' numbers at {1e9 / clock.period_ns:.6g} Hz; "
                                       f"{clock.pauses} pause(s) or restart(s)"))
        for problem in (clock.rate_problem, clock.step_problem):
            if problem:
                reasons.append((WARN, problem))


def _measured_status(measured: WindowValue | None, stated: bool, values: list[tuple[str, str]]) -> str:
    """The measured efficiency over the latest window (keys always there; a headline when there is one)."""
    if measured is None:
        values += [("measured efficiency", "none (no measured output torque)"),
                   ("measured efficiency uncertainty", "none")]
        return ""
    values += [("measured efficiency", repr(measured.efficiency)),  # all its digits: a logger's number
               ("measured efficiency uncertainty", repr(measured.uncertainty) if stated else "not stated (sensors.*)"),
               ("measured efficiency window [s]", _fmt(measured.window_s)),
               ("measured efficiency samples", str(measured.samples)),
               ("measured efficiency window end [ns]", str(measured.end_ns))]
    if math.isfinite(measured.efficiency) and abs(measured.efficiency) <= NO_OUTPUT_SHARE:
        return f"no power leaves the output over {measured.window_s:g} s (a spin test): the drive power is all loss"
    spread = f" ± {100 * measured.uncertainty:.2f}" if stated else ""
    return f"measured efficiency {100 * measured.efficiency:.2f}{spread} % over {measured.window_s:g} s"


def _skip_status(estimator: Estimator, previous_skips: dict[str, int], reasons: list[tuple[int, str]],
                 values: list[tuple[str, str]]) -> None:
    """The samples skipped, by reason, in total and since the last report; a WARN for new ones."""
    for r in SKIP_REASONS:
        total = estimator.counts[r]
        new = total - previous_skips.get(r, 0)
        values.append((f"skipped {r.replace('_', ' ')}", f"{total} (+{new})"))
        if new and r in ("non_finite", "implausible"):
            reasons.append((WARN, f"{new} samples with {r.replace('_', ' ')} input skipped"))
        elif new and r in ("malformed", "duplicate"):
            reasons.append((WARN, f"{new} {r} input messages skipped"))
        elif new and r == "lost":
            reasons.append((WARN, f"overloaded: {new} samples lost in delivery (the node fell a whole "
                                  "best-effort input queue behind)"))
        elif new and r == "unpaired":
            reasons.append((WARN, f"{new} input messages without partner (dropped or late)"))
        elif new and r == "stale":
            reasons.append((WARN, f"{new} samples skipped: the motor speed (another rate than the torque's) "
                                  "had no value within estimator.resample_max_age_s"))
        elif new and r == "out_of_order":
            reasons.append((WARN, f"{new} samples skipped: stamped too far behind one already seen to be put "
                                  "in order for the channel lags"))
    aligner = estimator.aligner
    if aligner is not None:  # the file's lags: how steady the stamps they are applied on are
        values.append(("lag stamp intervals off the period", f"{aligner.jittered} of {aligner.intervals}"))
        if aligner.jitters:
            reasons.append((WARN, aligner.jitter_text()))
    resampler = estimator.resampler
    for channel in resampler.resampled:  # channels at another rate: how their values were made
        made = resampler.made[channel]
        total = sum(made.values())
        values.append((f"{channel} resampled", f"{total} samples: {made['interpolated']} interpolated, "
                                               f"{made['held']} held, {made['none']} without a value"))
        values.append((f"{channel} held share", _fmt(made["held"] / total if total else 0.0)))


def _estimate_status(estimator: Estimator, min_efficiency_warn: float, previous_alarms: int,
                     reasons: list[tuple[int, str]], values: list[tuple[str, str]], trace_hint: str = "") -> None:
    """The latest estimate, the residual's statistics, the adapted coefficients and the change
    alarms; a low efficiency, a torque near its limit or a new alarm is a WARN."""
    est = estimator.config.estimator
    last = estimator.last
    if last is not None:
        values += [("loss torque [N·m]", _fmt(last.loss_torque_nm)), ("loss power [W]", _fmt(last.loss_power_w)),
                   ("efficiency", _fmt(last.efficiency)), ("drive torque [N·m]", _fmt(last.torque_nm)),
                   ("drive speed [rad/s]", _fmt(last.speed_rad_s))]
        if not math.isnan(last.efficiency) and last.efficiency < min_efficiency_warn:
            reasons.append((WARN, f"efficiency {100 * last.efficiency:.1f} % below {100 * min_efficiency_warn:.0f} %"))
        if math.isfinite(last.torque_nm) and abs(last.torque_nm) > 0.9 * est.max_abs_torque_nm:
            reasons.append((WARN, f"drive torque {last.torque_nm:.0f} N·m near the plausibility limit"))
    stats = estimator.residual_stats
    if stats.count:
        values += [("residual mean [N·m]", _fmt(stats.mean)), ("residual RMS [N·m]", _fmt(stats.rms)),
                   ("residual samples", str(stats.count))]
    for (name, c), held in zip(estimator.coefficients().items(), estimator.rls.held):
        values.append((f"adapted {name}", _fmt(c, 5)))
        if held:
            values.append((f"adapted {name} kept in range [updates]", str(held)))
    _residual_alarm_status(estimator, previous_alarms, reasons, values, trace_hint)


def _residual_alarm_status(estimator: Estimator, previous_alarms: int, reasons: list[tuple[int, str]],
                           values: list[tuple[str, str]], trace_hint: str = "") -> None:
    """A WARN for as long as the residual stays beyond its threshold after an alarm (the change
    detector holds it), saying whether it changed or was off from the start; one for an alarm whose
    residual returned before this report."""
    det = estimator.detector
    values.append(("residual change alarms", str(det.alarms)))
    beyond = det.refractory and det.alarms > 0
    values.append(("residual beyond threshold", "yes" if beyond else "no"))
    if det.alarm_times_ns:
        values.append(("last residual alarm [ns]", str(det.alarm_times_ns[-1])))
    if not (beyond or det.alarms > previous_alarms):
        return
    limit = f"±{det.delta / 2:.3g} N·m"
    if not beyond:
        what = "the residual went beyond its threshold and returned within it since the last report"
    elif det.alarm_from_start and det.alarm_from_start[-1]:
        what = (f"the residual has been beyond {limit} since the estimates began (block mean "
                f"{det.last_block_mean:+.3g} N·m): not a change -- the parameters lack an effect; run "
                "`rollergear calibrate`" + (f" ({trace_hint})" if trace_hint else ""))
    else:
        what = (f"the residual changed (a new or changed effect) and stays beyond {limit} (block mean "
                f"{det.last_block_mean:+.3g} N·m): " + (f"{trace_hint}, " if trace_hint else "")
                + "re-run `rollergear calibrate`")
    reasons.append((WARN, what))
