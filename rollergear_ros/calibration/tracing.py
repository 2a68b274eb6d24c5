"""Online tracing: ``calibrate``'s discovery on a window of the live node's own samples.

The node keeps the inputs of its recent estimates (:class:`TraceBuffer`); when its change
detector fires, once enough samples have come after the alarm, or every ``node.trace_period_s``,
it hands a snapshot (:class:`TraceRequest`) to a worker process (:class:`~.traceworker.TraceWorker`) that runs
:func:`trace`:

1. the samples (those since the last gap in the inputs, with a measured output or not) are
   estimated with the bare model (:func:`~.samples.bare_config`) into the very
   :class:`~.samples.SampleData` that ``calibrate`` analyses for a recording
   (:func:`~.samples.samples_from_estimates`): an effect's memory steps over every sample, the
   analysis takes those with a measured output;
2. with an alarm, the change point is where the running parameters' residual (block means of
   ``block_s``) splits best into two levels -- least squares, searched before the alarm;
3. :func:`~.calibrate.calibrate` runs on the latest window after the change point (at most
   ``window_s``: a trace of the same change later on slides it on) and, when it holds enough
   samples, on the window before it -- as ``calibrate --start/--end`` on the node's recording (an
   effect's memory steps over the samples before the window too) -- both with the node's
   parameters (their accepted effects assumed, as ``--assume``, where the data cannot tell them
   from another);
4. an effect *traced* is one accepted after the change, not enabled in the node's parameters and
   not accepted before the change (it did not appear then); a periodic trace (no change point)
   names the effects the parameters lack over the whole window;
5. the errors are those of exactly the parameter sets compared: the node's and the candidate file
   (``calibrate``'s result: the node's parameters with the accepted effects), each run through the
   estimator over the window after the change; ``calibrate``'s held-out errors are kept beside.

No rclpy import: the worker process never loads ROS.
"""

from __future__ import annotations

import bisect
import json
import math
import time
from array import array
from dataclasses import dataclass, field

import numpy as np

from ..base.errors import BagError, RollergearError
from ..base.instants import iso_ns
from ..core.estimator import Estimator
from ..core.params import Config, config_to_yaml, validate
from .calibrate import CalibrationResult, CalibrationSettings, calibrate
from .samples import SampleData, bare_config, samples_from_estimates

__all__ = ["INPUT_FIELDS", "SAMPLE_FIELDS", "TraceBuffer", "TraceRequest", "TraceResult", "change_point", "trace"]

#: the estimator's inputs, in :meth:`~core.estimator.Estimator.process_batch`'s order
INPUT_FIELDS = ("t_ns", "torque_nm", "speed_rad_s", "out_torque_nm", "out_speed_rad_s", "temperature_c")
#: the fields of an estimate the buffer keeps, in its tuples' order: the inputs, and the measured loss
#: (NaN: none; the node's measured-efficiency window takes the samples that have one, as replay's does)
SAMPLE_FIELDS = (*INPUT_FIELDS, "measured_loss_nm")
MIN_BEFORE_S = 10.0  #: a window before the change point shorter than this is not analysed
#: inputs silent this long (at least; 20 sample periods where those are longer), or time going back,
#: are a gap -- a new recording, a pause of the rig: a trace's window starts after the last one
GAP_S = 2.0
CHANGE_BLOCK_S = 0.25  #: block length of the change point's search [s]


