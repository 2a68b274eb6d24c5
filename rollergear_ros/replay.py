"""Offline replay: a recorded bag through the same estimator the node runs.

Reads any ROS 2 MCAP with the input topics (Float64 channels or a JointState topic), pairs and
estimates with :class:`~rollergear_ros.estimator.Estimator`, writes an output MCAP (inputs +
``interface.md`` outputs) and a rerun recording, and summarises.  Everything is written in
batches, so an interrupt (Ctrl-C, SIGTERM) leaves valid files holding all processed samples.
No rclpy import.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import numpy as np

from .bag import (BagError, BagInfo, BagWriter, RawBatch, TopicMap, cdr_problem, decode_float64, decoder_for,
                  float64_problem, inspect_bag, iter_raw_batches, median_period_s, offered_qos_yaml, read_metadata)
from .errors import UsageError
from .estimator import BatchEstimate, Estimator
from .pairing import ARRIVAL_PAIRINGS, CHANNELS, OIL_TEMPERATURE, OUT_SPEED, OUT_TORQUE, SPEED, TORQUE
from .interface import MessageType, Metadata
from .params import Config
from .progress import TimedProgress
from . import stamped


@dataclass
class InputPlan:
    """Which topics of a bag feed which estimator channel, and how to decode them."""

    mode: str  # "float64" or "joint_state"
    float64: dict[str, str]  # topic -> channel
    joint_states: str | None
    temperature: tuple[str, str] | None  # (topic, type)
    topics: TopicMap

    @property
    def all_topics(self) -> set[str]:
        t = set(self.float64)
        if self.joint_states:
            t.add(self.joint_states)
        if self.temperature:
            t.add(self.temperature[0])
        return t


def _check_float64_schema(info: BagInfo, topic: str) -> None:
    """A schema named ``std_msgs/msg/Float64`` must define ``float64 data`` (else its payloads
    would be decoded as something they are not)."""
    text = info.schema_texts.get(MessageType.FLOAT64)
    if text is None:
        return
    fields = [line.split("#")[0].strip() for line in text.split("=" * 80)[0].splitlines()]
    fields = [" ".join(f.split()) for f in fields if f]
    if fields != ["float64 data"]:
        shown = "; ".join(fields)[:120]
        raise BagError(f"topic {topic}: its schema {MessageType.FLOAT64} defines '{shown}', not 'float64 data'")


def plan_inputs(info: BagInfo, topics: TopicMap) -> InputPlan:
    """Check the bag has the inputs (with the right types); raise :class:`BagError` saying what it has."""
    have = info.topics

    def need_type(topic: str, expected: tuple[str, ...]) -> None:
        if have[topic] not in expected:
            raise BagError(f"topic {topic} has type {have[topic] or '<no schema>'}, expected "
                           f"{' or '.join(expected)}")

    temperature = None
    if topics.oil_temperature in have:
        need_type(topics.oil_temperature, (MessageType.TEMPERATURE, MessageType.FLOAT64))
        temperature = (topics.oil_temperature, have[topics.oil_temperature])
    if topics.motor_torque in have or topics.motor_speed in have:
        missing = [t for t in (topics.motor_torque, topics.motor_speed) if t not in have]
        if missing:
            raise BagError(
                f"{info.path}: missing input topic {', '.join(missing)}; the bag has: {info.describe_topics()}"
            )
        f64 = {}
        for ch, topic in topics.float64_inputs().items():
            if topic in have:
                need_type(topic, (MessageType.FLOAT64,))
                _check_float64_schema(info, topic)
                f64[topic] = ch
        return InputPlan("float64", f64, None, temperature, topics)
    if topics.joint_states in have:
        need_type(topics.joint_states, (MessageType.JOINT_STATE,))
        return InputPlan("joint_state", {}, topics.joint_states, temperature, topics)
    raise BagError(
        f"{info.path} has none of the input topics ({topics.motor_torque} and {topics.motor_speed} "
        f"as std_msgs/msg/Float64, or {topics.joint_states} as sensor_msgs/msg/JointState); "
        f"the bag has: {info.describe_topics()}"
    )


def _decode_temperature(payload: bytes, plan: InputPlan, info: BagInfo) -> tuple[float, str | None]:
    """An oil temperature message (Float64 or sensor_msgs/Temperature) -> (°C, problem or None)."""
    temp_type = plan.temperature[1]
    if temp_type == MessageType.FLOAT64:
        problem = float64_problem(payload)
        return (math.nan, problem) if problem else (float(decode_float64([payload])[0]), None)
    problem = cdr_problem(payload)
    if problem:
        return math.nan, problem
    try:
        return float(decoder_for(temp_type, info.schema_texts.get(temp_type))(payload).temperature), None
    except Exception as exc:  # noqa: BLE001 - the CDR decoder raises assorted errors on a bad payload
        return math.nan, f"cannot decode {temp_type} ({type(exc).__name__})"


def decode_batch(batch: RawBatch, plan: InputPlan, info: BagInfo,
                 problems: InputProblems | None = None) -> tuple[list[tuple[int, str, float]], set[int]]:
    """Decode a raw batch of a JointState recording into ``(time, channel, value)`` in file order,
    and the indices of the messages that could not be decoded.

    Float64 recordings take the vectorised path (:func:`_float64_batches`); non-finite values are
    kept.  A message that cannot be decoded is skipped and added to ``problems`` (raised without).
    """
    out: list[tuple[int, str, float]] = []
    bad: set[int] = set()
    tp = plan.topics
    temp_topic = plan.temperature[0] if plan.temperature else None
    js_dec = decoder_for(MessageType.JOINT_STATE, info.schema_texts.get(MessageType.JOINT_STATE))
    for i, (topic, t, data) in enumerate(zip(batch.topics, batch.log_time_ns, batch.data)):
        if topic == temp_topic:
            value, problem = _decode_temperature(data, plan, info)
            if problem is None:
                out.append((t, OIL_TEMPERATURE, value))
        elif topic == plan.joint_states:
            problem = cdr_problem(data)
            if problem is None:
                try:
                    msg = js_dec(data)
                except Exception as exc:  # noqa: BLE001 - the CDR decoder raises assorted errors
                    problem = f"cannot decode {MessageType.JOINT_STATE} ({type(exc).__name__})"
            if problem is None:
                names = list(msg.name)
                for joint, ch_t, ch_w in ((tp.input_joint, TORQUE, SPEED), (tp.output_joint, OUT_TORQUE, OUT_SPEED)):
                    if joint in names:
                        k = names.index(joint)
                        out.append((t, ch_t, float(msg.effort[k]) if k < len(msg.effort) else math.nan))
                        out.append((t, ch_w, float(msg.velocity[k]) if k < len(msg.velocity) else math.nan))
        else:
            problem = None
        if problem is not None:
            if problems is None:
                raise BagError(f"{topic} at log time {t} ns: {problem}")
            problems.add("malformed", topic, t, problem)
            bad.add(i)
    return out, bad


class InputProblems:
    """Input messages replay skips (``malformed``, ``duplicate``: added to the estimator's skip
    counts) or flags (log time going backwards on a topic), with the first few of each for the warning."""

    EXAMPLES = 3

    def __init__(self, counts: dict[str, int], plan: InputPlan) -> None:
        self.counts = counts
        self.backwards = 0
        self.examples: dict[str, list[str]] = {}
        self.topic_of = {CHANNELS.index(ch): topic for topic, ch in plan.float64.items()}
        if plan.temperature:
            self.topic_of[CHANNELS.index(OIL_TEMPERATURE)] = plan.temperature[0]
        self._last_t = np.full(len(CHANNELS), np.iinfo(np.int64).min, dtype=np.int64)
        self._last_v = np.full(len(CHANNELS), np.nan)

    def add(self, kind: str, topic: str, t_ns: int, reason: str, n: int = 1) -> None:
        if kind == "backwards":
            self.backwards += n
        else:
            self.counts[kind] = self.counts.get(kind, 0) + n
        shown = self.examples.setdefault(kind, [])
        if len(shown) < self.EXAMPLES:
            shown.append(f"{topic} at log time {t_ns} ns{': ' + reason if reason else ''}")

    def check_order(self, codes: np.ndarray, t_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Which messages (in file order) to keep: a repeat of its topic's previous message (same
        log time, same value) is a duplicate and skipped; a log time before its topic's previous
        one is counted as going backwards (and kept: replay orders by log time)."""
        keep = np.ones(len(codes), dtype=bool)
        for code in np.unique(codes).tolist():
            idx = np.flatnonzero(codes == code)
            tt, vv = t_ns[idx], values[idx]
            pt = np.concatenate([self._last_t[code:code + 1], tt[:-1]])
            pv = np.concatenate([self._last_v[code:code + 1], vv[:-1]])
            dup = (tt == pt) & ((vv == pv) | (np.isnan(vv) & np.isnan(pv)))
            back = tt < pt
            topic = self.topic_of.get(code, CHANNELS[code])
            for kind, mask, why in (("duplicate", dup, "same log time and value as the one before"),
                                    ("backwards", back, "log time before the previous message's")):
                if mask.any():
                    self.add(kind, topic, int(tt[mask][0]), why, int(mask.sum()))
            keep[idx[dup]] = False
            self._last_t[code], self._last_v[code] = tt[-1], vv[-1]
        return keep

    def warnings(self) -> list[str]:
        lines = []
        for kind, what in (("malformed", "malformed input messages skipped"),
                           ("duplicate", "duplicated input messages skipped"),
                           ("backwards", "input messages whose log time goes backwards on their topic")):
            n = self.backwards if kind == "backwards" else self.counts.get(kind, 0)
            if n:
                lines.append(f"{n:,} {what} (first: {'; '.join(self.examples.get(kind, []))})")
        return lines


