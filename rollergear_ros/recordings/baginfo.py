"""What an MCAP bag holds and its raw messages: :func:`inspect_bag` (topics, types, counts, time
span; from the summary, or by scanning a recording without a usable one and saying how far it is
readable), its metadata records, and :func:`iter_raw_batches` over the numpy chunk reader
(:mod:`.fastmcap`, which skips and lists damaged spans).  No rclpy import here.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding

from ..base.errors import BagError

@dataclass
class BagInfo:
    """What a bag holds: topics with types and counts; whether its index (summary) is intact."""

    path: Path
    topics: dict[str, str]  #: topic -> schema (type) name
    counts: dict[str, int]  #: topic -> message count (None-free; counted when no summary)
    schema_texts: dict[str, str] = field(default_factory=dict)  #: type -> ros2msg text
    indexed: bool = True
    truncated: bool = False
    bytes_total: int = 0
    bytes_readable: int = 0
    start_ns: int = 0
    end_ns: int = 0
    problem: str = ""

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def describe_topics(self) -> str:
        return ", ".join(f"{t} [{ty}]" for t, ty in sorted(self.topics.items())) or "no topics"


def _check_mcap(path: Path) -> None:
    if not path.exists():
        raise BagError(f"{path} does not exist")
    if path.is_dir():
        mcaps = sorted(path.glob("*.mcap"))
        raise BagError(
            f"{path} is a directory; pass the .mcap file inside it" + (f" (e.g. {mcaps[0]})" if mcaps else "")
        )
    if not path.is_file():  # a FIFO or a device would block or never end
        raise BagError(f"{path} is not a regular file")
    with path.open("rb") as fh:
        magic = fh.read(8)
    if magic != b"\x89MCAP0\r\n":
        raise BagError(f"{path} is not an MCAP file (it does not begin with MCAP's magic bytes)")


def read_metadata(path: str | Path, name: str) -> dict[str, str] | None:
    """The bag's MCAP metadata record ``name`` (string key/values), or None when it has none or
    it cannot be read (a recording without its summary)."""
    try:
        with Path(path).open("rb") as fh:
            for md in make_reader(fh).iter_metadata():
                if md.name == name:
                    return dict(md.metadata)
    except SUMMARY_ERRORS:
        return None
    return None


#: what the ``mcap`` library raises on a damaged summary (lengths, offsets and ids it trusts)
SUMMARY_ERRORS = (McapError, struct.error, ValueError, EOFError, KeyError, IndexError, OSError, OverflowError)


def _from_summary(path: Path, size: int, summary) -> BagInfo:
    """The bag's topics, types and counts from its summary (KeyError when the summary contradicts itself)."""
    topics = {c.topic: (summary.schemas[c.schema_id].name if c.schema_id else "") for c in summary.channels.values()}
    texts = {s.name: s.data.decode(errors="replace") for s in summary.schemas.values()}
    enc = {s.encoding for s in summary.schemas.values()} | {c.message_encoding for c in summary.channels.values()}
    counts: dict[str, int] = {}
    for cid, n in summary.statistics.channel_message_counts.items():
        topic = summary.channels[cid].topic
        counts[topic] = counts.get(topic, 0) + n
    info = BagInfo(path, topics, counts, texts, True, False, size, size, summary.statistics.message_start_time,
                   summary.statistics.message_end_time)
    _check_encodings(info, enc)
    return info


def inspect_bag(path: str | Path) -> BagInfo:
    """Read the bag's summary; without a usable one (a recording cut by a crash, a damaged
    summary) scan what is readable."""
    path = Path(path)
    _check_mcap(path)
    size = path.stat().st_size
    with path.open("rb") as fh:
        try:
            summary = make_reader(fh).get_summary()
            if summary is not None and summary.statistics is not None:
                return _from_summary(path, size, summary)
        except SUMMARY_ERRORS:  # OSError: shorter than a footer
            pass
    return _scan(path, size)


