"""Replay's input side: which topics a recording's inputs are on, decoding them batch by batch
(Float64 through the numpy chunk reader, other types record by record), and the problems found
on the way (damaged spans, malformed, duplicated and out-of-order messages).  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from collections.abc import Callable

import numpy as np

from ..base.errors import BagError
from ..recordings.baginfo import BagInfo, RawBatch, iter_raw_batches, median_period_s, read_metadata
from ..recordings.bagwriter import BagWriter
from ..recordings.messages import TopicMap, cdr_problem, decode_float64, decoder_for, encode_float64, float64_problem
from ..recordings.records import byte_rows
from ..base.errors import damage_totals, lost_share
from ..core.pairing import ARRIVAL_PAIRINGS, CHANNELS, OIL_TEMPERATURE, OUT_SPEED, OUT_TORQUE, SPEED, TORQUE
from ..base.interface import MessageType, Metadata

__all__ = ["InputBatch", "InputPlan", "InputProblems", "decode_batch", "input_batches", "plan_inputs",
           "recorded_pairing"]


@dataclass
class InputPlan:
    """Which topics of a bag feed which estimator channel, and how to decode them."""

    mode: str  # "float64" or "joint_state"
    float64: dict[str, str]  # topic -> channel
    joint_states: str | None
    temperature: tuple[str, str] | None  # (topic, type)
    topics: TopicMap
    #: read the Float64 inputs in file order rather than by log time: a recording the node made,
    #: whose inputs stand in the order the node took them (:func:`recorded_pairing`)
    file_order: bool = False

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


def _decode_temperature(payload: bytes, plan: InputPlan, info: BagInfo) -> tuple[float, str | None, int]:
    """An oil temperature message (Float64 or sensor_msgs/Temperature) -> (°C, problem or None, its
    header stamp in ns: 0 where it has none)."""
    temp_type = plan.temperature[1]
    if temp_type == MessageType.FLOAT64:
        problem = float64_problem(payload)
        return (math.nan, problem, 0) if problem else (float(decode_float64([payload])[0]), None, 0)
    problem = cdr_problem(payload)
    if problem:
        return math.nan, problem, 0
    try:
        msg = decoder_for(temp_type, info.schema_texts.get(temp_type))(payload)
    except Exception as exc:  # noqa: BLE001 - the CDR decoder raises assorted errors on a bad payload
        return math.nan, f"cannot decode {temp_type} ({type(exc).__name__})", 0
    return float(msg.temperature), None, _stamp_ns(msg)


def _stamp_ns(msg) -> int:
    """A message's header stamp in ns (0: none given)."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def decode_batch(batch: RawBatch, plan: InputPlan, info: BagInfo,
                 problems: InputProblems | None = None) -> tuple[list[tuple[int, str, float, int]], set[int]]:
    """Decode a raw batch of a JointState recording into ``(time, channel, value, log time)`` in file
    order (time: a message's header stamp, its log time where the stamp is 0), and the indices of the
    messages that could not be decoded.

    Float64 recordings take the vectorised path (:func:`_float64_batches`); non-finite values are
    kept.  A message that cannot be decoded is skipped and added to ``problems`` (raised without).
    """
    out: list[tuple[int, str, float, int]] = []
    bad: set[int] = set()
    tp = plan.topics
    temp_topic = plan.temperature[0] if plan.temperature else None
    js_dec = decoder_for(MessageType.JOINT_STATE, info.schema_texts.get(MessageType.JOINT_STATE))
    for i, (topic, t, data) in enumerate(zip(batch.topics, batch.log_time_ns, batch.data)):
        if topic == temp_topic:
            value, problem, stamp = _decode_temperature(data, plan, info)
            if problem is None:  # on the joint states' clock, their header stamps, as the node takes it
                out.append((stamp or t, OIL_TEMPERATURE, value, t))
        elif topic == plan.joint_states:
            problem = cdr_problem(data)
            if problem is None:
                try:
                    msg = js_dec(data)
                except Exception as exc:  # noqa: BLE001 - the CDR decoder raises assorted errors
                    problem = f"cannot decode {MessageType.JOINT_STATE} ({type(exc).__name__})"
            if problem is None:
                names = list(msg.name)
                sample_t = _stamp_ns(msg) or t  # the sample's own stamp, as the node pairs and aligns by
                for joint, ch_t, ch_w in ((tp.input_joint, TORQUE, SPEED), (tp.output_joint, OUT_TORQUE, OUT_SPEED)):
                    if joint in names:
                        k = names.index(joint)
                        out.append((sample_t, ch_t, float(msg.effort[k]) if k < len(msg.effort) else math.nan, t))
                        out.append((sample_t, ch_w, float(msg.velocity[k]) if k < len(msg.velocity) else math.nan,
                                    t))
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
        self.damaged: list = []  #: the :class:`~recordings.fastmcap.DamagedSpan` the read skipped
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
    """Decoded input messages in file order (``codes`` index :data:`~core.estimator.CHANNELS`)."""

    codes: np.ndarray
    t_ns: np.ndarray
    values: np.ndarray
    write_inputs: Callable[[BagWriter], None]
    #: the messages' publish times (the node records its inputs' source timestamps there): in file
    #: order only, where arrival pairing's skew detector measures with them; else None
    source_ns: np.ndarray | None = None
    #: the log times of the recording's messages these came from, where one carries several channels
    #: (a JointState: torque and speed of two joints); None: one value per message
    message_t_ns: np.ndarray | None = None
    #: each value's message's log time, where the value is taken at another time (a JointState's header
    #: stamp): the clock the node's recorded parameter changes are placed on; None: ``t_ns``
    event_log_ns: np.ndarray | None = None

    @property
    def message_count(self) -> int:
        """The recording's messages read for this batch (as ``rollergear info`` counts them)."""
        return len(self.codes) if self.message_t_ns is None else len(self.message_t_ns)

    def messages_between(self, lo_ns: int, hi_ns: int, in_range: np.ndarray) -> int:
        """The messages of this batch with a log time in ``[lo_ns, hi_ns)`` (``in_range``: which of
        its values lie there, when one value is one message)."""
        if self.message_t_ns is None:
            return int(np.count_nonzero(in_range))
        return int(np.count_nonzero((self.message_t_ns >= lo_ns) & (self.message_t_ns < hi_ns)))