@dataclass
class InputBatch:
    """Decoded input messages in file order (``codes`` index :data:`~rollergear_ros.estimator.CHANNELS`)."""

    codes: np.ndarray
    t_ns: np.ndarray
    values: np.ndarray
    write_inputs: Callable[[BagWriter], None]
    #: the messages' publish times (the node records its inputs' source timestamps there): in file
    #: order only, where arrival pairing's skew detector measures with them; else None
    source_ns: np.ndarray | None = None


def _input_batches(info: BagInfo, plan: InputPlan, batch_size: int, warn: Callable[[str], None],
                   problems: InputProblems, log_time_range: tuple[int, int] | None = None,
                   file_order: bool = False):
    """Batches of decoded inputs: Float64 bags through the numpy chunk reader, others record by record.

    Float64 inputs are sorted by log time, except with ``file_order``: a recording the node made,
    whose inputs stand in the order the node took them (which pairing by publisher timestamps
    depends on, when the node takes one input's backlog before another's).

    Damaged spans of the file are skipped, malformed and duplicated messages too (``problems``);
    each is reported through ``warn`` when the read ends.
    """
    from .fastmcap import ReadState, preload_summary

    state = ReadState(log_time_range=log_time_range)
    preload_summary(info.path, state)
    try:
        if plan.mode == "float64":
            yield from _float64_batches(info, plan, batch_size, state, problems, file_order)
        else:
            yield from _decoded_batches(info, plan, batch_size, state, problems)
    finally:
        for line in state.damage_report() + problems.warnings():
            warn(f"{info.path}: {line}")
        if state.truncated and not state.damaged:
            warn(f"{info.path}: stopped reading: {state.problem}")


