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
"""

from __future__ import annotations

import enum
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

if TYPE_CHECKING:
    from concurrent.futures import Future

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

        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(fn, item) for item in items]
            _report(futures, done)
            return [future.result() for future in futures]


def _report(futures: Sequence[Future[R]], done: Callable[[R], None] | None) -> None:
    """``done`` with every result as it completes (the first error is raised)."""
    from concurrent.futures import as_completed

    for future in as_completed(futures):
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
        except (OSError, TimeoutError, ValueError) as error:
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise ExecutorError(
                f"--scheduler {self.scheduler}: cannot reach a Dask scheduler ({reason})"
            ) from None
        with client, client.as_current():  # as_completed asks for the current client
            # pure=False: every item is a task of its own, even two equal ones
            futures: list[Any] = client.map(fn, list(items), pure=False)
            for future in dask_completed(futures):  # type: ignore[no-untyped-call]
                result = future.result()
                if done is not None:
                    done(result)
            results: list[R] = client.gather(futures)  # type: ignore[no-untyped-call]
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
        return DaskExecutor(scheduler)
    if scheduler:
        raise ExecutorError("--scheduler is for --executor dask")
    return LocalExecutor(workers)