def input_batches(info: BagInfo, plan: InputPlan, batch_size: int, warn: Callable[[str], None],
                  problems: InputProblems, log_time_range: tuple[int, int] | None = None):
    """Batches of decoded inputs: Float64 bags through the numpy chunk reader, others record by record.

    Float64 inputs are sorted by log time, except with ``plan.file_order``: a recording the node
    made, whose inputs stand in the order the node took them (which pairing by publisher timestamps
    depends on, when the node takes one input's backlog before another's).

    Damaged spans of the file are skipped, malformed and duplicated messages too (``problems``);
    each is reported through ``warn`` when the read ends.
    """
    from ..recordings.fastmcap import ReadState, preload_summary

    state = ReadState(log_time_range=log_time_range)
    preload_summary(info.path, state)
    try:
        if plan.mode == "float64":
            yield from _float64_batches(info, plan, batch_size, state, problems, plan.file_order)
        else:
            yield from _decoded_batches(info, plan, batch_size, state, problems)
    finally:
        problems.damaged = list(state.damaged)
        for line in state.damage_report() + problems.warnings():
            warn(f"{info.path}: {line}")
        if state.truncated and not state.damaged:
            warn(f"{info.path}: stopped reading: {state.problem}")


def _decoded_batches(info: BagInfo, plan: InputPlan, batch_size: int, state, problems: InputProblems):
    code_of = {c: i for i, c in enumerate(CHANNELS)}
    for raw in iter_raw_batches(info, plan.all_topics, batch_size, state):
        events, bad = decode_batch(raw, plan, info, problems)
        codes = np.array([code_of[e[1]] for e in events], dtype=np.int8)
        t = np.array([e[0] for e in events], dtype=np.int64)
        v = np.array([e[2] for e in events], dtype=float)
        logged = np.array([e[3] for e in events], dtype=np.int64)
        keep = problems.check_order(codes, t, v)
        codes, t, v, logged = codes[keep], t[keep], v[keep], logged[keep]

        def write(writer: BagWriter, raw: RawBatch = raw, bad: set[int] = bad) -> None:
            for i, (tp, tt, d) in enumerate(zip(raw.topics, raw.log_time_ns, raw.data)):
                if i not in bad:
                    writer.write_raw(tp, info.topics[tp], tt, d, info.schema_texts.get(info.topics[tp]))

        read = np.array([tt for i, tt in enumerate(raw.log_time_ns) if i not in bad], dtype=np.int64)
        yield InputBatch(codes, t, v, write, message_t_ns=read, event_log_ns=logged)