def _decoded_batches(info: BagInfo, plan: InputPlan, batch_size: int, state, problems: InputProblems):
    code_of = {c: i for i, c in enumerate(CHANNELS)}
    for raw in iter_raw_batches(info, plan.all_topics, batch_size, state):
        events, bad = decode_batch(raw, plan, info, problems)
        codes = np.array([code_of[c] for _, c, _ in events], dtype=np.int8)
        t = np.array([e[0] for e in events], dtype=np.int64)
        v = np.array([e[2] for e in events], dtype=float)
        keep = problems.check_order(codes, t, v)
        codes, t, v = codes[keep], t[keep], v[keep]

        def write(writer: BagWriter, raw: RawBatch = raw, bad: set[int] = bad) -> None:
            for i, (tp, tt, d) in enumerate(zip(raw.topics, raw.log_time_ns, raw.data)):
                if i not in bad:
                    writer.write_raw(tp, info.topics[tp], tt, d, info.schema_texts.get(info.topics[tp]))

        yield InputBatch(codes, t, v, write)


def _float64_batches(info: BagInfo, plan: InputPlan, batch_size: int, state, problems: InputProblems,
                     file_order: bool = False):
    from .fastmcap import iter_message_arrays, release_count

    code_of = {c: i for i, c in enumerate(CHANNELS)}
    temp_code = code_of[OIL_TEMPERATURE]
    pending: list = []
    count = 0

    def assemble(parts: list) -> InputBatch:
        codes, ts, sources, vals, writes = [], [], [], [], []
        for arrays, lut in parts:
            code = lut[arrays.channel]
            keep = np.flatnonzero(code >= 0)
            c = code[keep]
            v = np.full(len(keep), np.nan)
            good = np.ones(len(keep), dtype=bool)
            f64 = c != temp_code
            if plan.temperature and plan.temperature[1] == MessageType.FLOAT64:
                f64[:] = True
            if f64.any():
                try:
                    v[f64] = arrays.float64(keep[f64])
                except ValueError:  # big-endian, padded or malformed payloads: one by one
                    rows = np.flatnonzero(f64)
                    found: list[tuple[int, str]] = []
                    v[rows] = decode_float64([arrays.payload(i) for i in keep[rows].tolist()], found)
                    for j, reason in found:
                        good[rows[j]] = False
                        problems.add("malformed", problems.topic_of[int(c[rows[j]])],
                                     int(arrays.log_time[keep[rows[j]]]), reason)
            for j in np.flatnonzero(~f64).tolist():
                v[j], reason = _decode_temperature(arrays.payload(int(keep[j])), plan, info)
                if reason:
                    good[j] = False
                    problems.add("malformed", plan.temperature[0], int(arrays.log_time[keep[j]]), reason)
            decodable = keep[good]  # what the output copies: every message a reader can decode
            t = arrays.log_time[keep]
            sub = np.flatnonzero(good)
            good[sub[~problems.check_order(c[sub], t[sub], v[sub])]] = False
            codes.append(c[good])
            ts.append(t[good])
            sources.append(arrays.publish_time[keep][good])
            vals.append(v[good])
            writes.append((arrays, decodable))

        def write(writer: BagWriter) -> None:
            """Copy the input messages in file order; equal-sized payloads go in with one numpy call."""
            for arrays, keep in writes:
                lens = arrays.length[keep]
                fixed = keep[lens == 12]  # Float64 (and any other 12-byte payloads)
                cids = sorted(set(arrays.channel[fixed].tolist()))
                if len(fixed):
                    meta = []
                    for cid in cids:
                        topic, sid, _ = state.channels[cid]
                        type_name = state.schemas[sid][0] if sid in state.schemas else info.topics.get(topic, "")
                        meta.append((topic, type_name, info.schema_texts.get(type_name)))
                    typed = np.array([bool(m[1]) for m in meta])  # a type lost with a damaged chunk: not copied
                    which = np.searchsorted(np.array(cids), arrays.channel[fixed])
                    fixed, which = fixed[typed[which]], (np.cumsum(typed) - 1)[which[typed[which]]]
                    payload = arrays.buf[arrays.offset[fixed][:, None] + np.arange(12)]
                    writer.write_fixed_mixed([m for m in meta if m[1]], which, arrays.log_time[fixed], payload)
                for i in keep[lens != 12].tolist():
                    topic, sid, _ = state.channels[int(arrays.channel[i])]
                    type_name = state.schemas[sid][0] if sid in state.schemas else info.topics.get(topic, "")
                    if not type_name:
                        continue
                    writer.write_raw(
                        topic, type_name, int(arrays.log_time[i]), arrays.payload(i), info.schema_texts.get(type_name)
                    )

        return InputBatch(np.concatenate(codes).astype(np.int8), np.concatenate(ts), np.concatenate(vals), write,
                          np.concatenate(sources))

    carry: InputBatch | None = None

    def in_time_order(batch: InputBatch, final: bool) -> InputBatch:
        """Prepend what the previous batch held back, sort by log time (file order among equal
        times), and hold back messages newer than the oldest channel's last one (not final)."""
        nonlocal carry
        if file_order:
            return batch
        batch.source_ns = None  # sorted by log time: pairing by time needs no publish times
        if carry is not None:
            batch = InputBatch(
                np.concatenate([carry.codes, batch.codes]),
                np.concatenate([carry.t_ns, batch.t_ns]),
                np.concatenate([carry.values, batch.values]),
                batch.write_inputs,
            )
        order = np.argsort(batch.t_ns, kind="stable")
        codes, t, v = batch.codes[order], batch.t_ns[order], batch.values[order]
        carry = None
        if not final:
            cut = release_count(t, codes, ignore_key=temp_code)
            if cut < len(t):
                carry = InputBatch(codes[cut:], t[cut:], v[cut:], batch.write_inputs)
                codes, t, v = codes[:cut], t[:cut], v[:cut]
        return InputBatch(codes, t, v, batch.write_inputs)

    lut_cache: dict[int, np.ndarray] = {}
    for arrays in iter_message_arrays(info.path, state):
        key = len(state.channels)
        if key not in lut_cache:  # channel id -> estimator channel code (-1: not an input)
            lut = np.full(65536, -1, dtype=np.int16)
            for cid, (topic, _sid, _enc) in state.channels.items():
                if topic in plan.float64:
                    lut[cid] = code_of[plan.float64[topic]]
                elif plan.temperature and topic == plan.temperature[0]:
                    lut[cid] = temp_code
            lut_cache = {key: lut}
        pending.append((arrays, lut_cache[key]))
        count += len(arrays)
        if count >= batch_size:
            yield in_time_order(assemble(pending), final=False)
            pending, count = [], 0
    if pending or carry is not None:
        yield in_time_order(
            assemble(pending)
            if pending
            else InputBatch(np.empty(0, np.int8), np.empty(0, np.int64), np.empty(0), lambda w: None),
            final=True,
        )


