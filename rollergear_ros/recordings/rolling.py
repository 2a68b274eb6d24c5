"""Live recordings that run for weeks: one file after another, by size or duration, each whole.

As ``ros2 bag record --max-bag-size/--max-bag-duration``: :class:`RollingRecorder` writes the node's
MCAP through a :class:`~.bag.BagWriter` and, when the file has reached ``max_bytes`` or has been
open ``max_s`` (looked at by :meth:`RollingRecorder.roll_if_due`, from a timer), opens the next
one and closes the last -- its summary written, so every file is complete and readable on its own.
Each file gets the metadata records of the first (the node's provenance with its parameters, how it
paired its inputs) and, first thing, the last message of each latched topic (the live loss map, the
latest online trace), so a file taken alone still has them.  A file is written under a hidden name
until those are on disk, then takes its own (``BagWriter.publish``); from then on a kill leaves it
whole up to its last chunk (a durable writer: :class:`~.mcapwriter.ChunkedMcapWriter`).

File names come from a template (:func:`file_name`): ``{start}`` is the file's start time (UTC,
``20261127T041503Z``), ``{index}`` its number in the run (0, 1, …); a name without either gets
``_<index>`` before its suffix when the recording is split (``rig.mcap`` -> ``rig_0.mcap``,
``rig_1.mcap``, as rosbag2 names its files).  A name that exists is never overwritten: the next free
one (``…_1.mcap``) is taken (:func:`free_name`), so a restarted node needs no new name by hand.
No rclpy import.
"""

from __future__ import annotations

import datetime
from collections.abc import Callable
from pathlib import Path

from .bagwriter import BagWriter
from .messages import encoder_for

__all__ = ["MAX_NAME_BYTES", "RollingRecorder", "file_name", "free_name", "is_template", "next_file", "roll_due",
           "splits", "template_problem"]

FIELDS = ("{start}", "{index}")


def is_template(name: str) -> bool:
    """Whether ``name`` holds a field of :data:`FIELDS`."""
    return any(f in name for f in FIELDS)


#: the longest file name most file systems take, less what a file's hidden name while it is opened adds
MAX_NAME_BYTES = 255 - len(".") - len(".000000.partial")


def template_problem(template: str, suffix: str) -> str | None:
    """Why ``template`` names no recording of files ending in ``suffix`` (None: it does): a name
    with that suffix and something before it, not too long for the file system once its fields
    ({start}, {index} up to 9999, or ``_9999`` where it is split) are filled in."""
    name = Path(template).name
    filled = file_name(template, 4_102_444_799 * 10**9, 9999, True).name  # the longest stamp and index
    if not name or name in (".", "..") or Path(filled).suffix.lower() != suffix or not Path(filled).stem.strip("._-"):
        return f"needs a file name ending in {suffix} with a name before it (e.g. rig_{{start}}{suffix})"
    if len(filled.encode()) > MAX_NAME_BYTES:
        return f"the file name is {len(filled.encode())} bytes with its fields filled in; at most {MAX_NAME_BYTES}"
    return None


def splits(max_bytes: int, max_s: float) -> bool:
    """Whether a recording with these limits is split (a limit of 0 is none)."""
    return max_bytes > 0 or max_s > 0


