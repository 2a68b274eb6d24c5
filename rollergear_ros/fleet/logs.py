"""A fleet's recordings: found under files, folders, globs or fsspec URLs, each named by its gearbox.

:func:`discover` lists them (:class:`Recording`: path, gearbox, size, modification time and, for
an MCAP, its span from the summary); :func:`time_slices` cuts a long one into the slices a fleet
replay runs as separate tasks.  No rclpy import.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..base.errors import RollergearError, UsageError
from ..base.interface import Metadata
from ..sources.formats import is_format, recording_suffixes

__all__ = ["SLICE_MESSAGES", "Recording", "discover", "time_slices"]


#: a recording of more messages is replayed in time slices of about this many: a task of seconds to
#: a minute, short enough to spread an hours-long recording over the workers
SLICE_MESSAGES = 30_000_000
GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class Recording:
    """One log of the fleet."""

    path: str  #: local path or fsspec URL
    gearbox_id: str
    size: int
    mtime: float
    start_ns: int | None = None  #: first message (MCAP summary), for time windows
    end_ns: int | None = None  #: last message (MCAP summary), for time slices
    messages: int | None = None  #: message count (MCAP summary), for time slices
    problem: str = ""  #: why it cannot be read at all (a FIFO, a symlink loop): its row fails with this

    @property
    def key(self) -> str:
        """What identifies a recording already done: path, size and modification time."""
        return f"{self.path}|{self.size}|{self.mtime:.6f}"


def discover(logs: Sequence[str], group_by: str = "auto", exclude: str | Path | None = None) -> list[Recording]:
    """The recordings under ``logs`` (files, folders, globs; local or fsspec URLs), sorted by
    gearbox and start.  ``group_by``: ``auto`` (metadata ``gearbox_id``, else the folder),
    ``folder`` or ``metadata``.  ``exclude``: a local folder whose files are not recordings (the
    fleet's own output).  A file that cannot be read at all (a FIFO, a device, a symlink loop) is
    a recording with a ``problem``: its row fails with the reason and the rest go on."""
    import fsspec

    skip = os.path.realpath(exclude) + os.sep if exclude is not None else None
    found: dict[str, Recording] = {}
    for log in logs:
        try:
            fs, root = fsspec.core.url_to_fs(str(log))
        except ImportError as exc:  # s3://, gs://, http:// without their fsspec packages
            raise UsageError(f"{log}: {exc} (pip install it into this environment)") from None
        except ValueError as exc:
            raise UsageError(f"{log}: not a path or URL fsspec can open ({exc})") from None
        local = "file" in (fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,))
        if GLOB_CHARS & set(root):
            paths = sorted(fs.glob(root))
        elif local and os.path.isdir(root):
            paths = _local_files(root)
        elif fs.isdir(root):
            paths = sorted(p for p in fs.find(root) if p.lower().endswith(recording_suffixes()))
        elif fs.exists(root) or os.path.islink(root):
            paths = [root]
        else:
            raise UsageError(f"{log} does not exist")
        for p in paths:
            url = p if local else fs.unstrip_protocol(p)
            if local and skip and os.path.realpath(p).startswith(skip):
                continue
            key = os.path.realpath(p) if local else url  # one file under two names is one recording
            if key in found:
                continue
            problem = _unreadable(p) if local else ""
            if problem:
                found[key] = Recording(url, Path(url).parent.name or "fleet", 0, 0.0, problem=problem)
                continue
            info = fs.info(p)
            mtime = info.get("mtime") or info.get("LastModified") or info.get("updated") or 0.0
            mtime = mtime.timestamp() if hasattr(mtime, "timestamp") else float(mtime)
            gid, span = _identity(url, local, group_by)
            found[key] = Recording(url, gid, int(info.get("size") or 0), mtime, *span)
    if not found:
        raise UsageError(f"no recordings under {', '.join(map(str, logs))} ({', '.join(recording_suffixes())})")
    return sorted(found.values(), key=lambda r: (r.gearbox_id, r.start_ns or 0, r.path))


def _local_files(root: str) -> list[str]:
    """The recordings under a local folder, without following symlinks to folders (a loop would
    never end); a symlink to a file is listed (and checked by :func:`_unreadable`)."""
    paths = []
    for folder, _dirs, files in os.walk(root, followlinks=False):
        paths += [os.path.join(folder, f) for f in files if f.lower().endswith(recording_suffixes())]
    return sorted(paths)


def _unreadable(path: str) -> str:
    """Why a local path cannot be read as a recording ('' when it can be)."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        return f"cannot be read: {exc.strerror or exc}"
    if stat.S_ISDIR(mode):
        return ""
    if not stat.S_ISREG(mode):
        kind = "a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else \
            "a socket" if stat.S_ISSOCK(mode) else "not a regular file"
        return f"is {kind}, not a recording"
    return ""


def _identity(url: str, local: bool, group_by: str) -> tuple[str, tuple[int | None, int | None, int | None]]:
    """Gearbox id and (start, end, message count) of a recording (metadata and summary of a local MCAP)."""
    folder = Path(url.rstrip("/")).parent.name or "fleet"
    gid, span = None, (None, None, None)
    if local and is_format(url, "MCAP"):
        from ..recordings.baginfo import inspect_bag, read_metadata

        try:
            record = read_metadata(url, Metadata.GEARBOX) or {}
            gid = record.get("gearbox_id")
            info = inspect_bag(url)
            if info.message_count:  # log time may start at 0 (relative times of an imported table)
                span = (info.start_ns, info.end_ns, info.message_count) if info.indexed else (info.start_ns, None, None)
        except RollergearError:
            pass  # a damaged recording: it fails in its task, with the reason
    if group_by == "folder":
        gid = folder
    elif group_by == "metadata" and not gid:
        raise UsageError(f"{url} has no '{Metadata.GEARBOX}' metadata record with a gearbox_id (--group-by metadata)")
    return gid or folder, span


def time_slices(rec: Recording, slice_messages: int = SLICE_MESSAGES) -> list[tuple[int | None, int | None]]:
    """The time slices ``[start, end)`` (``None``: open) a recording is replayed in: one, unless
    its MCAP summary counts more than ``slice_messages`` messages; then equal spans of log time."""
    if not rec.messages or rec.start_ns is None or rec.end_ns is None or rec.messages <= slice_messages:
        return [(None, None)]
    n = math.ceil(rec.messages / slice_messages)
    edges = [rec.start_ns + (rec.end_ns - rec.start_ns) * i // n for i in range(1, n)]
    return list(zip([None, *edges], [*edges, None]))