#: the lead-in of a time slice when an accepted effect has memory: the slice's state starts from the
#: motion of this long before it (a Dahl state is exactly its direction after a fraction of a radian)
MEMORY_LEAD_NS = 60 * 10**9


class TimeWindow:
    """A time slice ``[start_ns, end_ns)`` of a recording (``None``: open), replayed on its own.

    The estimator is fed the messages from ``lead_ns`` before the slice to as much after its end --
    twice the longest the estimator holds anything: the oil temperature (5 s), a motor message
    waiting for its partner (``staleness_s``; 5 s over a lossless arrival delivery) -- so that the
    samples at the slice's edges are paired, and carry the temperature, as in a replay of the whole
    recording; only estimates whose sample time lies in the slice are kept.  The counts
    (samples, input messages, skips, change alarms) are those taken while the slice's own messages
    were pushed.  Slices of one recording therefore add up to the whole replay, except that each
    slice's online adaptation and change detector start from the parameter file (as a recording's do).
    With an effect with memory the lead-in is at least :data:`MEMORY_LEAD_NS`: its state at the
    slice's start is then the whole replay's, unless the gearbox rested that long before it.
    """

    def __init__(self, start_ns: int | None, end_ns: int | None, lead_ns: int) -> None:
        self.start_ns, self.end_ns = start_ns, end_ns
        self.lead_ns = lead_ns
        self.done = False  #: the lead-out has been read: stop reading
        self.input_messages = 0
        self.samples = 0
        self._at_start: tuple[dict[str, int], int] | None = None  # (skip counts, alarms) when the slice began
        self._at_end: tuple[dict[str, int], int] | None = None

    def read_range(self) -> tuple[int, int] | None:
        """The log-time range to read (chunks outside it are skipped unread)."""
        lo = -(2**63) if self.start_ns is None else self.start_ns - self.lead_ns
        hi = 2**63 - 1 if self.end_ns is None else self.end_ns + self.lead_ns
        return lo, hi

    def split(self, batch: InputBatch, estimator) -> Iterator[tuple[np.ndarray, ...]]:
        """The batch's messages before, inside and after the slice, in that order, as ``(codes,
        t_ns, values, source_ns or None)`` (counts are snapshot where the slice begins and ends)."""
        t = batch.t_ns
        lo = -(2**63) if self.start_ns is None else self.start_ns
        hi = 2**63 - 1 if self.end_ns is None else self.end_ns
        phase = (t >= lo).astype(np.int8) + (t >= hi)
        for p in (0, 1, 2):
            sel = phase == p
            if p >= 1 and self._at_start is None and sel.any():
                self._at_start = (dict(estimator.counts), estimator.detector.alarms)
            if p == 2 and sel.any() and self._at_end is None:
                self._at_end = (dict(estimator.counts), estimator.detector.alarms)
            if not sel.any():
                continue
            codes = batch.codes[sel]
            if p == 1:
                self.input_messages += len(codes)
                self.samples += int(np.count_nonzero(codes == 0))
            if p == 2 and int(t[sel].max()) >= hi + self.lead_ns:
                self.done = True
            yield codes, t[sel], batch.values[sel], None if batch.source_ns is None else batch.source_ns[sel]

    def keep(self, b: BatchEstimate | None, acc: _Accumulator) -> BatchEstimate | None:
        """The estimates of samples inside the slice (one before it primes the energy integral)."""
        if b is None or len(b.t_ns) == 0:
            return b
        t = b.t_ns
        inside = np.ones(len(t), bool)
        if self.start_ns is not None:
            before = t < self.start_ns
            if before.any():
                acc.prime(int(t[before].max()))
            inside &= ~before
        if self.end_ns is not None:
            inside &= t < self.end_ns
        return b if inside.all() else b.select(inside)

    def finish(self, summary: ReplaySummary, estimator, acc: _Accumulator) -> None:
        """The slice's own counts in ``summary``."""
        counts_now = (dict(estimator.counts), estimator.detector.alarms)
        # an open start counts from zero (what decoding counted before the first push is the slice's)
        zero = ({k: 0 for k in counts_now[0]}, 0)
        start = zero if self.start_ns is None or self._at_start is None else self._at_start
        end = self._at_end or counts_now
        summary.skipped = {k: end[0][k] - start[0].get(k, 0) for k in end[0]}
        summary.alarms = end[1] - start[1]
        summary.samples = self.samples
        summary.input_messages = self.input_messages
        summary.estimated = acc.n