def _float64_batches(info: BagInfo, plan: InputPlan, batch_size: int, state, problems: InputProblems,
                     file_order: bool = False):
    """Batches of a Float64 recording's inputs through the numpy chunk reader, in log-time order
    (file order with ``file_order``)."""
    from ..recordings.fastmcap import iter_message_arrays

    code_of = {c: i for i, c in enumerate(CHANNELS)}
    temp_code = code_of[OIL_TEMPERATURE]
    decode = _PartDecoder(plan, info, problems, temp_code)
    order = _TimeOrder(temp_code, file_order)
    pending: list = []
    count = 0
    lut_cache: dict[int, np.ndarray] = {}
    for arrays in iter_message_arrays(info.path, state):
        key = len(state.channels)
        if key not in lut_cache:  # channel id -> estimator channel code (-1: not an input)
            lut_cache = {key: _channel_codes(state, plan, code_of, temp_code)}
        pending.append((arrays, lut_cache[key]))
        count += len(arrays)
        if count >= batch_size:
            yield order(_assemble(pending, decode, state, info), final=False)
            pending, count = [], 0
    if pending or order.carry is not None:
        yield order(
            _assemble(pending, decode, state, info)
            if pending
            else InputBatch(np.empty(0, np.int8), np.empty(0, np.int64), np.empty(0), lambda w: None),
            final=True,
        )


def _channel_codes(state, plan: InputPlan, code_of: dict[str, int], temp_code: int) -> np.ndarray:
    """MCAP channel id -> estimator channel code (-1: not an input), for the channels read so far."""
    lut = np.full(65536, -1, dtype=np.int16)
    for cid, (topic, _sid, _enc) in state.channels.items():
        if topic in plan.float64:
            lut[cid] = code_of[plan.float64[topic]]
        elif plan.temperature and topic == plan.temperature[0]:
            lut[cid] = temp_code
    return lut


