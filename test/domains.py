"""A DDS domain of its own for each test session on this machine.

Two suites that run at once (a developer's and CI's, or a stress run beside a fresh clone's) must
never share a domain: on one they see each other's nodes and messages.  :func:`claim_domain`
takes the first free id of a range, holding an exclusive ``flock`` on a lock file per id for as long
as the process lives (the lock goes with the process, also when it is killed).
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
from pathlib import Path

DOMAINS = range(100, 200)  #: ids the suites take (within DDS's 0..232; clear of the default 0)
_held: list = []  # the open lock files: closing one frees its domain


def claim_domain(lock_dir: str | Path | None = None) -> int:
    """A domain id no other live process has claimed from ``lock_dir``; held until this process ends."""
    folder = Path(lock_dir or tempfile.gettempdir())
    ids = list(DOMAINS)
    random.Random(os.getpid()).shuffle(ids)  # concurrent starts try different ids first
    for domain in ids:
        fh = open(folder / f"rollergear_ros_domain_{domain}.lock", "a")  # noqa: SIM115 - held open on purpose
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            continue
        _held.append(fh)
        return domain
    raise RuntimeError(f"every DDS domain {DOMAINS.start}..{DOMAINS.stop - 1} is taken by a running test session")
