"""The sweep engine: one function over many jobs, on a local process pool or a Dask cluster.

:func:`map_jobs` yields ``(index, result)`` as jobs finish, in any order, with a rich progress
bar. ``workers`` = 1 and no scheduler: in this process, one after the other (no pickling, the
numba caches warm); ``workers`` > 1: a :class:`~concurrent.futures.ProcessPoolExecutor` of
spawned processes (not forked: numba's threads, once started, make a fork unsafe), each with
its share of the cores (:mod:`cellsight.threads`);
``scheduler``: the address of a Dask ``distributed`` scheduler (``tcp://host:8786``) or a
:class:`distributed.Client` / ``LocalCluster`` object, whose workers must be able to import
cellsight. Jobs and results must pickle; the function must be importable by name (module
level). On Ctrl-C (or SIGTERM under :func:`sigterm_interrupts`, as :class:`Terminated`) the
jobs not started are cancelled, the pool's workers are sent SIGTERM (a run in one ends at its
next frame and writes what it has), killed after :data:`GRACE_S`, and the exception
propagates. While the local pool is waited on, those signals are only noted and raised between
waits (:func:`_signals_between_waits`): raised inside ``concurrent.futures``' locks they left
them half released ("RuntimeError: release unlocked lock" instead of the interrupt).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing import get_context
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from cellsight import threads
from cellsight.errors import CellsightError

GRACE_S = 10.0
"""Seconds the pool's workers have, after SIGTERM, to end their runs before they are killed."""

WAIT_S = 0.2
"""Seconds between looks at the signals noted while the local pool is waited on."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread by :func:`sigterm_interrupts`: a
    ``KeyboardInterrupt``, so every clean-up for Ctrl-C runs for it too."""


def stop_status(stop: KeyboardInterrupt) -> tuple[str, int]:
    """The signal that raised ``stop`` and the exit status it gives: ``("SIGTERM", 143)``
    for :class:`Terminated`, else ``("SIGINT", 130)``."""
    sig = signal.SIGTERM if isinstance(stop, Terminated) else signal.SIGINT
    return sig.name, 128 + sig.value


def raise_if_stopped(metrics: dict) -> None:
    """Raise again the signal that ended a run in this process (its own handler took it, and
    its ``metrics`` say ``interrupted`` and which ``signal``): :class:`Terminated` for SIGTERM,
    ``KeyboardInterrupt`` for SIGINT; nothing for a run that was not stopped by one."""
    if metrics.get("interrupted") and metrics.get("signal") == "SIGTERM":
        raise Terminated("SIGTERM")
    if metrics.get("interrupted") and metrics.get("signal") == "SIGINT":
        raise KeyboardInterrupt


@contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """While held, SIGTERM raises :class:`Terminated` in the main thread (once; a second one
    is ignored, so the clean-up is not cut); the previous handler comes back on exit. Outside
    the main thread nothing is installed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired = False

    def stop(signum: int, frame: object) -> None:
        nonlocal fired
        if not fired:
            fired = True
            raise Terminated("SIGTERM")

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def map_jobs(fn: Callable[[Any], Any], jobs: Sequence[Any], *, workers: int = 1,
             scheduler: Any = None, progress: bool = True, label: str = "jobs",
             connect_s: float = 20.0,
             on_crash: Callable[[Any], Any] | None = None) -> Iterator[tuple[int, Any]]:
    """``(i, fn(jobs[i]))`` for every job, as each finishes (module docstring); ``connect_s``:
    how long to try reaching the scheduler, to wait for a first worker, and to wait once every
    worker is gone before giving up (s); ``on_crash``: on a local pool, the result of a job
    whose worker died under it twice (:func:`_on_pool`; None: a dead worker ends the map)."""
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
            results = _on_pool(fn, jobs, workers, on_crash)
        for i, result in results:
            bar.advance(task)
            yield i, result


def _on_pool(fn: Callable, jobs: Sequence, workers: int,
             on_crash: Callable[[Any], Any] | None) -> Iterator[tuple[int, Any]]:
    """The jobs on a pool of ``workers`` spawned processes. A worker that dies (a crash in
    native code) breaks the pool: without ``on_crash`` the break propagates. With it, the jobs
    that may have been running then (the first ``workers + 1`` unfinished, in the order they
    were queued) run again, each alone in a pool of its own; one that kills its worker there
    too gets ``on_crash(job)`` as its result. The others go on in a new pool."""
    order = list(range(len(jobs)))
    while order:
        broken = yield from _pool_pass(fn, jobs, order, workers, on_crash is not None)
        suspects, order = broken[:workers + 1], broken[workers + 1:]
        for i in suspects:
            if (yield from _pool_pass(fn, jobs, [i], 1, True)):
                yield i, on_crash(jobs[i])


def _pool_pass(fn: Callable, jobs: Sequence, order: list[int], workers: int,
               survive: bool) -> Iterator[tuple[int, Any]]:
    """``jobs[i]`` for ``i`` in ``order`` on one pool, yielding ``(i, result)``; returns the
    jobs a dead worker left unfinished, in ``order`` (``survive``; else the break raises)."""
    workers = min(workers, len(order))
    per_job = threads.share(workers)  # each worker its share of the cores (threading policy)
    pool = ProcessPoolExecutor(workers, mp_context=get_context("spawn"),
                               initializer=threads.apply, initargs=(per_job,))
    broken: list[int] = []
    done = False
    with _signals_between_waits() as raise_noted:
        try:
            # the workers start at the submits; a worker that crashes in native code (a
            # segmentation fault) prints every thread's Python stack on its stderr first
            with _environment(threads.environment(per_job) | {"PYTHONFAULTHANDLER": "1"}):
                futures = {pool.submit(fn, jobs[i]): i for i in order}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, timeout=WAIT_S, return_when=FIRST_COMPLETED)
                raise_noted()
                for future in finished:
                    if survive and isinstance(future.exception(), BrokenProcessPool):
                        broken.append(futures[future])
                        continue
                    yield futures[future], future.result()
                    raise_noted()
            done = True
        finally:
            if done and not broken:
                pool.shutdown()
            else:  # interrupted, a job failed, a worker died, or the caller stopped early
                _stop_pool(pool)
    return sorted(broken, key=order.index)


@contextmanager
def _signals_between_waits() -> Iterator[Callable[[], None]]:
    """While held (in the main thread), SIGINT and SIGTERM are noted, not raised where they
    land; the function it gives raises the first one noted (``KeyboardInterrupt``,
    :class:`Terminated`) where it is called. Signals during the clean-up are ignored; the
    previous handlers come back on exit."""
    noted: list[int] = []

    def raise_noted() -> None:
        if noted:
            raise Terminated("SIGTERM") if noted[0] == signal.SIGTERM else KeyboardInterrupt

    if threading.current_thread() is not threading.main_thread():
        yield raise_noted
        return
    previous = {s: signal.signal(s, lambda signum, frame: noted.append(signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield raise_noted
    finally:
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)


@contextmanager
def _environment(values: dict[str, str]) -> Iterator[None]:
    """``os.environ`` with ``values`` while the pool's processes start (they inherit it)."""
    before = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel the jobs not started and end the workers: SIGTERM, then SIGKILL after
    :data:`GRACE_S` (a pool shut down the plain way waits for every running job)."""
    # The executor has no public handle on its processes before Python 3.14
    # (terminate_workers, which does just this); copy them before shutdown drops them.
    processes = list((pool._processes or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    deadline = time.monotonic() + GRACE_S
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join(1.0)


def _on_dask(fn: Callable, jobs: Sequence, scheduler: Any,
             connect_s: float) -> Iterator[tuple[int, Any]]:
    from distributed import Client

    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout=f"{connect_s}s") if own else scheduler
    except OSError as exc:
        raise CellsightError(f"--scheduler: cannot reach the Dask scheduler at {scheduler!r} "
                             f"({exc})") from exc
    try:
        check_workers(client, connect_s)
        futures = client.map(fn, list(jobs), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            yield from _results(client, futures, index, connect_s)
        finally:
            client.cancel(futures)
    finally:
        if own:
            client.close()


def _importable(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def check_workers(client: Any, wait_s: float, module: str = "cellsight") -> None:
    """The cluster has a worker within ``wait_s`` seconds, and the scheduler and every worker
    can import ``module`` (else one :class:`CellsightError` naming them: a job would fail to
    unpickle there with a long traceback)."""
    try:
        client.wait_for_workers(1, timeout=wait_s)
    except TimeoutError as exc:
        raise CellsightError(f"--scheduler: the Dask scheduler has no worker after {wait_s:g} "
                             f"s; start some (dask worker ADDRESS)") from exc
    missing = sorted(w for w, ok in client.run(_importable, module).items() if not ok)
    if not client.run_on_scheduler(_importable, module):
        missing.insert(0, "the scheduler")
    if missing:
        raise CellsightError(f"--scheduler: {', '.join(missing)} cannot import {module}; install "
                             f"it there (pip install cellsight, or -e of this checkout) and "
                             f"start them again")


def _results(client: Any, futures: list, index: dict, grace_s: float,
             poll_s: float = 2.0) -> Iterator[tuple[int, Any]]:
    """Each job's result as it finishes; when the cluster has had no worker for ``grace_s``
    seconds, one :class:`CellsightError` saying how many finished (instead of waiting for
    ever)."""
    from distributed import wait

    pending, alone_since = set(futures), None
    while pending:
        try:
            done, pending = wait(list(pending), timeout=poll_s, return_when="FIRST_COMPLETED")
        except TimeoutError:
            done = set()
        for future in done:
            yield index[future.key], future.result()
        if done or client.scheduler_info().get("workers"):
            alone_since = None
            continue
        alone_since = alone_since or time.monotonic()
        if time.monotonic() - alone_since > grace_s:
            raise CellsightError(
                f"--scheduler: every Dask worker is gone (none for {grace_s:g} s); "
                f"{len(futures) - len(pending)} of {len(futures)} jobs finished (their runs "
                f"are kept: the same sweep again resumes)")