class _PartDecoder:
    """Decodes one chunk's messages of the input channels (Float64 vectorised; the temperature one
    by one), setting aside malformed and out-of-order messages (``problems``)."""

    def __init__(self, plan: InputPlan, info: BagInfo, problems: InputProblems, temp_code: int) -> None:
        self.plan, self.info, self.problems, self.temp_code = plan, info, problems, temp_code

    def __call__(self, arrays, lut: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(codes, log times, publish times, values, decodable)`` of the part's input messages;
        ``decodable``: the indices of the messages the output copies (every one a reader can decode)."""
        plan, problems = self.plan, self.problems
        code = lut[arrays.channel]
        keep = np.flatnonzero(code >= 0)
        c = code[keep]
        v = np.full(len(keep), np.nan)
        good = np.ones(len(keep), dtype=bool)
        f64 = c != self.temp_code
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
            v[j], reason, _stamp = _decode_temperature(arrays.payload(int(keep[j])), plan, self.info)
            if reason:
                good[j] = False
                problems.add("malformed", plan.temperature[0], int(arrays.log_time[keep[j]]), reason)
        decodable = keep[good]
        t = arrays.log_time[keep]
        sub = np.flatnonzero(good)
        good[sub[~problems.check_order(c[sub], t[sub], v[sub])]] = False
        return c[good], t[good], arrays.publish_time[keep][good], v[good], decodable


def _assemble(parts: list, decode: _PartDecoder, state, info: BagInfo) -> InputBatch:
    """One batch of the decoded parts, in file order, with the copy of their input messages."""
    codes, ts, sources, vals, writes = [], [], [], [], []
    for arrays, lut in parts:
        c, t, source, v, decodable = decode(arrays, lut)
        codes.append(c)
        ts.append(t)
        sources.append(source)
        vals.append(v)
        writes.append((arrays, decodable))
    return InputBatch(np.concatenate(codes).astype(np.int8), np.concatenate(ts), np.concatenate(vals),
                      partial(_copy_inputs, writes=writes, state=state, info=info), np.concatenate(sources))


def _copy_inputs(writer: BagWriter, writes: list, state, info: BagInfo) -> None:
    """Copy the input messages in file order; the payloads of one length go in with one numpy call
    (a Float64 payload that is not the canonical 12 bytes, one by one as those)."""
    for arrays, keep in writes:
        lens = arrays.length[keep]
        canonical = lens == 12  # Float64 (and any other 12-byte payloads): all but a few
        for length in [12, *np.unique(lens[~canonical]).tolist()]:
            sel = keep[canonical if length == 12 else lens == length]
            if not len(sel):
                continue
            cids = np.flatnonzero(np.bincount(arrays.channel[sel])).tolist()
            meta = []
            for cid in cids:
                topic, sid, _ = state.channels[cid]
                type_name = state.schemas[sid][0] if sid in state.schemas else info.topics.get(topic, "")
                meta.append((topic, type_name, info.schema_texts.get(type_name)))
            which = np.searchsorted(np.array(cids), arrays.channel[sel])
            # a type lost with a damaged chunk: not copied; padded or big-endian Float64: re-encoded
            as_is = np.array([bool(m[1]) and (length == 12 or m[1] != MessageType.FLOAT64) for m in meta])
            fixed, fixed_which = sel[as_is[which]], (np.cumsum(as_is) - 1)[which[as_is[which]]]
            if len(fixed):
                payload = byte_rows(arrays.buf, length)[arrays.offset[fixed]] if length else \
                    np.empty((len(fixed), 0), dtype=np.uint8)
                writer.write_fixed_mixed([m for m, ok in zip(meta, as_is.tolist()) if ok], fixed_which,
                                         arrays.log_time[fixed], payload)
            for i in sel[~as_is[which]].tolist():
                topic, type_name, text = meta[cids.index(int(arrays.channel[i]))]
                if type_name:  # copied as the canonical 12 bytes (every reader decodes those)
                    payload = encode_float64(decode_float64([arrays.payload(i)]))[0]
                    writer.write_raw(topic, type_name, int(arrays.log_time[i]), payload, text)


class _TimeOrder:
    """Batches in log-time order across batch boundaries: what a batch holds back (newer than the
    oldest channel's last message) goes in front of the next (``file_order``: as they come)."""

    def __init__(self, temp_code: int, file_order: bool) -> None:
        self.temp_code, self.file_order = temp_code, file_order
        self.carry: InputBatch | None = None

    def __call__(self, batch: InputBatch, final: bool) -> InputBatch:
        """Prepend what the previous batch held back, sort by log time (file order among equal
        times), and hold back messages newer than the oldest channel's last one (not final)."""
        from ..recordings.logorder import release_count

        if self.file_order:
            return batch
        batch.source_ns = None  # sorted by log time: pairing by time needs no publish times
        carry = self.carry
        if carry is not None:
            batch = InputBatch(
                np.concatenate([carry.codes, batch.codes]),
                np.concatenate([carry.t_ns, batch.t_ns]),
                np.concatenate([carry.values, batch.values]),
                batch.write_inputs,
            )
        order = np.argsort(batch.t_ns, kind="stable")
        codes, t, v = batch.codes[order], batch.t_ns[order], batch.values[order]
        self.carry = None
        if not final:
            cut = release_count(t, codes, ignore_key=self.temp_code)
            if cut < len(t):
                self.carry = InputBatch(codes[cut:], t[cut:], v[cut:], batch.write_inputs)
                codes, t, v = codes[:cut], t[:cut], v[:cut]
        return InputBatch(codes, t, v, batch.write_inputs)


def paired_plan(info: BagInfo, topics: TopicMap) -> tuple[InputPlan, str, float | None]:
    """The inputs' plan (:func:`plan_inputs`) in the order to take them, how to pair them and the
    sample period (:func:`recorded_pairing`): what replay and predict start from."""
    plan = plan_inputs(info, topics)
    period_s = median_period_s(info.path, plan.joint_states or topics.motor_torque)
    pairing, period_s, file_order = recorded_pairing(info.path, plan, period_s)
    return replace(plan, file_order=file_order), pairing, period_s


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
                      or recording.get("input_log_time") in ("source_timestamp", "sequence_clock")):
        try:
            node_period_s = float(recording.get("sample_period_s", "nan"))
        except ValueError:
            node_period_s = math.nan
        if math.isfinite(node_period_s) and node_period_s > 0:
            return recording["pairing"], node_period_s, True
    return "timestamp", period_s, False


def damaged_share(info: BagInfo, problems: InputProblems, nothing_read: bool) -> float:
    """The share of the recording its damaged spans cost (:func:`base.errors.lost_share`; 0: none
    found); damage that left nothing readable (``nothing_read``) is a :class:`BagError`."""
    if not problems.damaged:
        return 0.0
    if nothing_read:
        damaged_bytes, lost = damage_totals(problems.damaged)
        raise BagError(f"{info.path}: nothing readable: {len(problems.damaged)} damaged span(s), "
                       f"{damaged_bytes:,} bytes{f', {lost:,} messages' if lost else ''} lost; no output written")
    return lost_share(problems.damaged, info.bytes_total, info.message_count)
