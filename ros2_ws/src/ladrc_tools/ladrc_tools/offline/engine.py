"""The distributed engine of the fleet tools: Dask's ``distributed`` scheduler.

A local cluster of worker processes by default (one thread each: the per-bag work is Python
and numpy, which a process per core runs in parallel and threads would serialise on the GIL);
``scheduler``: the address of an existing cluster (``tcp://host:8786``), whose scheduler and
workers need the project's packages (start them with ``scripts/in-env dask scheduler`` and
``scripts/in-env dask worker ADDRESS``): a scheduler without them cannot read the task graph.
Whatever the cluster does wrong (unreachable, a different environment, a worker lost) is an
:class:`EngineError` with one line, never a traceback. Why Dask and not Ray: docs/fleet.md
(measured here).
"""

from __future__ import annotations

from contextlib import contextmanager
import os
from typing import Any, Iterator


class EngineError(RuntimeError):
    """The cluster could not run the tasks (one line: why)."""


def _one_line(exc: BaseException) -> str:
    text = ' '.join(str(exc).split()) or type(exc).__name__
    return text if len(text) < 300 else text[:297] + '...'


@contextmanager
def client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """Yield a ``distributed.Client``: of ``scheduler``, else of a local cluster of ``workers``.

    ``workers`` defaults to the machine's cores. The local cluster's dashboard is off and its
    processes end with the context.
    """
    import logging

    from distributed import Client, LocalCluster

    logging.getLogger('distributed').setLevel(logging.ERROR)
    if scheduler:
        try:
            c = Client(scheduler, timeout='10s')
        except (OSError, TimeoutError, ValueError) as exc:
            raise EngineError(f'cannot reach the scheduler {scheduler}: {_one_line(exc)}'
                              ) from None
        try:
            yield c
        finally:
            c.close()
        return
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=logging.ERROR)
    c = Client(cluster)
    try:
        yield c
    finally:
        c.close()
        cluster.close()


def in_order(c: Any, fn: Any, items: list[Any], *args: Any,
             progress: Any = None) -> list[Any]:
    """Run ``fn(item, *args)`` for every item on the cluster; return the results in order.

    ``progress(done, total)`` is called as results arrive (a terminal's progress line).
    """
    from distributed import as_completed

    if not items:
        return []
    futures = c.map(fn, items, *[[a] * len(items) for a in args], pure=False)
    index = {f.key: i for i, f in enumerate(futures)}
    out: list[Any] = [None] * len(items)
    for done, f in enumerate(as_completed(futures), 1):
        try:
            out[index[f.key]] = f.result()
        except Exception as exc:  # the task's function never raises: this is the cluster
            c.cancel(futures)
            raise EngineError(f'the cluster could not run {getattr(fn, "__name__", fn)}: '
                              f'{_one_line(exc)}') from None
        if progress is not None:
            progress(done, len(items))
    return out
