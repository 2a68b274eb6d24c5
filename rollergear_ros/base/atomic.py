"""Files replaced atomically: written beside their final name, renamed onto it when complete.

Every file the package writes for a command goes through :func:`replacing` (or its helpers
:func:`write_text` and :func:`save_figure`), so a reader never sees half a file, and a failure, a
full disk or a kill never leaves a truncated file where a good one was: the old file stays until
the new one is whole.  A write that fails removes its partial file; a process that is killed leaves
it beside the final name as the hidden ``.NAME.<random>.partial`` (what it had written is readable
there; no temporary name looks like an output).  The outputs of one command are put in place
together (:func:`together`): when one fails, none replaces its file.  An ``OSError`` from a write
that names no file (a full disk: ENOSPC) is raised naming the output.  No rclpy.
"""

from __future__ import annotations

import os
import secrets
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

PARTIAL_SUFFIX = ".partial"
#: per thread: the commits deferred by its :func:`together` blocks, innermost last (partial, final path)
_local = threading.local()


def _groups() -> list[list[tuple[Path, Path]]]:
    if not hasattr(_local, "groups"):
        _local.groups = []
    return _local.groups


def final_path(path: str | Path) -> Path:
    """Where an output goes: a symlink's target (replacing the link would cut it), else ``path``."""
    p = Path(path)
    return Path(os.path.realpath(p)) if p.is_symlink() else p


def partial_path(path: str | Path) -> Path:
    """A new, unused file name beside ``path`` for its content while it is written."""
    p = final_path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    while True:
        candidate = p.with_name(f".{p.name}.{secrets.token_hex(3)}{PARTIAL_SUFFIX}")
        try:  # created here, with the permissions a plain open() would give (the umask applies)
            os.close(os.open(candidate, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            return candidate
        except FileExistsError:
            continue


def commit(partial: str | Path, path: str | Path) -> None:
    """Put a complete partial file in place of ``path`` (flushed to disk first); inside a
    :func:`together` block, when the block ends."""
    fd = os.open(partial, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    groups = _groups()
    if groups:
        groups[-1].append((Path(partial), final_path(path)))
        return
    os.replace(partial, final_path(path))


@contextmanager
def together() -> Iterator[None]:
    """The files committed inside the block replace theirs when it ends normally, all of them;
    when it raises (a failed write of another output, Ctrl-C), none does: their partial files are
    removed and every existing file is left as it was."""
    group: list[tuple[Path, Path]] = []
    _groups().append(group)
    try:
        yield
    except BaseException:
        _groups().remove(group)
        for partial, _ in group:
            discard(partial)
        raise
    _groups().remove(group)
    for partial, path in group:
        commit(partial, path)  # into an enclosing block, or in place


def discard(partial: str | Path) -> None:
    """Remove a partial file (a write that failed)."""
    try:
        os.unlink(partial)
    except FileNotFoundError:
        pass


@contextmanager
def named(path: str | Path) -> Iterator[None]:
    """OSErrors that name no file (a full disk) are raised naming ``path``."""
    try:
        yield
    except OSError as exc:
        if exc.filename is not None:
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Yields a partial file's path to write ``path``'s content to; when the block ends normally it
    replaces ``path``, when it raises (a failure, Ctrl-C) the partial file is removed and an existing
    ``path`` is left as it was."""
    partial = partial_path(path)
    try:
        with named(path):
            yield partial
            commit(partial, path)
    except BaseException:
        discard(partial)
        raise


def write_text(path: str | Path, text: str, encoding: str = "utf-8") -> None:
    """A text file, replaced atomically."""
    with replacing(path) as partial:
        partial.write_text(text, encoding=encoding)


def save_figure(fig, path: str | Path, **kwargs) -> None:
    """A matplotlib figure as PNG, replaced atomically."""
    with replacing(path) as partial:
        fig.savefig(partial, format="png", **kwargs)


__all__ = ["PARTIAL_SUFFIX", "commit", "discard", "final_path", "named", "partial_path", "replacing",
           "save_figure", "together", "write_text"]