class GracefulStop:
    """SIGINT/SIGTERM set a flag that long loops check between batches (files stay consistent).

    Installed before any output is opened, so a signal at any moment leaves complete files.  A
    second signal stops at once (``KeyboardInterrupt``) — but not inside :meth:`critical`, where
    one batch's estimates and inputs are written together: there it waits for the section's end.
    Only active in the main thread.
    """

    def __init__(self, announce: bool = True) -> None:
        import signal
        import threading

        self.announce = announce
        self.requested = False
        self._forced = False
        self._critical = 0
        self._old: dict[int, object] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)

    def _handler(self, signum, frame) -> None:  # noqa: ARG002
        if not self.requested:
            self.requested = True
            if self.announce:  # at once: the batch under way and the outputs' closing take a moment
                print("rollergear: interrupted: finishing the batch under way and closing the outputs with "
                      "what was processed (again to stop at once)", file=sys.stderr, flush=True)
        elif self._critical:
            self._forced = True
        else:
            raise KeyboardInterrupt

    @contextmanager
    def critical(self, raise_after: bool = True) -> Iterator[None]:
        """A section a second signal does not cut in two (it stops at the section's end)."""
        self._critical += 1
        try:
            yield
        finally:
            self._critical -= 1
        if raise_after and self._forced and not self._critical:
            raise KeyboardInterrupt

    def restore(self) -> None:
        import signal

        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()


@dataclass
class ReplaySummary:
    """What a replay did (printed, and returned for tests)."""

    bag: str
    input_messages: int = 0
    samples: int = 0
    estimated: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    mean_loss_nm: float = math.nan
    peak_loss_nm: float = math.nan
    energy_lost_j: float = 0.0
    energy_in_j: float = 0.0  #: ∫|T_in·ω_in| dt, the energy through the gearbox
    #: over the samples with a measured loss: the energy through the gearbox and the measured energy lost
    energy_in_measured_j: float = 0.0
    energy_lost_measured_j: float = 0.0
    mean_efficiency: float = math.nan
    residual_rms_nm: float = math.nan
    residual_mean_nm: float = math.nan
    residual_samples: int = 0
    efficiency_samples: int = 0  #: estimates with a finite efficiency (the mean's weight)
    duration_s: float = 0.0
    start_ns: int | None = None  #: first estimated sample
    end_ns: int | None = None  #: last estimated sample
    alarms: int = 0
    interrupted: bool = False
    sync_tolerance_s: float = math.nan  #: the pairing tolerance used
    sample_period_s: float | None = None  #: the motor torque's median message period in the bag
    pairing: str = "timestamp"  #: ``arrival`` for a recording of the node that paired by arrival
    warnings: list[str] = field(default_factory=list)
    coefficients: dict[str, float] = field(default_factory=dict)
    summary_png: str | None = None  #: the summary picture, when one was drawn

    def text(self) -> str:
        lines = [
            f"bag: {self.bag}",
            f"input messages: {self.input_messages:,} ({self.samples:,} motor torque); "
            f"estimated: {self.estimated:,}; log duration {self.duration_s:.1f} s",
        ]
        if self.pairing in ARRIVAL_PAIRINGS:
            lines.append(
                f"pairing: by arrival, as loss_estimator paired them when it recorded this bag (its sample "
                f"period {1e3 * (self.sample_period_s or 0):.3g} ms, arrivals within "
                f"{1e3 * self.sync_tolerance_s:.3g} ms)"
            )
        elif self.sample_period_s:
            lines.append(
                f"pairing: sample period {1e3 * self.sample_period_s:.3g} ms, inputs within "
                f"{1e3 * self.sync_tolerance_s:.3g} ms form one sample"
            )
        skipped = {k: v for k, v in self.skipped.items() if v}
        lines.append("skipped: " + (", ".join(f"{v:,} {k.replace('_', ' ')}" for k, v in skipped.items()) or "none"))
        lines.append(
            f"loss torque: mean {self.mean_loss_nm:.4f} N·m, peak {self.peak_loss_nm:.4f} N·m; "
            f"energy lost {self.energy_lost_j:.1f} J; mean efficiency "
            + ("n/a" if math.isnan(self.mean_efficiency) else f"{100 * self.mean_efficiency:.2f} %")
        )
        if self.residual_samples:
            lines.append(
                f"residual (measured − estimated loss): RMS {self.residual_rms_nm:.4f} N·m over "
                f"{self.residual_samples:,} samples; change alarms: {self.alarms}"
            )
        if self.coefficients:
            lines.append("adapted coefficients: " + ", ".join(f"{k} {v:.4g}" for k, v in self.coefficients.items()))
        if self.interrupted:
            lines.append("INTERRUPTED: outputs hold everything processed up to the interrupt")
        lines.extend(f"warning: {w}" for w in self.warnings)
        return "\n".join(lines)