def file_name(template: str, start_ns: int, index: int, split: bool) -> Path:
    """The file a recording named ``template`` writes its ``index``-th file to, started at ``start_ns``."""
    stamp = datetime.datetime.fromtimestamp(start_ns / 1e9, datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    if is_template(template):
        return Path(template.replace("{start}", stamp).replace("{index}", str(index)))
    path = Path(template)
    return path.with_name(f"{path.stem}_{index}{path.suffix}") if split else path


def free_name(path: Path) -> Path:
    """``path``, or the first of ``stem_1.suffix``, ``stem_2.suffix`` … that does not exist."""
    if not (path.exists() or path.is_symlink()):
        return path
    k = 1
    while True:
        other = path.with_name(f"{path.stem}_{k}{path.suffix}")
        if not (other.exists() or other.is_symlink()):
            return other
        k += 1


def next_file(template: str, start_ns: int, index: int, split: bool) -> Path:
    """The free file the ``index``-th file of a recording named ``template`` is written to."""
    return free_name(file_name(template, start_ns, index, split))


def roll_due(size_bytes: int, age_ns: int, max_bytes: int, max_ns: int) -> bool:
    """Whether a file of this size and age has reached a limit (0: none)."""
    return bool(max_bytes and size_bytes >= max_bytes) or bool(max_ns and age_ns >= max_ns)


class RollingRecorder:
    """A :class:`~.bag.BagWriter` that rolls over to a new file (see the module docstring).

    ``open_writer(path)`` opens one file's writer; ``now_ns()`` is the clock a file's age is
    measured by (the node's); ``latched``: topics whose last message each new file starts with."""

    def __init__(self, template: str, open_writer: Callable[[Path], BagWriter], now_ns: Callable[[], int],
                 max_bytes: int = 0, max_s: float = 0.0, latched: tuple[str, ...] = (),
                 metadata: tuple[tuple[str, dict[str, str]], ...] = ()) -> None:
        """``metadata``: records every file holds from its start (the node's provenance), on disk
        before the file has its name."""
        self.template = template
        self._open_writer = open_writer
        self._now_ns = now_ns
        self.max_bytes = int(max_bytes)
        self.max_ns = int(max_s * 1e9)
        self.latched = set(latched)
        self._split = splits(self.max_bytes, max_s)
        self.files: list[Path] = []  #: every file of the run, in order
        self._metadata: list[tuple[str, dict[str, str]]] = [(name, dict(data)) for name, data in metadata]
        self._last_latched: dict[str, tuple] = {}
        self.writer: BagWriter = self._open()

    @property
    def path(self) -> Path:
        """The file being written."""
        return self.writer.path

    def _open(self) -> BagWriter:
        start = self._now_ns()
        path = next_file(self.template, start, len(self.files), self._split)
        writer = self._open_writer(path)
        self._opened_ns = start
        for name, data in self._metadata:
            writer.add_metadata(name, data)
        for topic, (type_name, data, schema_text) in self._last_latched.items():
            writer.write_raw(topic, type_name, start, data, schema_text)
        while True:  # named once its header, metadata and latched messages are on disk
            try:
                path = writer.publish(path)
                break
            except FileExistsError:  # taken meanwhile (another recorder): the next free name
                path = free_name(path)
        self.files.append(path)
        return writer

    def write_raw(self, topic: str, type_name: str, log_time_ns: int, data: bytes, schema_text: str | None = None,
                  publish_time_ns: int | None = None) -> None:
        """:meth:`~.bag.BagWriter.write_raw` into the current file."""
        self.writer.write_raw(topic, type_name, log_time_ns, data, schema_text, publish_time_ns)
        if topic in self.latched:
            self._last_latched[topic] = (type_name, data, schema_text)

    def write_message(self, topic: str, type_name: str, log_time_ns: int, message: dict) -> None:
        """:meth:`~.bag.BagWriter.write_message` into the current file."""
        self.write_raw(topic, type_name, log_time_ns, encoder_for(type_name)(message))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record in this file and in every file after it."""
        self._metadata.append((name, dict(data)))
        self.writer.add_metadata(name, data)

    def due(self) -> bool:
        """Whether the current file has reached its size or age."""
        return roll_due(self.writer.bytes_written, self._now_ns() - self._opened_ns, self.max_bytes, self.max_ns)

    def roll_if_due(self) -> Path | None:
        """Open the next file and close the current one when it is due; the closed file's path."""
        if not self.due():
            return None
        done = self.writer
        self.writer = self._open()
        done.close()
        return done.path

    def close(self) -> None:
        """Close the current file (its summary written)."""
        self.writer.close()
