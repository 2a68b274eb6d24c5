"""Checks on the files a command reads and writes, made before any work starts.

A command that would fail writing its result — an output path that is a folder, a device or a FIFO,
a folder that cannot be created or written (``/proc``), an output that is one of the inputs or
another output of the same command, a suffix that says another kind of file — fails at once with
one line, instead of after the whole analysis with a traceback (and the result lost, or a device
replaced by a file).  :func:`check_outputs` is the one entry; every command lists its outputs in
it.  No rclpy.
"""

from __future__ import annotations

import fnmatch
import os
import stat
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..base.errors import UsageError
from .formats import suffixes as input_suffixes

#: kind of output -> (what it is, the suffixes it may have)
OUTPUT_KINDS: dict[str, tuple[str, tuple[str, ...]]] = {
    "mcap": ("an MCAP recording", (".mcap",)),
    "rrd": ("a rerun recording", (".rrd",)),
    "png": ("a PNG picture", (".png",)),
    "yaml": ("a parameter file", (".yaml", ".yml")),
    "vtlm": ("a VECTO loss map", (".vtlm", ".csv")),
    "csv": ("a CSV table", (".csv",)),
    "parquet": ("a Parquet table", (".parquet",)),
    "mf4": ("an MDF4 file", (".mf4", ".mdf")),
    "fmu": ("an FMI unit", (".fmu",)),
    "folder": ("a folder", ()),
}
#: suffixes that name a kind of file besides the outputs and the input formats (:mod:`.formats`)
OTHER_KNOWN_SUFFIXES = frozenset({".json", ".md", ".txt", ".mat", ".jpg", ".jpeg", ".svg", ".pdf"})


def known_suffixes() -> frozenset[str]:
    """Suffixes that name a kind of file: an output with one of another kind's is refused."""
    return (frozenset(s for _, suffixes in OUTPUT_KINDS.values() for s in suffixes) | frozenset(input_suffixes())
            | OTHER_KNOWN_SUFFIXES)


@dataclass(frozen=True)
class Output:
    """One output of a command: its option (as the user typed it), path and kind (:data:`OUTPUT_KINDS`)."""

    option: str
    path: str | Path | None
    kind: str
    #: a folder output: the names (glob patterns) of the files it writes in the folder
    files: tuple[str, ...] = ()

    @property
    def is_folder(self) -> bool:
        return self.kind == "folder"


def _key(path: str | Path) -> str:
    """A path as the file system will resolve it (symlinks in its folders followed)."""
    return os.path.realpath(os.path.abspath(path))