class _Accumulator:
    """Running sums for the summary."""

    def __init__(self) -> None:
        self.n = 0
        self.loss_sum = 0.0
        self.peak = 0.0
        self.energy = 0.0
        self.energy_in = 0.0
        self.energy_in_meas = 0.0
        self.energy_lost_meas = 0.0
        self.res_sum = 0.0
        self.eta_sum = 0.0
        self.eta_n = 0
        self.res_sq = 0.0
        self.res_n = 0
        self.last_t: int | None = None
        self.first_t: int | None = None
        self.dt_ns = 0
        self.trace = None  #: a :class:`.replay_plot.SummaryTrace` when a summary picture is drawn

    def prime(self, last_t_ns: int) -> None:
        """A sample before a time slice: the slice's first sample integrates from it."""
        self.last_t = last_t_ns

    def add(self, b: BatchEstimate) -> None:
        if len(b.t_ns) == 0:
            return
        if self.trace is not None:
            self.trace.add(b)
        mag = np.abs(b.loss_torque_nm)
        self.n += len(mag)
        self.loss_sum += float(mag.sum())
        self.peak = max(self.peak, float(mag.max()))
        t = np.asarray(b.t_ns, dtype=np.int64)
        if self.first_t is None:
            self.first_t = int(t[0])
        prev = self.last_t if self.last_t is not None else int(t[0])
        dt = np.diff(np.concatenate([[prev], t])).astype(float)
        typical = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
        if typical > 0:
            self.dt_ns = typical
        # integrate P·dt; gaps longer than 5 sample periods (missing data) are not integrated
        dt = np.where((dt > 0) & (dt <= 5 * max(self.dt_ns, 1.0)), dt, 0.0)
        self.energy += float(np.sum(b.loss_power_w * dt) * 1e-9)
        p_in = np.abs(b.torque_nm * b.speed_rad_s)
        self.energy_in += float(np.sum(p_in * dt) * 1e-9)
        meas = np.isfinite(b.measured_loss_nm)
        if meas.any():
            self.energy_in_meas += float(np.sum(p_in[meas] * dt[meas]) * 1e-9)
            p_lost = b.measured_loss_nm[meas] * np.abs(b.speed_rad_s[meas])
            self.energy_lost_meas += float(np.sum(p_lost * dt[meas]) * 1e-9)
        self.last_t = int(t[-1])
        eta = b.efficiency[np.isfinite(b.efficiency)]
        self.eta_sum += float(eta.sum())
        self.eta_n += len(eta)
        r = b.residual_nm[np.isfinite(b.residual_nm)]
        self.res_sq += float(np.sum(r * r))
        self.res_sum += float(np.sum(r))
        self.res_n += len(r)


def recorded_pairing(path: Path, plan: InputPlan, period_s: float | None) -> tuple[str, float | None, bool]:
    """How to pair the bag's Float64 inputs, the sample period that sets the tolerance, and whether
    to take them in file order.

    A recording ``loss_estimator`` made (its ``rollergear_recording`` metadata) logged its inputs
    at the times it paired them by -- arrival times, or publisher timestamps -- in the order it took
    them, so replay pairs them as the node did: by its pairing and its sample period, in file order.
    Any other bag: ``("timestamp", period_s, False)``.
    """
    recording = read_metadata(path, Metadata.RECORDING) if plan.mode == "float64" else None
    if recording and (recording.get("pairing") in ARRIVAL_PAIRINGS
                      or recording.get("input_log_time") == "source_timestamp"):
        try:
            node_period_s = float(recording.get("sample_period_s", "nan"))
        except ValueError:
            node_period_s = math.nan
        if math.isfinite(node_period_s) and node_period_s > 0:
            return recording["pairing"], node_period_s, True
    return "timestamp", period_s, False