class TraceBuffer:
    """The inputs of the node's most recent estimates, with a measured output or not (NaN): their
    times (``int64``) and the other
    :data:`SAMPLE_FIELDS` (``float64``, interleaved) in two growing ``array.array``.

    The input path appends with two C calls (:attr:`add_time`, :attr:`add_values`), no Python
    function; :meth:`snapshot` copies the buffer into numpy arrays in a memory copy (milliseconds,
    taken under the input lock, so that a trace never holds the interpreter long enough to delay an
    input), and :meth:`trim` drops what is older than ``capacity`` samples (from a timer)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = max(int(capacity), 1)
        self.times = array("q")
        self.values = array("d")
        self.add_time = self.times.append  #: ``add_time(t_ns)``
        #: ``add_values((torque, speed, out_torque, out_speed, temperature, measured_loss))``
        self.add_values = self.values.extend

    def __len__(self) -> int:
        return len(self.times)

    def last_ns(self) -> int | None:
        return self.times[-1] if self.times else None

    def first_ns(self) -> int | None:
        """The oldest sample kept once trimmed (None: empty)."""
        return self.times[max(len(self.times) - self.capacity, 0)] if self.times else None

    def add(self, row: tuple) -> None:
        """One sample: ``(t_ns, torque, speed, out_torque, out_speed, temperature, measured_loss)``."""
        self.add_time(row[0])
        self.add_values(row[1:])

    def trim(self) -> None:
        """Drop all but the last ``capacity`` samples."""
        extra = len(self.times) - self.capacity
        if extra > 0:
            del self.times[:extra]
            del self.values[:extra * (len(SAMPLE_FIELDS) - 1)]

    def since(self, after_ns: int | None) -> dict[str, np.ndarray]:
        """The buffered samples later than ``after_ns`` (None: all kept), as :meth:`snapshot` gives them."""
        start = 0 if after_ns is None else bisect.bisect_right(self.times, after_ns)
        width = len(SAMPLE_FIELDS) - 1
        times = np.frombuffer(self.times, dtype=np.int64)[start:].copy()
        values = np.frombuffer(self.values, dtype=np.float64)[start * width:].reshape(len(times), width)
        return {"t_ns": times} | {f: values[:, k].copy() for k, f in enumerate(SAMPLE_FIELDS[1:])}  # copies

    def snapshot(self) -> dict[str, np.ndarray]:
        """The last ``capacity`` buffered samples as one array per field, in time order (copies)."""
        n = min(len(self.times), self.capacity)
        width = len(SAMPLE_FIELDS) - 1
        times = np.frombuffer(self.times, dtype=np.int64)[len(self.times) - n:].copy()
        values = np.frombuffer(self.values, dtype=np.float64)[(len(self.times) - n) * width:].reshape(n, width).copy()
        return {"t_ns": times} | {f: values[:, k].copy() for k, f in enumerate(SAMPLE_FIELDS[1:])}


@dataclass(frozen=True)
class TraceRequest:
    """What the worker traces: samples, the node's parameters, and why."""

    samples: dict[str, np.ndarray]  #: :data:`SAMPLE_FIELDS` -> arrays, in time order
    parameters: dict  #: the node's parameter set, flat (:meth:`~core.params.Config.to_flat`)
    reason: str  #: "alarm" or "period"
    alarm_ns: int | None = None  #: the change alarm's sample time (reason "alarm")
    window_s: float = 60.0  #: the longest window on each side of the change point (after it: the latest)
    min_after_s: float = 20.0  #: samples needed after the change point
    #: the last sample time analysed (None: all): a trace scheduled for a time sees exactly the samples
    #: up to it, however late the worker gets to it -- the same samples give the same result
    end_ns: int | None = None
    #: the node's speed noise as it learned it (``auto``): its checkpoints ``(sample time, σ)``, which the
    #: trace's estimates follow by sample time as a time slice of a recording does (``calibrate --start``)
    speed_noise: tuple[tuple[int, float], ...] = ()


