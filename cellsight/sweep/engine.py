"""The sweep engine: one function over many jobs, on a local process pool or a Dask cluster.

:func:`map_jobs` yields ``(index, result)`` as jobs finish, in any order, with a rich progress
bar. ``workers`` = 1 and no scheduler: in this process, one after the other (no pickling, the
numba caches warm); ``workers`` > 1: a :class:`~concurrent.futures.ProcessPoolExecutor` of
spawned processes (not forked: numba's OpenMP threads, once started, make a fork unsafe);
``scheduler``: the address of a Dask ``distributed`` scheduler (``tcp://host:8786``) or a
:class:`distributed.Client` / ``LocalCluster`` object, whose workers must be able to import
cellsight. Jobs and results must pickle; the function must be importable by name (module
level). On Ctrl-C the jobs not started are cancelled and ``KeyboardInterrupt`` propagates.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from cellsight.errors import CellsightError


def map_jobs(fn: Callable[[Any], Any], jobs: Sequence[Any], *, workers: int = 1,
             scheduler: Any = None, progress: bool = True, label: str = "jobs",
             connect_s: float = 20.0) -> Iterator[tuple[int, Any]]:
    """``(i, fn(jobs[i]))`` for every job, as each finishes (module docstring); ``connect_s``:
    how long to try reaching the scheduler (s)."""
    if workers < 1:
        raise CellsightError(f"--jobs: expected a whole number >= 1, got {workers}")
    with Progress(TextColumn(f"[bold]{label}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), disable=not progress) as bar:
        task = bar.add_task(label, total=len(jobs))
        if scheduler is not None:
            results = _on_dask(fn, jobs, scheduler, connect_s)
        elif workers == 1 or len(jobs) <= 1:
            results = ((i, fn(job)) for i, job in enumerate(jobs))
        else:
            results = _on_pool(fn, jobs, workers)
        for i, result in results:
            bar.advance(task)
            yield i, result


def _on_pool(fn: Callable, jobs: Sequence, workers: int) -> Iterator[tuple[int, Any]]:
    pool = ProcessPoolExecutor(min(workers, len(jobs)), mp_context=get_context("spawn"))
    try:
        futures = {pool.submit(fn, job): i for i, job in enumerate(jobs)}
        for future in as_completed(futures):
            yield futures[future], future.result()
    finally:
        pool.shutdown(cancel_futures=True)


def _on_dask(fn: Callable, jobs: Sequence, scheduler: Any,
             connect_s: float) -> Iterator[tuple[int, Any]]:
    from distributed import Client, as_completed

    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout=f"{connect_s}s") if own else scheduler
    except OSError as exc:
        raise CellsightError(f"--scheduler: cannot reach the Dask scheduler at {scheduler!r} "
                             f"({exc})") from exc
    try:
        futures = client.map(fn, list(jobs), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for future in as_completed(futures):
                yield index[future.key], future.result()
        finally:
            client.cancel(futures)
    finally:
        if own:
            client.close()