def _special(path: Path) -> str | None:
    """What a path that exists and is neither a regular file nor a folder is ('a FIFO', …)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    for test, name in ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return None


def _same(a: str | Path, b: str | Path) -> bool:
    if _key(a) == _key(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(inputs: Sequence[str | Path | None], outputs: Sequence[Output]) -> None:
    """Every check on a command's outputs, before anything is opened or computed: each output is
    of its kind (a file that is not a folder, device, FIFO or socket, with no suffix of another
    kind; a folder that is not a file), none is an input or another output, and each one's folder
    exists (or can be made) and takes new files."""
    for out in outputs:
        if out.path is not None and str(out.path).strip() == "":
            raise UsageError(f"{out.option} {str(out.path)!r} names no {'folder' if out.is_folder else 'file'}")
    given = [o for o in outputs if o.path is not None]
    existing = input_files(inputs)  # a folder input walked once, for both checks
    _refuse_same_files(inputs, existing, {o.option: o.path for o in given})
    _refuse_writing_over_inputs_in_folders(existing, [o for o in given if o.is_folder and o.files])
    for out in given:
        p = Path(out.path)
        special = _special(p)
        if special:
            raise UsageError(f"{out.option} {out.path} is {special}; give a "
                             f"{'folder' if out.is_folder else 'regular file'}")
        if out.is_folder:
            if p.exists() and not p.is_dir():
                raise UsageError(f"{out.option} {out.path} is a file; give a folder")
            continue
        if p.is_dir():
            raise UsageError(f"{out.option} {out.path} is a folder; give a file name")
        what, suffixes = OUTPUT_KINDS[out.kind]
        suffix = p.suffix.lower()
        if suffix in known_suffixes() and suffix not in suffixes:
            raise UsageError(f"{out.option} {out.path}: {out.option} writes {what} ({' or '.join(suffixes)}), "
                             f"not a {suffix} file")
    for i, a in enumerate(given):
        for b in given[i + 1:]:
            if _same(a.path, b.path):
                raise UsageError(f"{a.option} {a.path} and {b.option} {b.path} are the same path: each output "
                                 "needs its own")
    for out in given:
        p = Path(out.path)
        _writable_folder(out.option, out.path, p if out.is_folder else (p.parent if str(p.parent) else Path(".")))


#: the most files of a folder input compared with the outputs (a rosbag2 folder holds a few)
MAX_FOLDER_INPUT_FILES = 100_000


def input_files(inputs: Sequence[str | Path | None]) -> list[Path]:
    """The existing inputs, a folder as itself and every file in it (a rosbag2 folder's storage
    files -- with a suffix or without, one or a split bag's parts -- and its ``metadata.yaml``)."""
    files: list[Path] = []
    for given in inputs:
        if given is None or str(given) == "" or not Path(given).exists():
            continue
        files.append(Path(given))
        if Path(given).is_dir():
            for folder, _, names in os.walk(given):
                files += [Path(folder) / n for n in names]
                if len(files) > MAX_FOLDER_INPUT_FILES:
                    raise UsageError(f"{given}: more than {MAX_FOLDER_INPUT_FILES:,} files in the folder; "
                                     "give the recording's own folder")
    return files


def refuse_overwriting_inputs(inputs: Sequence[str | Path | None], outputs: dict[str, str | Path | None]) -> None:
    """Refuse, before anything is opened, an output that is the same file as an input or as a file
    in an input folder (the same path, another path to it, or a hard link): writing it would
    destroy the recording."""
    _refuse_same_files(inputs, input_files(inputs), outputs)


def _refuse_same_files(inputs: Sequence[str | Path | None], existing: Sequence[Path],
                       outputs: dict[str, str | Path | None]) -> None:
    """:func:`refuse_overwriting_inputs` with the inputs' files (:func:`input_files`) given."""
    given = {str(p) for p in inputs if p is not None}
    for option, out in outputs.items():
        if out is None:
            continue
        for source in existing:
            if _same(out, source):
                what = "the input" if str(source) in given else "a file of the input"
                raise UsageError(f"{option} {out} is {what} {source}: refusing to overwrite it")


def _refuse_writing_over_inputs_in_folders(existing: Sequence[Path], folders: Sequence[Output]) -> None:
    """Refuse a folder output whose files (:attr:`Output.files`) would replace an input in it
    (``existing``: the inputs' files, :func:`input_files`)."""
    for out in folders:
        for source in existing:
            if not source.is_file() or not _same(source.parent, out.path):
                continue
            if any(fnmatch.fnmatchcase(source.name, pattern) for pattern in out.files):
                raise UsageError(f"{out.option} {out.path} would replace the input {source} (it writes "
                                 f"{', '.join(out.files)} there): give another folder")


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


def check_output_file(option: str, path: str | Path | None, kind: str) -> None:
    """One output file (see :func:`check_outputs`)."""
    check_outputs([], [Output(option, path, kind)])


def check_output_folder(option: str, path: str | Path | None) -> None:
    """One output folder (see :func:`check_outputs`)."""
    check_outputs([], [Output(option, path, "folder")])


def check_input_file(option: str, path: str | Path | None) -> None:
    """An input file: exists and is a regular file (not a folder, a FIFO or a device)."""
    if path is None:
        return
    p = Path(path)
    if not p.exists():
        raise UsageError(f"{option} {path} does not exist")
    if not p.is_file():
        raise UsageError(f"{option} {path} is {'a folder' if p.is_dir() else 'not a regular file'}; give a file")


__all__ = ["OUTPUT_KINDS", "Output", "check_input_file", "check_output_file", "input_files", "known_suffixes",
           "check_output_folder", "check_outputs", "refuse_overwriting_inputs"]
