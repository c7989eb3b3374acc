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
command stops them itself, so that a worker never prints a traceback of its own.
"""

from __future__ import annotations

import contextlib
import enum
import os
import signal
from collections.abc import Callable, Sequence
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
    ) -> list[R]:
        workers = min(len(items), self.workers or os.cpu_count() or 1)
        if workers <= 1:
            results = []
            for item in items:
                results.append(fn(item))
                if done is not None:
                    done(results[-1])
            return results
        from concurrent.futures import ProcessPoolExecutor  # not at start-up: 30 ms

        pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_signals)
        try:
            futures = [pool.submit(fn, item) for item in items]
            _report(futures, done)
            results = [future.result() for future in futures]
        except BaseException:
            _stop_pool(pool)
            raise
        pool.shutdown()
        return results


STOP_GRACE_S = 0.5  # how long a stopped worker gets to exit before it is killed
POLL_S = 0.2  # how often a wait looks for an interrupt whose exception was swallowed


def _worker_signals() -> None:
    """In a local worker: SIGINT ignored (the parent stops the pool), SIGTERM ends it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


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


def _report(futures: Sequence[Future[R]], done: Callable[[R], None] | None) -> None:
    """``done`` with every result as it completes (the first error is raised); an
    interrupt whose exception was swallowed (see :func:`signals.raise_if_interrupted`)
    is raised within ``POLL_S``."""
    from concurrent.futures import FIRST_COMPLETED, wait

    pending = set(futures)
    while pending:
        finished, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
        signals.raise_if_interrupted()
        for future in [f for f in futures if f in finished]:  # in the items' order
            result = future.result()
            if done is not None:
                done(result)


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
    ) -> list[R]:
        try:
            from distributed import Client
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
            try:
                for future in dask_completed(futures):  # type: ignore[no-untyped-call]
                    result = future.result()
                    if done is not None:
                        done(result)
                results: list[R] = client.gather(futures)  # type: ignore[no-untyped-call]
            except BaseException:  # interrupted or failed: the cluster drops the rest
                client.cancel(futures)  # type: ignore[no-untyped-call]
                raise
            return results


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
