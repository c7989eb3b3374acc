"""Where a study's runs execute: local processes, or a Dask cluster.

An executor maps a function over items and returns the results in the items' order,
calling ``done`` with each result as it arrives (for a progress bar)::

    executor = make_executor("dask", scheduler="tcp://10.0.0.5:8786")
    results = executor.map(functools.partial(run_trial, trials), seeds, done=tick)

The results do not depend on the executor: each item is the same pure computation
(a seeded Monte-Carlo trial, one replay of a log), wherever it runs. ``fn`` and the
items must pickle; a Dask cluster's workers need ekfviz installed, and the files a
run reads (a sweep's log) at the same path.

Dask (the ``dask`` extra) is imported only by :class:`DaskExecutor.map`.

A study stops at once when interrupted: on any exception while it waits (Ctrl-C,
SIGTERM, a run that failed) the runs still queued are cancelled and the running ones
stopped, instead of waiting for every one as leaving a process pool's ``with`` does.
Local workers ignore SIGINT, which a terminal sends to the whole process group: the
command stops them itself, so that a worker never prints a traceback of its own; they
die with the command (Linux), even one killed with SIGKILL.

A process that dies under a run (the OOM killer, a crash of a compiled library) breaks
a local pool: with ``lost`` given, the runs it broke are run again in a new pool, and
those broken again each alone in a pool of its own, where one that breaks it too is
``lost(item, why)`` as its result; the others go on. On a Dask cluster, a task whose
workers died (``KilledWorker``) is likewise ``lost``.
"""

from __future__ import annotations

import contextlib
import enum
import os
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from ekfviz import signals

if TYPE_CHECKING:
    from concurrent.futures import Future, ProcessPoolExecutor

T = TypeVar("T")
R = TypeVar("R")


class ExecutorName(str, enum.Enum):
    LOCAL = "local"
    DASK = "dask"


class ExecutorError(Exception):
    """An executor that cannot run, with a one-line reason."""


class Executor(Protocol):
    """Runs ``fn`` over ``items``; results in the items' order."""

    def map(
        self,
        fn: Callable[[T], R],
        items: Sequence[T],
        done: Callable[[R], None] | None = None,
        lost: Callable[[T, str], R] | None = None,
    ) -> list[R]: ...


@dataclass(frozen=True, slots=True)
class LocalExecutor:
    """A process per core (or ``workers``), or this process alone for one worker or item."""

    workers: int | None = None

    def map(
        self,
        fn: Callable[[T], R],
        items: Sequence[T],
        done: Callable[[R], None] | None = None,
        lost: Callable[[T, str], R] | None = None,
    ) -> list[R]:
        workers = min(len(items), self.workers or os.cpu_count() or 1)
        if workers <= 1:
            results = []
            for item in items:
                results.append(fn(item))
                if done is not None:
                    done(results[-1])
            return results
        found: dict[int, R] = {}
        broken = _pooled(fn, items, range(len(items)), workers, found, done)
        if broken and lost is None:
            from concurrent.futures.process import BrokenProcessPool

            raise BrokenProcessPool(f"a process of the pool died during {len(broken)} run(s)")
        if broken:  # the runs it broke, again in a new pool
            broken = _pooled(fn, items, broken, workers, found, done)
        for index in broken:  # broken twice: each alone, the one that breaks it again lost
            if _pooled(fn, items, [index], 1, found, done) and lost is not None:
                found[index] = lost(items[index], "died (a process of the pool ended under it)")
                if done is not None:
                    done(found[index])
        return [found[index] for index in range(len(items))]


def _pooled(
    fn: Callable[[T], R],
    items: Sequence[T],
    indices: Sequence[int],
    workers: int,
    found: dict[int, R],
    done: Callable[[R], None] | None,
) -> list[int]:
    """Run ``fn`` on the items at ``indices`` in a new pool, into ``found``; the indices
    whose runs a dead process of the pool broke."""
    from concurrent.futures import ProcessPoolExecutor  # not at start-up: 30 ms
    from concurrent.futures.process import BrokenProcessPool

    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_signals)
    broken: list[int] = []
    futures: dict[Future[R], int] = {}
    try:
        # a local pool forks its processes as runs are submitted: a signal acted on inside
        # os.fork's hooks breaks them (logging's lock released unheld, said on stderr), so
        # one that comes meanwhile is acted on once the runs are queued
        with signals.held():
            futures = {pool.submit(fn, items[index]): index for index in indices}
        for future in _completed(list(futures)):
            try:
                found[futures[future]] = future.result()
            except BrokenProcessPool:
                broken.append(futures[future])
                continue
            if done is not None:
                done(found[futures[future]])
    except BaseException:
        _keep_finished(futures, found, done)
        _stop_pool(pool)
        raise
    pool.shutdown(wait=not broken)
    return sorted(broken)