def median_period_s(path: str | Path, topic: str, max_messages: int = 2000) -> float | None:
    """Median log-time interval between consecutive ``topic`` messages, over its first ``max_messages``
    (``None`` with fewer than two distinct times)."""
    from .fastmcap import ReadState, iter_message_arrays

    state = ReadState()
    parts, n = [], 0
    chunks = iter_message_arrays(path, state)
    try:
        for arrays in chunks:
            ids = [cid for cid, (name, _sid, _enc) in state.channels.items() if name == topic]
            t = arrays.log_time[np.isin(arrays.channel, ids)]
            parts.append(t)
            n += len(t)
            if n >= max_messages:
                break
    finally:
        chunks.close()
    d = np.diff(np.sort(np.concatenate(parts + [np.empty(0, dtype=np.int64)])))
    d = d[d > 0]
    return float(np.median(d)) * 1e-9 if len(d) else None


def _check_encodings(info: BagInfo, encodings: set[str]) -> None:
    foreign = encodings - {SchemaEncoding.ROS2, MessageEncoding.CDR, ""}
    if foreign:
        raise BagError(
            f"{info.path} is not a ROS 2 bag: it uses encodings {', '.join(sorted(foreign))} "
            "(expected ros2msg schemas and cdr messages)"
        )


def _scan(path: Path, size: int) -> BagInfo:
    """Linear scan of a bag without summary: channels, counts, and how far it is readable."""
    from .fastmcap import ReadState, iter_message_arrays

    state = ReadState()
    counts_by_id: dict[int, int] = {}
    start = end = None
    for arrays in iter_message_arrays(path, state):
        ids, n = np.unique(arrays.channel, return_counts=True)
        for cid, k in zip(ids.tolist(), n.tolist()):
            counts_by_id[cid] = counts_by_id.get(cid, 0) + k
        lo, hi = int(arrays.log_time.min()), int(arrays.log_time.max())
        start = lo if start is None else min(start, lo)
        end = hi if end is None else max(end, hi)
    schema_names = {sid: name for sid, (name, _enc, _data) in state.schemas.items()}
    topics = {topic: schema_names.get(sid, "") for topic, sid, _enc in state.channels.values()}
    texts = {name: data.decode(errors="replace") for name, _enc, data in state.schemas.values()}
    counts: dict[str, int] = {}
    for cid, k in counts_by_id.items():
        topic = state.channels[cid][0] if cid in state.channels else "?"
        counts[topic] = counts.get(topic, 0) + k
    encodings = {enc for _n, enc, _d in state.schemas.values()} | {enc for _t, _s, enc in state.channels.values()}
    info = BagInfo(
        path,
        topics,
        counts,
        texts,
        False,
        state.truncated,
        size,
        min(max(state.bytes_read, 8), size),
        start or 0,
        end or 0,
        state.problem,
    )
    _check_encodings(info, encodings)
    return info


@dataclass
class RawBatch:
    """A batch of raw messages in file order: topic, log time, payload."""

    topics: list[str]
    log_time_ns: list[int]
    data: list[bytes]


def iter_raw_batches(info: BagInfo, topics: set[str] | None, batch_size: int = 50_000, state=None
                     ) -> Iterator[RawBatch]:
    """Yield batches of raw messages (file order, which for recorders is time order within chunks).

    Reads with :func:`~.fastmcap.iter_message_arrays`: damaged spans are skipped and
    listed in ``state.damaged`` (a :class:`~.fastmcap.ReadState`).
    """
    from .fastmcap import ReadState, iter_message_arrays

    state = state if state is not None else ReadState()
    tp: list[str] = []
    lt: list[int] = []
    dd: list[bytes] = []
    for arrays in iter_message_arrays(info.path, state):
        names = {cid: topic for cid, (topic, _sid, _enc) in state.channels.items()}
        for i, (cid, t) in enumerate(zip(arrays.channel.tolist(), arrays.log_time.tolist())):
            topic = names.get(cid)
            if topic is None or (topics is not None and topic not in topics):
                continue
            tp.append(topic)
            lt.append(t)
            dd.append(arrays.payload(i))
        if len(tp) >= batch_size:
            yield RawBatch(tp, lt, dd)
            tp, lt, dd = [], [], []
    if tp:
        yield RawBatch(tp, lt, dd)
