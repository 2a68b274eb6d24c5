"""Writing ROS 2 MCAP bags: :class:`BagWriter` (chunked, time-ordered, written under a hidden name
and published whole, optionally built and compressed in a background thread) over
:class:`~.mcapwriter.ChunkedMcapWriter`, with rosbag2's own metadata and each topic's offered QoS
(:func:`offered_qos_yaml`).  No rclpy import here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mcap.well_known import MessageEncoding, SchemaEncoding

from ..base.interface import MessageType
from .messages import MSG_DEFINITIONS, ROSBAG2_METADATA, encoder_for, float64_payloads

def offered_qos_yaml(reliable: bool, depth: int, transient_local: bool = False) -> str:
    """One publisher's QoS as rosbag2 stores it in ``offered_qos_profiles`` (rmw enum values: history
    1 keep last, reliability 1 reliable / 2 best effort, durability 1 transient local / 2 volatile;
    infinite deadline, lifespan and lease as 0, automatic liveliness)."""
    zero = "\n    sec: 0\n    nsec: 0"
    return (f"- history: 1\n  depth: {depth}\n  reliability: {1 if reliable else 2}\n"
            f"  durability: {1 if transient_local else 2}\n  deadline:{zero}\n  lifespan:{zero}\n"
            f"  liveliness: 1\n  liveliness_lease_duration:{zero}\n  avoid_ros_namespace_conventions: false")


_MAX_JOBS = 2  #: a background writer's jobs in flight before the caller waits for the oldest


class BagWriter:
    """Writes a ROS 2 MCAP bag (``ros2`` profile, ``ros2msg`` schemas, ``cdr`` messages).

    Whole series of equal-sized messages (Float64 outputs, copied inputs) are added with numpy
    (:class:`~.mcapwriter.ChunkedMcapWriter`).  Used as a context manager; :meth:`close`
    (also on error or interrupt) writes the summary and footer, so everything added so far stays
    readable.  ``time_ordered``: messages are held back and written in log-time order across topics
    (:class:`~.timeorder.TimeOrderBuffer`; :meth:`release` writes what is older than
    a watermark, :meth:`close` the rest), as streaming readers need; a recorder that writes as
    messages come passes False.  ``offered_qos``: topic -> the QoS profiles its publisher offers
    (:func:`offered_qos_yaml`), stored as rosbag2 does.  :meth:`close` adds rosbag2's own metadata
    record (``rosbag2``: ``serialized_metadata``), so ``ros2 bag info`` shows topics, counts and QoS.
    ``background``: full chunks are compressed and written by a second thread, and a time-ordered
    writer lays out its records in a third (bulk writers: the caller goes on while what it handed
    over is written; an error there is raised by a later call or :meth:`close`).
    ``replace_atomically`` (default): written beside ``path`` and renamed onto it when closed
    without an error (:mod:`~base.atomic`); a live recorder passes False and ``durable=True``: a
    hidden file until :meth:`publish`, whole up to its last chunk whenever it is killed
    (:class:`~.mcapwriter.ChunkedMcapWriter`).
    """

    def __init__(self, path: str | Path, chunk_size: int = 1024 * 1024, time_ordered: bool = True,
                 offered_qos: Mapping[str, str] | None = None, background: bool = False,
                 replace_atomically: bool = True, durable: bool = False) -> None:
        from .mcapwriter import ChunkedMcapWriter
        from .timeorder import TimeOrderBuffer

        self.path = Path(path)
        self._writer = ChunkedMcapWriter(self.path, chunk_size=chunk_size, background=background,
                                         replace_atomically=replace_atomically, durable=durable)
        self._held = TimeOrderBuffer(self._writer) if time_ordered else None
        self._sink = self._held if time_ordered else self._writer
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self._offered_qos = dict(offered_qos or {})
        self.closed = False
        # background + time_ordered: what touches the file (channels, held messages, metadata) runs
        # on one builder thread, in the order called; calls until the next release go as one job
        self._builder = None
        self._ops: list[Callable[[], None]] = []
        self._jobs: list = []
        self._failed = False
        self._error: BaseException | None = None  # the builder's first error
        if background and time_ordered:
            from concurrent.futures import ThreadPoolExecutor

            self._builder = ThreadPoolExecutor(1, thread_name_prefix="mcap-layout")

    def _apply(self, op: Callable[[], None]) -> None:
        """Run ``op`` (which touches the file) now, or with the builder thread's next job."""
        if self._builder is None:
            op()
        else:
            self._ops.append(op)

    def _submit(self, wait_beyond: int = _MAX_JOBS) -> None:
        """Hand the calls made since the last job to the builder thread; raise the error of a job that
        failed; wait while more than ``wait_beyond`` jobs are in flight (memory stays bounded)."""
        if self._ops:
            ops, self._ops = self._ops, []
            self._jobs.append(self._builder.submit(self._run, ops))
        while self._jobs and (len(self._jobs) > wait_beyond or self._jobs[0].done()):
            self._jobs.pop(0).result()

    def _run(self, ops: list[Callable[[], None]]) -> None:
        if self._failed:  # the file's state after a failed job is no base for the next
            return
        try:
            for op in ops:
                op()
        except BaseException as exc:
            self._failed, self._error = True, exc
            raise

    def channel(self, topic: str, type_name: str, schema_text: str | None = None) -> int:
        """Register (once) a topic of a ROS 2 type; returns its channel id."""
        if topic in self._channels:
            return self._channels[topic]
        if type_name not in self._schema_ids:
            text = schema_text if schema_text is not None else MSG_DEFINITIONS[type_name]
            self._schema_ids[type_name] = self._writer.register_schema(type_name, SchemaEncoding.ROS2, text.encode())
        cid = self._writer.register_channel(topic, MessageEncoding.CDR, self._schema_ids[type_name],
                                            metadata={"offered_qos_profiles": self._offered_qos.get(topic, "")})
        self._channels[topic] = cid
        self._types[topic] = type_name
        return cid

    def release(self, up_to_ns: int) -> None:
        """``time_ordered``: write the held messages whose log time is at most ``up_to_ns``."""
        if self._held is None:
            return
        self._apply(lambda: self._held.release(up_to_ns))
        if self._builder is not None:
            self._submit()

    def write_raw(
        self, topic: str, type_name: str, log_time_ns: int, data: bytes, schema_text: str | None = None,
        publish_time_ns: int | None = None,
    ) -> None:
        """One serialized message (``publish_time_ns``: when its publisher sent it; None: its log time)."""
        log_time_ns = int(log_time_ns)
        self._apply(lambda: self._sink.add_message(self.channel(topic, type_name, schema_text), log_time_ns, data,
                                                   publish_time_ns))

    def write_message(self, topic: str, type_name: str, log_time_ns: int, message: dict) -> None:
        """Encode a message dict with the type's CDR encoder and write it."""
        self.write_raw(topic, type_name, log_time_ns, encoder_for(type_name)(message))

    def write_fixed(
        self, topic: str, type_name: str, t_ns: np.ndarray, payloads: np.ndarray | Callable[[], np.ndarray],
        schema_text: str | None = None,
    ) -> None:
        """Many messages of one topic whose serialized payloads are the rows of ``payloads`` -- or of
        what ``payloads()`` returns, called where the records are laid out (a background writer's
        builder thread: the caller does not wait for the encoding)."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        self._apply(lambda: self._sink.add_messages(self.channel(topic, type_name, schema_text), t_ns,
                                                    payloads() if callable(payloads) else payloads))

    def write_fixed_mixed(
        self, topics: list[tuple[str, str, str | None]], which: np.ndarray, t_ns: np.ndarray, payloads: np.ndarray
    ) -> None:
        """Messages of several topics in their given (time) order: row i belongs to ``topics[which[i]]``
        (``(topic, type, schema text)``); all payloads have the same length."""
        which, t_ns = np.asarray(which), np.asarray(t_ns, dtype=np.int64)

        def add() -> None:
            ids = np.array([self.channel(tp, ty, tx) for tp, ty, tx in topics], dtype=np.int64)
            self._sink.add_messages(ids[which], t_ns, payloads)

        self._apply(add)

    def write_float64_series(self, topic: str, t_ns: np.ndarray, values: np.ndarray) -> None:
        """A whole series of Float64 messages (vectorised encoding)."""
        self.write_fixed(topic, MessageType.FLOAT64, t_ns, lambda: float64_payloads(values))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record (string key/values)."""
        data = dict(data)
        self._apply(lambda: self._writer.add_metadata(name, data))

    @property
    def bytes_written(self) -> int:
        """About the file's size so far (the open chunk counted uncompressed)."""
        return self._writer.bytes_written

    def publish(self, path: str | Path | None = None) -> Path:
        """A durable recording takes its name (:meth:`~.mcapwriter.ChunkedMcapWriter.publish`)."""
        self.path = self._writer.publish(path)
        return self.path

    def close(self, commit: bool = True) -> None:
        """Write what is held, rosbag2's metadata record and the summary; ``commit=False``: the
        command failed -- a file replaced atomically is not put in place (see ``replace_atomically``)."""
        if self.closed:
            return
        self.closed = True
        ok = False
        try:
            if self._builder is not None:
                self._submit(wait_beyond=0)  # every job done, its error raised
                if self._error is not None:  # raised by an earlier call: the file is not finished
                    raise self._error
            if self._held is not None:
                self._held.release()
            self._writer.add_metadata(ROSBAG2_METADATA, {"serialized_metadata": self._rosbag2_metadata()})
            ok = True
        finally:
            if self._builder is not None:
                self._failed = True  # a job still queued (after an error) does nothing
                self._builder.shutdown(wait=True)
            self._writer.close(commit=commit and ok)

    def _rosbag2_metadata(self) -> str:
        """rosbag2's ``BagMetadata`` (version 9, Jazzy) of what was written, as YAML."""
        import yaml

        start, end = self._writer.log_time_range or (0, 0)
        duration = end - start
        by_id = self._writer.channel_counts
        counts = {topic: by_id.get(cid, 0) for topic, cid in self._channels.items()}
        total = sum(counts.values())
        topics = [{"topic_metadata": {"name": topic, "type": self._types[topic], "serialization_format": "cdr",
                                      "offered_qos_profiles": self._offered_qos.get(topic, ""),
                                      "type_description_hash": ""},
                   "message_count": counts[topic]} for topic in self._channels]
        info = {"version": 9, "storage_identifier": "mcap", "duration": {"nanoseconds": duration},
                "starting_time": {"nanoseconds_since_epoch": start}, "message_count": total,
                "topics_with_message_count": topics, "compression_format": "", "compression_mode": "",
                "relative_file_paths": [self.path.name],
                "files": [{"path": self.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                           "duration": {"nanoseconds": duration}, "message_count": total}],
                "custom_data": {}, "ros_distro": "jazzy"}
        return yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        self.close(commit=exc_type is None)
