"""The Dask client a fleet runs on: a ``LocalCluster`` of worker processes, or a scheduler's address.

A malformed or unreachable ``--scheduler`` is one clear error line within
:data:`SCHEDULER_TIMEOUT_S`; a Ctrl-C while the cluster starts or runs ends it quietly.  No rclpy
import.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager

from ..base.errors import UsageError
from ..base.stopping import children_spared_interrupts

__all__ = ["SCHEDULER_TIMEOUT_S", "dask_client"]


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None,
                note: Callable[[str], None] | None = None) -> Iterator:
    """A Dask client: of the scheduler at ``scheduler``, else of a ``LocalCluster`` of ``workers``
    processes (one thread each: the estimator is numpy and Python, the GIL would serialise threads)."""
    import logging

    from dask.distributed import Client, LocalCluster

    if scheduler:
        with _scheduler_client(scheduler) as client:
            yield client
        return
    import dask

    cores = os.cpu_count() or 1
    n = workers or cores
    if n > cores:  # more worker processes than cores only adds memory, open files and start-up time
        if note:
            note(f"--workers {n}: this machine has {cores} cores; running {cores} worker processes")
        n = cores
    # Dask's nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536: glibc then maps and unmaps
    # every allocation above 128 KB instead of reusing it, which slows replay's numpy batches in a
    # worker.  None: the workers inherit this process's setting.
    # the workers start with Ctrl-C ignored: the terminal's SIGINT is this process's to handle; it
    # closes the cluster, which ends them quietly
    with ExitStack() as stack:
        stack.enter_context(dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}))
        with children_spared_interrupts():  # a Ctrl-C meanwhile comes when the cluster is on the stack
            cluster = stack.enter_context(LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                       silence_logs=logging.ERROR, dashboard_address=":0"))
        client = stack.enter_context(Client(cluster))
        stack.enter_context(_without_gc_diagnosis())
        if note:
            note(f"running on a local Dask cluster of {n} worker process{'es' if n > 1 else ''}"
                 + (f" (dashboard: {client.dashboard_link})" if _has_bokeh() else ""))
        yield client


@contextmanager
def _without_gc_diagnosis() -> Iterator[None]:
    """Dask's scheduler hooks a diagnosis into every garbage collection of this process; a Ctrl-C
    that lands in it is printed as "Exception ignored" with a traceback and lost.  Unhooked while the
    fleet runs, hooked again before the cluster closes (which unhooks it itself)."""
    import gc

    hooks = [cb for cb in gc.callbacks if type(getattr(cb, "__self__", None)).__name__ == "GCDiagnosis"]
    for cb in hooks:
        gc.callbacks.remove(cb)
    try:
        yield
    finally:
        gc.callbacks.extend(hooks)


#: how long ``--scheduler`` is waited for
SCHEDULER_TIMEOUT_S = 10.0


@contextmanager
def _scheduler_client(scheduler: str) -> Iterator:
    """A client of the scheduler at ``scheduler`` (``tcp://host:port``, ``tls://…``); a malformed or
    unreachable address is one :class:`UsageError` line within :data:`SCHEDULER_TIMEOUT_S`."""
    import re

    from dask.distributed import Client

    if not re.fullmatch(r"(tcp|tls|ucx|ws|wss)://[^\s/:]+(:\d{1,5})?/?", scheduler):
        raise UsageError(f"--scheduler {scheduler!r} is not a scheduler address (tcp://HOST:PORT)")
    try:
        client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise UsageError(f"--scheduler {scheduler}: no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s "
                         f"({type(exc).__name__}: {' '.join(str(exc).split())[:160]})") from None
    with client:
        yield client


def _has_bokeh() -> bool:
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None