def replay(
    bag: str | Path,
    config: Config,
    topics: TopicMap = TopicMap(),
    out_mcap: str | Path | None = None,
    rrd: str | Path | None = None,
    show_progress: bool | None = None,
    batch_size: int = 100_000,
    warn: Callable[[str], None] | None = None,
    collect: bool = False,
    window_ns: tuple[int | None, int | None] | None = None,
    summary_png: str | Path | None = None,
    exports: Sequence[tuple[str, str | Path]] = (),
) -> tuple[ReplaySummary, list[BatchEstimate]]:
    """Replay ``bag`` through the estimator; returns the summary (and all estimates if ``collect``).

    ``summary_png``: draw the summary picture there (:mod:`.replay_plot`), also of an interrupted
    replay (what was processed).  ``exports``: ``(kind, path)`` tables of the estimates with their
    inputs, a row per sample (:mod:`.exports`: ``csv``, ``parquet``, ``mf4``).

    ``window_ns``: a time slice ``[start, end)`` of the recording (``None``: open): only its samples
    are estimated and summed up, so that the slices of a long recording, replayed apart, add up to
    it (:class:`TimeWindow`).  Not with outputs (``out_mcap``, ``rrd``).
    """
    if window_ns is not None and (out_mcap or rrd or summary_png or exports):
        raise UsageError("a time slice of a recording is replayed without outputs")
    stop = GracefulStop()  # first: from here on a signal leaves complete files
    try:
        return _replay(bag, config, topics, out_mcap, rrd, show_progress, batch_size, warn, collect, stop,
                       window_ns, summary_png, exports)
    finally:
        stop.restore()


def _replay(bag, config, topics, out_mcap, rrd, show_progress, batch_size, warn, collect,
            stop: GracefulStop, window_ns, summary_png, exports) -> tuple[ReplaySummary, list[BatchEstimate]]:
    warnings: list[str] = []

    def _warn(msg: str) -> None:
        warnings.append(msg)
        if warn:
            warn(msg)

    info = inspect_bag(bag)
    if info.truncated or not info.indexed:
        lost = info.bytes_total - info.bytes_readable
        _warn(
            f"{info.path} has no index (summary/footer): a recording cut short? Readable: "
            f"{info.message_count:,} messages; {lost:,} trailing bytes ({100 * lost / max(info.bytes_total, 1):.1f} %) "
            "could not be read"
            if info.truncated
            else f"{info.path} has no index; read linearly"
        )
    plan = plan_inputs(info, topics)
    period_s = median_period_s(info.path, plan.joint_states or topics.motor_torque)
    pairing, period_s, file_order = recorded_pairing(info.path, plan, period_s)
    estimator = Estimator(config, pairing=pairing, sample_period_s=period_s)
    problems = InputProblems(estimator.counts, plan)
    window = None
    if window_ns is not None:
        sync = estimator.sync
        lead_ns = 2 * max(sync.hold_ns, sync.temperature_hold_ns)
        if estimator.has_memory:  # an effect with memory: its state settles in the lead-in's motion
            lead_ns = max(lead_ns, MEMORY_LEAD_NS)
        window = TimeWindow(*window_ns, lead_ns=lead_ns)
    summary = ReplaySummary(
        str(bag), sync_tolerance_s=estimator.sync_tolerance_s, sample_period_s=period_s, pairing=pairing
    )
    acc = _Accumulator()
    release_lag_ns = 2 * max(estimator.sync.hold_ns, estimator.sync.tolerance_ns)  # output held back
    collected: list[BatchEstimate] = []
    total = sum(info.counts.get(t, 0) for t in plan.all_topics)
    sink = collected if collect else None
    if summary_png:
        from .replay_plot import SummaryTrace

        acc.trace = SummaryTrace(info.counts.get(plan.joint_states or topics.motor_torque, 0))
    writer = rlog = bar = None
    tables: list = []  # the exports being written
    completed = False  # an error (not an interrupt) leaves no output in place of an existing one
    try:
        with stop.critical():  # outputs are opened whole
            writer = _output_writer(out_mcap, info, config, topics) if out_mcap else None
            if exports:
                from .exports import Export

                tables = [Export(kind, path) for kind, path in exports]
            if rrd:
                from .review import RerunLog, SkipEvents

                rlog = RerunLog("rollergear_replay", rrd, breakdown_terms=estimator.model.nonzero_terms(),
                                with_effects=bool(config.effects.enabled()), replace_atomically=True)
                skip_events = SkipEvents()
        bar = TimedProgress("replay", total, "msg", enabled=show_progress).start()
        for batch in _input_batches(info, plan, batch_size, _warn, problems,
                                    window.read_range() if window else None, file_order):
            if stop.requested:
                summary.interrupted = True
                break
            if window is not None:  # a time slice (no outputs): its lead-in, its samples, its lead-out
                for codes, t, v, source in window.split(batch, estimator):
                    _emit(window.keep(estimator.push_many(codes, t, v, source), acc), None, None, acc, sink,
                          topics, ())
            else:
                with stop.critical():  # one batch's estimates and inputs, both or neither
                    summary.input_messages += len(batch.codes)
                    _emit(estimator.push_many(batch.codes, batch.t_ns, batch.values, batch.source_ns), writer,
                          rlog, acc, sink, topics, tables)
                    if rlog and len(batch.t_ns):
                        _skip_event(rlog, skip_events, estimator, int(batch.t_ns.max()))
                    if writer:
                        batch.write_inputs(writer)
                        if len(batch.t_ns):  # no later estimate can be older than its inputs' hold
                            writer.release(int(batch.t_ns.max()) - release_lag_ns)
            bar.update(len(batch.codes))
            if window is not None and window.done:
                break
        else:
            with stop.critical():
                _emit(window.keep(estimator.flush(), acc) if window else estimator.flush(), writer, rlog, acc, sink,
                      topics, tables)
                if rlog and acc.last_t is not None:
                    _skip_event(rlog, skip_events, estimator, acc.last_t)
        completed = True
    except KeyboardInterrupt:
        summary.interrupted = completed = True  # what was processed so far is a whole output
    finally:
        with stop.critical(raise_after=False):  # outputs are closed whole, whatever comes
            if bar:
                bar.close()
            if writer:
                writer.close(commit=completed)
            if rlog:
                rlog.close(commit=completed)
            for table in tables:
                table.close(commit_file=completed)
    summary.interrupted |= stop.requested  # a signal near the end is not ignored either
    summary.samples = estimator.motor_messages
    summary.estimated = estimator.estimated
    summary.skipped = dict(estimator.counts)
    summary.alarms = estimator.detector.alarms
    if window is not None:
        window.finish(summary, estimator, acc)
    unpaired = summary.skipped.get("unpaired", 0)
    if summary.samples and unpaired > 0.05 * summary.samples:
        _warn(
            f"{unpaired:,} of {summary.samples:,} motor messages had no partner within the pairing tolerance of "
            f"{1e3 * estimator.sync_tolerance_s:.2g} ms: do the input topics share one time base? "
            "Set estimator.sync_tolerance_s (below half the sample period) if they are logged further apart"
        )
    if acc.n:
        summary.mean_loss_nm = acc.loss_sum / acc.n
        summary.peak_loss_nm = acc.peak
        summary.energy_lost_j = acc.energy
        summary.energy_in_j = acc.energy_in
        summary.energy_in_measured_j = acc.energy_in_meas
        summary.energy_lost_measured_j = acc.energy_lost_meas
        summary.duration_s = ((acc.last_t or 0) - (acc.first_t or 0)) * 1e-9
        summary.start_ns, summary.end_ns = acc.first_t, acc.last_t
    if acc.eta_n:
        summary.mean_efficiency = acc.eta_sum / acc.eta_n
        summary.efficiency_samples = acc.eta_n
    if acc.res_n:
        summary.residual_rms_nm = math.sqrt(acc.res_sq / acc.res_n)
        summary.residual_mean_nm = acc.res_sum / acc.res_n
        summary.residual_samples = acc.res_n
    summary.coefficients = estimator.coefficients()
    summary.warnings = warnings
    if acc.trace is not None and acc.n:
        from .replay_plot import plot_summary

        try:  # a picture of what was processed, also after an interrupt; a second one abandons it
            summary.summary_png = str(plot_summary(acc.trace, config, summary_png, f"replay of {Path(bag).name}"))
        except KeyboardInterrupt:
            _warn(f"interrupted: no summary picture {summary_png}")
        summary.interrupted |= stop.requested
    return summary, collected