@dataclass
class TraceResult:
    """What a trace found; :meth:`to_json` is what the node publishes and records."""

    reason: str
    verdict: str  #: traced | nothing_new | inconclusive
    message: str  #: one sentence
    since_ns: int | None  #: the change point (alarm) or the window's start (period)
    window_ns: tuple[int, int]  #: the samples analysed after the change point (or the whole window)
    samples: int  #: in that window
    effects: list[dict] = field(default_factory=list)  #: traced: name, params, ci95
    error_now_nm: float = math.nan  #: RMS residual of the node's parameters over the window
    error_candidate_nm: float = math.nan  #: ... of the candidate parameter set
    heldout_rmse_nm: tuple[float, float] = (math.nan, math.nan)  #: calibrate's held-out RMSE before/after
    candidate_yaml: str | None = None  #: the candidate parameter file (None: nothing to propose)
    candidate_changes: dict = field(default_factory=dict)  #: its parameters that differ from the node's
    elapsed_s: float = 0.0  #: the worker's time for this trace
    notes: list[str] = field(default_factory=list)
    alarm_ns: int | None = None  #: the change alarm traced (reason "alarm")

    @property
    def calibrate_window(self) -> str:
        """The window as ``calibrate --start/--end`` of the node's recording takes it: its first and last
        sample's instants on the recording's clock (the same samples, to the nanosecond)."""
        return f"--start {iso_ns(self.window_ns[0])} --end {iso_ns(self.window_ns[1])}"

    def to_json(self) -> dict:
        return {"reason": self.reason, "alarm_ns": self.alarm_ns, "verdict": self.verdict, "message": self.message,
                "since_ns": self.since_ns, "window_ns": list(self.window_ns),
                "window_iso": [iso_ns(t) for t in self.window_ns], "calibrate_window": self.calibrate_window,
                "samples": self.samples,
                "effects": self.effects, "error_now_nm": self.error_now_nm,
                "error_candidate_nm": self.error_candidate_nm, "heldout_rmse_nm": list(self.heldout_rmse_nm),
                "elapsed_s": self.elapsed_s, "notes": self.notes}

    def key_values(self) -> list[tuple[str, str]]:
        """Key/values of the ``/diagnostics`` entry and the ``loss/traced`` status."""
        kv = [("reason", self.reason), ("verdict", self.verdict),
              ("since [ns]", "" if self.since_ns is None else str(self.since_ns)),
              ("window [ns]", f"{self.window_ns[0]} {self.window_ns[1]}"),
              ("window", " ".join(iso_ns(t) for t in self.window_ns)), ("calibrate window", self.calibrate_window),
              ("samples", str(self.samples)),
              ("error now RMS [N*m]", f"{self.error_now_nm:.6g}"),
              ("error with candidate RMS [N*m]", f"{self.error_candidate_nm:.6g}"),
              ("held-out RMSE before/after [N*m]", f"{self.heldout_rmse_nm[0]:.6g} {self.heldout_rmse_nm[1]:.6g}"),
              ("trace time [s]", f"{self.elapsed_s:.2f}")]
        for e in self.effects:
            kv.append((f"effect {e['name']}", _effect_text(e)))
        kv += [("note", n) for n in self.notes]
        kv.append(("json", json.dumps(self.to_json())))  # the whole result, for programs
        return kv


def _effect_text(effect: dict) -> str:
    """An effect as ``c=0.06 (95 %: c in [0.058, 0.062])``."""
    params = ", ".join(f"{k}={v:.4g}" for k, v in effect["params"].items())
    ci = ", ".join(f"{k} in [{lo:.4g}, {hi:.4g}]" for k, (lo, hi) in effect["ci95"].items())
    return f"{params} (95 %: {ci})" if ci else params


def change_point(t_ns: np.ndarray, residual: np.ndarray, alarm_ns: int, block_s: float = CHANGE_BLOCK_S) -> int:
    """The time before ``alarm_ns`` where ``residual`` splits best into two levels.

    Residuals are averaged over blocks of ``block_s``; the split minimises the sum of squared
    deviations of the block means from the mean of their side (the least-squares single change
    point), searched among the blocks that start before the alarm.  Returns the first sample time
    of the block after the split (``t_ns[0]`` when there is nothing to split)."""
    ok = np.isfinite(residual)
    t, r = t_ns[ok], residual[ok]
    if len(t) < 4:
        return int(t_ns[0]) if len(t_ns) else alarm_ns
    block = ((t - t[0]) // int(block_s * 1e9)).astype(np.int64)
    starts = np.flatnonzero(np.diff(block, prepend=-1))
    means = np.add.reduceat(r, starts) / np.diff(np.append(starts, len(r)))
    n = len(means)
    if n < 2:
        return int(t[0])
    k = np.arange(1, n)  # split before block k
    csum, csq = np.cumsum(means), np.cumsum(means ** 2)
    left = csq[k - 1] - csum[k - 1] ** 2 / k
    right = (csq[-1] - csq[k - 1]) - (csum[-1] - csum[k - 1]) ** 2 / (n - k)
    cost = left + right
    cost[t[starts[k]] > alarm_ns] = np.inf
    if not np.isfinite(cost).any():
        return int(t[0])
    return int(t[starts[k[int(np.argmin(cost))]]])


def after_last_gap(t_ns: np.ndarray) -> int:
    """Index of the first sample after the last gap in ``t_ns`` (:data:`GAP_S`; 0: none)."""
    if len(t_ns) < 2:
        return 0
    steps = np.diff(np.asarray(t_ns, dtype=np.int64))
    positive = steps[steps > 0]
    limit = max(GAP_S * 1e9, 20.0 * float(np.median(positive))) if len(positive) else GAP_S * 1e9
    gaps = np.flatnonzero((steps > limit) | (steps < 0))
    return int(gaps[-1]) + 1 if len(gaps) else 0


def _estimates(config: Config, s: dict[str, np.ndarray], keep: np.ndarray, speed_noise=()):
    """The estimator with ``config`` over the samples where ``keep``, fresh (one batch), its speed noise
    following the node's checkpoints (``speed_noise``): the estimates and the estimator."""
    estimator = Estimator(config)
    if speed_noise:
        estimator.speed_noise.follow(list(speed_noise))
    batch = estimator.process_batch(s["t_ns"][keep], s["torque_nm"][keep], s["speed_rad_s"][keep],
                                    s["out_torque_nm"][keep], s["out_speed_rad_s"][keep], s["temperature_c"][keep],
                                    breakdown=False)
    return batch, estimator


def _rms_residual(config: Config, s: dict[str, np.ndarray], keep: np.ndarray, speed_noise=()) -> float:
    r = _estimates(config, s, keep, speed_noise)[0].residual_nm
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r ** 2))) if len(r) else math.nan


