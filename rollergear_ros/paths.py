"""Checks on the files a command reads and writes, made before any work starts.

A command that would fail writing its result — an output path that is a folder, a folder that
cannot be created or written (``/proc``), an output that is one of the inputs — fails at once with
one line, instead of after the whole analysis with a traceback (and the result lost).  No rclpy.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

from .errors import UsageError


def refuse_overwriting_inputs(inputs: Sequence[str | Path | None], outputs: dict[str, str | Path | None]) -> None:
    """Refuse, before anything is opened, an output that is the same file as an input (the same
    path, another path to it, or a hard link): writing it would destroy the recording."""
    existing = [Path(p) for p in inputs if p is not None and Path(p).exists()]
    for option, out in outputs.items():
        if out is None or not Path(out).exists():
            continue
        for source in existing:
            try:
                same = os.path.samefile(out, source)
            except OSError:
                same = False
            if same:
                raise UsageError(f"{option} {out} is the input {source}: refusing to overwrite it")


def _writable_folder(option: str, given: str | Path, folder: Path) -> None:
    """Create ``folder`` if needed (the command would) and prove a file can be created in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{option} {given}: cannot create the folder {folder} ({exc.strerror or exc})") from None
    if not folder.is_dir():
        raise UsageError(f"{option} {given}: {folder} is not a folder")
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".rollergear-write-check-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise UsageError(f"{option} {given}: cannot write in {folder} ({exc.strerror or exc})") from None


def check_output_file(option: str, path: str | Path | None) -> None:
    """An output file: not a folder, in a folder that exists (or can be made) and takes new files."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"{option} {path} is a folder; give a file name")
    _writable_folder(option, path, p.parent if str(p.parent) else Path("."))


def check_output_folder(option: str, path: str | Path | None) -> None:
    """An output folder: not a file, and one that exists (or can be made) and takes new files."""
    if path is None:
        return
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise UsageError(f"{option} {path} is a file; give a folder")
    _writable_folder(option, path, p)


def check_input_file(option: str, path: str | Path | None) -> None:
    """An input file: exists and is a regular file (not a folder, a FIFO or a device)."""
    if path is None:
        return
    p = Path(path)
    if not p.exists():
        raise UsageError(f"{option} {path} does not exist")
    if not p.is_file():
        raise UsageError(f"{option} {path} is {'a folder' if p.is_dir() else 'not a regular file'}; give a file")


__all__ = ["check_input_file", "check_output_file", "check_output_folder", "refuse_overwriting_inputs"]