def _keep_finished(
    futures: dict[Future[R], int], found: dict[int, R], done: Callable[[R], None] | None
) -> None:
    """The runs whose results had come when an interrupt did, kept (into ``found``, told
    to ``done``) as if it had come after them."""
    for future, index in futures.items():
        if index in found or not future.done() or future.cancelled():
            continue
        if future.exception() is None:
            found[index] = future.result()
            if done is not None:
                done(found[index])


STOP_GRACE_S = 0.5  # how long a stopped worker gets to exit before it is killed
POLL_S = 0.2  # how often a wait looks for an interrupt whose exception was swallowed


def _worker_signals() -> None:
    """In a local worker: SIGINT ignored (the parent stops the pool), SIGTERM ends it, and
    so does its parent's end (Linux: ``PR_SET_PDEATHSIG``), so that no worker and no
    sandbox of its outlives a command killed outright."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        if os.getppid() == 1:  # the parent died before the above: go too
            os._exit(1)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel the queued runs and end the running ones now (SIGTERM, then SIGKILL)."""
    import time

    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join(1.0)


def _completed(futures: Sequence[Future[R]]) -> Iterator[Future[R]]:
    """Every future as it completes, in the items' order among those done together; an
    interrupt whose exception was swallowed (see :func:`signals.raise_if_interrupted`)
    is raised within ``POLL_S``."""
    from concurrent.futures import FIRST_COMPLETED, wait

    pending = set(futures)
    while pending:
        finished, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
        signals.raise_if_interrupted()
        yield from (f for f in futures if f in finished)


@dataclass(frozen=True, slots=True)
class DaskExecutor:
    """The workers of a running Dask scheduler (``dask.distributed``) at ``scheduler``,
    e.g. ``tcp://10.0.0.5:8786``."""

    scheduler: str
    timeout_s: float = 30.0

    def map(
        self,
        fn: Callable[[T], R],
        items: Sequence[T],
        done: Callable[[R], None] | None = None,
        lost: Callable[[T, str], R] | None = None,
    ) -> list[R]:
        try:
            from distributed import Client, KilledWorker
            from distributed import as_completed as dask_completed
        except ImportError:
            raise ExecutorError(
                "--executor dask needs dask.distributed: the dask extra"
                " (pip install -e '.[dask]' in a clone of ekfviz)"
            ) from None
        try:
            client = Client(  # type: ignore[no-untyped-call]
                self.scheduler, timeout=self.timeout_s, set_as_default=False
            )
        except Exception as error:  # unreachable, a refused address, TLS without its context
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise ExecutorError(
                f"--scheduler {self.scheduler}: cannot reach a Dask scheduler ({reason})"
            ) from None
        try:  # a scheduler without workers would hold the tasks for ever, without a word
            client.wait_for_workers(1, timeout=self.timeout_s)
        except Exception:
            with contextlib.suppress(Exception):
                client.close(timeout=5)  # type: ignore[no-untyped-call]
            raise ExecutorError(
                f"--scheduler {self.scheduler}: the Dask scheduler has no workers (none joined"
                f" in {self.timeout_s:g} s): start some with dask worker {self.scheduler}"
            ) from None
        with client, client.as_current():  # as_completed asks for the current client
            # pure=False: every item is a task of its own, even two equal ones
            futures: list[Any] = client.map(fn, list(items), pure=False)
            where = {future.key: index for index, future in enumerate(futures)}
            results: dict[int, R] = {}
            try:
                for future in dask_completed(futures):  # type: ignore[no-untyped-call]
                    index = where[future.key]
                    try:
                        results[index] = future.result()
                    except KilledWorker:
                        if lost is None:
                            raise
                        results[index] = lost(items[index], "died (its Dask workers died)")
                    if done is not None:
                        done(results[index])
            except BaseException:  # interrupted or failed: the cluster drops the rest
                client.cancel(futures)  # type: ignore[no-untyped-call]
                raise
            return [results[index] for index in range(len(items))]


def make_executor(
    name: ExecutorName | str, scheduler: str | None = None, workers: int | None = None
) -> Executor:
    """The executor asked for on the command line.

    :raises ExecutorError: dask without a scheduler address, or a scheduler for local
    """
    name = ExecutorName(name)
    if name is ExecutorName.DASK:
        if not scheduler:
            raise ExecutorError("--executor dask needs --scheduler ADDRESS (e.g. tcp://host:8786)")
        if workers is not None:  # it would be dropped without a word
            raise ExecutorError(
                "--workers is for --executor local: a Dask cluster runs on the workers it has"
            )
        return DaskExecutor(scheduler)
    if scheduler:
        raise ExecutorError("--scheduler is for --executor dask")
    return LocalExecutor(workers)