def _bare_samples(config: Config, s: dict[str, np.ndarray], speed_noise=()) -> SampleData:
    """Every buffered sample estimated with the bare model, as ``calibrate`` loads the node's recording
    (an effect's memory steps over all of them), with the same speed noise: once per trace, for both
    windows."""
    batch, estimator = _estimates(bare_config(config), s, np.ones(len(s["t_ns"]), bool), speed_noise)
    return samples_from_estimates([[batch]], config, sign_width_rad_s=estimator.sign_width_rad_s)


def _calibrate(config: Config, data: SampleData, t_ns: np.ndarray) -> CalibrationResult:
    """``calibrate`` on the samples of ``data`` from ``t_ns[0]`` to ``t_ns[-1]`` (a window's times, not empty),
    exactly as ``calibrate --start/--end`` on the node's recording."""
    window = data.select((data.t_ns >= t_ns[0]) & (data.t_ns <= t_ns[-1]))
    # the effects the parameters already accept are assumed where the data cannot tell them from another
    return calibrate(window, config, CalibrationSettings(assume=tuple(config.effects.enabled())))


def trace(request: TraceRequest) -> TraceResult:
    """Trace the residual of ``request``'s samples (see the module docstring)."""
    start = time.perf_counter()
    config = validate(request.parameters)
    s = request.samples
    if request.end_ns is not None:
        keep = s["t_ns"] <= request.end_ns
        s = {k: v[keep] for k, v in s.items()}
    gap_note = None
    cut = after_last_gap(s["t_ns"])
    if cut:  # never a window across a gap in the inputs: the two sides may be other gearboxes, other days
        pause_s = (int(s["t_ns"][cut]) - int(s["t_ns"][cut - 1])) * 1e-9
        what = f"paused for {pause_s:.3g} s" if pause_s > 0 else "went back in time"
        gap_note = (f"the inputs {what} before {int(s['t_ns'][cut])} ns (a new recording, a pause of the rig): "
                    "the window starts after it")
        s = {k: v[cut:] for k, v in s.items()}
    t = s["t_ns"]
    measured = np.isfinite(s["out_torque_nm"])  # the windows are spans of samples with a measured output
    stamps = t[measured]
    window_ns = int(request.window_s * 1e9)
    end = int(stamps[-1]) if len(stamps) else 0
    if request.reason == "alarm" and request.alarm_ns is not None and len(stamps) and request.alarm_ns >= t[0]:
        residual = _estimates(config, s, np.ones(len(t), bool), request.speed_noise)[0].residual_nm
        since = change_point(t, residual, request.alarm_ns)  # at samples with a residual
    else:
        since = max(int(stamps[0]), end - window_ns) if len(stamps) else 0
    # the latest window after the change point (a later trace of the same change slides it on)
    after = measured & (t >= max(since, end - window_ns))
    before = measured & (t < since) & (t >= since - window_ns)
    span = (int(t[after][0]), int(t[after][-1])) if after.any() else (since, since)
    result = TraceResult(request.reason, "inconclusive", "", since, span, int(after.sum()), alarm_ns=request.alarm_ns)
    if gap_note:
        result.notes.append(gap_note)
    after_s = (span[1] - span[0]) * 1e-9
    if request.reason == "alarm" and after_s < request.min_after_s:
        result.message = (f"inconclusive: needs {request.min_after_s:g} s of samples with measured output after the "
                          f"change, has {after_s:.1f} s")
        return _timed(result, start)
    before_s = (t[before][-1] - t[before][0]) * 1e-9 if before.any() else 0.0
    try:
        if not after.any():
            raise BagError("no samples in the window")
        data = _bare_samples(config, s, request.speed_noise)
        cal = _calibrate(config, data, t[after])
        before_cal = (_calibrate(config, data, t[before])
                      if request.reason == "alarm" and before_s >= MIN_BEFORE_S else None)
    except RollergearError as exc:
        result.message = f"inconclusive: {exc}"
        return _timed(result, start)
    # the errors: the estimator over every sample of the window after the change, measured output or not
    _judge(result, config, cal, before_cal, s, (t >= span[0]) & (t <= span[1]), request.speed_noise)
    return _timed(result, start)