def _output_writer(path: str | Path, info: BagInfo, config: Config, topics: TopicMap) -> BagWriter:
    """The estimates' MCAP: in log-time order, the outputs with the QoS the node offers them with,
    and its provenance (metadata ``rollergear_provenance``: package version, source recording,
    parameters with the accepted effects, command line)."""
    import datetime

    from .interface import OUTPUT_QUEUE_DEPTH, package_version
    from .params import config_to_yaml

    qos = offered_qos_yaml(reliable=True, depth=OUTPUT_QUEUE_DEPTH)
    outputs = (topics.loss_torque, topics.loss_power, topics.efficiency, topics.residual_torque, topics.loss_estimate)
    writer = BagWriter(path, offered_qos={t: qos for t in outputs}, background=True)
    source = Path(info.path)
    writer.add_metadata(Metadata.PROVENANCE, {
        "package": "rollergear_ros", "version": package_version(),
        "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "source": str(source.resolve()), "source_bytes": str(info.bytes_total),
        "source_messages": str(info.message_count),
        "accepted_effects": ", ".join(config.effects.enabled()) or "none",
        "parameters": config_to_yaml(config), "command": " ".join(sys.argv)})
    return writer


def _emit(b: BatchEstimate | None, writer: BagWriter | None, rlog, acc: _Accumulator, collected: list | None,
          tm: TopicMap, tables: Sequence) -> None:
    """Hand one batch of estimates to the writers, the summary and the caller."""
    if b is None:
        return
    acc.add(b)
    if collected is not None:
        collected.append(b)
    has_res = np.isfinite(b.residual_nm)
    if writer:
        writer.write_float64_series(tm.loss_torque, b.t_ns, b.loss_torque_nm)
        writer.write_float64_series(tm.loss_power, b.t_ns, b.loss_power_w)
        writer.write_float64_series(tm.efficiency, b.t_ns, b.efficiency)
        if has_res.any():
            writer.write_float64_series(tm.residual_torque, b.t_ns[has_res], b.residual_nm[has_res])
        payloads = stamped.codec().payloads(b.t_ns, np.column_stack(stamped.estimate_values(b)))
        writer.write_fixed(tm.loss_estimate, MessageType.JOINT_STATE, b.t_ns, payloads)
    if rlog:
        rlog.send_estimates(b)
    for table in tables:
        table.add(b)


def _skip_event(rlog, skip_events, estimator: Estimator, t_ns: int) -> None:
    """The samples skipped since the last event, as a warning on the rerun timeline at ``t_ns``."""
    text = skip_events.since_last(estimator.counts)
    if text:
        rlog.events([t_ns], [text], "WARN")