def _judge(result: TraceResult, config: Config, cal: CalibrationResult, before_cal: CalibrationResult | None,
           s: dict[str, np.ndarray], after: np.ndarray, speed_noise=()) -> None:
    """Fill ``result`` from the calibration after the change (and before it); ``after``: the samples of
    the window after the change."""
    enabled = set(config.effects.enabled())
    there_before = {e.name for e in before_cal.effects} if before_cal is not None and before_cal.written else set()
    new = [e for e in cal.effects if e.name not in enabled and e.name not in there_before]
    result.heldout_rmse_nm = (cal.error_before.rmse_nm, cal.error_after.rmse_nm)
    result.error_now_nm = _rms_residual(config, s, after, speed_noise)
    result.notes += list(cal.notes)
    if before_cal is not None:
        result.notes.append(f"before the change: {before_cal.verdict}"
                            + (f" ({', '.join(e.name for e in before_cal.effects)})" if before_cal.effects else ""))
    when = "since the change" if result.reason == "alarm" else "over the window"
    if cal.verdict == "inconclusive" or not cal.written:
        sets = "; ".join(f"{' / '.join(a.effects)} cannot be told apart (needs {a.needs})" for a in cal.ambiguous)
        result.message = f"inconclusive: {sets or 'needs a wider range of speed, torque and direction'}"
        return
    at_bound = [e for e in new if e.at_bound]
    if at_bound:  # the data want a law outside the vocabulary: no estimate to propose (as calibrate sets it aside)
        result.message = "inconclusive: " + "; ".join(e.bound_note() for e in at_bound)
        return
    if not new:
        result.verdict = "nothing_new"
        result.message = f"nothing new {when}: the residual holds no effect the parameters lack"
        return
    result.verdict = "traced"
    result.effects = [{"name": e.name, "params": e.params, "ci95": e.ci95,
                       "rms_contribution_nm": e.rms_contribution_nm} for e in new]
    result.error_candidate_nm = _rms_residual(cal.config, s, after, speed_noise)
    named = "; ".join(f"{e['name']} {_effect_text(e)}" for e in result.effects)
    result.message = (f"{when} the residual is {named}; with it the error falls from {result.error_now_nm:.4g} to "
                      f"{result.error_candidate_nm:.4g} N*m (RMS over {result.samples:,} samples)")
    now = config.to_flat()
    result.candidate_changes = {k: v for k, v in cal.config.to_flat().items() if now.get(k) != v}
    result.candidate_yaml = config_to_yaml(cal.config, (
        f"# Candidate written by the live tracer of rollergear's loss_estimator ({result.reason} trace of the samples "
        f"{result.window_ns[0]}..{result.window_ns[1]} ns: calibrate RECORDING {result.calibrate_window})\n"
        f"# {result.message}\n"
        "# The parameter file the node was started with is not changed.\n"))


def _timed(result: TraceResult, start: float) -> TraceResult:
    if result.samples:  # where to find it offline: the window on the recording's own clock
        result.message += f" (offline: calibrate RECORDING {result.calibrate_window})"
    result.elapsed_s = time.perf_counter() - start
    return result

