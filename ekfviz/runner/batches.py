"""A replay's events gathered into batches, handed on in order.

The replay appends each event to the batch being built (:class:`BatchStream.add`); a
batch is sealed once it holds ``BATCH_EVENTS`` events or its maps ``BATCH_LANDMARKS``
landmarks (a large map's batches stay some 3 MB), and wherever the replay asks (its
initialisation is a batch of its own, so that the consumers see the start at once). A
sealed batch whose events wait for work beside the filter (:mod:`ekfviz.runner.beside`)
is held until that work is in, its results then joining those events' extras: the
consumers get every batch in event order, whenever the thread is done.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import replace
from typing import TYPE_CHECKING

from ekfviz.core.batch import NO_EXTRAS, BatchBuilder, EventBatch
from ekfviz.runner.beside import Results

if TYPE_CHECKING:
    from concurrent.futures import Future

BATCH_EVENTS = 4096  # events of a batch at most
BATCH_LANDMARKS = 1 << 16  # landmarks in a batch's maps, at most (some 3 MB of them)

Waiting = list[tuple[int, "Future[Results]"]]  # rows of a batch, and the work they wait for


class BatchStream:
    """The batches of one replay (see the module).

    :param events: events of a batch at most
    :param landmarks: landmarks in a batch's maps at most
    """

    def __init__(self, events: int = BATCH_EVENTS, landmarks: int = BATCH_LANDMARKS) -> None:
        self.builder = BatchBuilder()
        self._events = events
        self._landmarks = landmarks
        self._waiting: Waiting = []  # of the batch being built
        self._held: deque[tuple[EventBatch, Waiting]] = deque()

    def wait_for(self, row: int, work: Future[Results] | None) -> None:
        """The event at ``row`` of the batch being built waits for ``work`` (if any)."""
        if work is not None:
            self._waiting.append((row, work))

    @property
    def full(self) -> bool:
        """Whether the batch being built is due to be sealed."""
        builder = self.builder
        return len(builder) >= self._events or builder.landmarks >= self._landmarks

    def ready(self) -> Iterator[EventBatch]:
        """Seal the batch being built; the batches held whose work is done, in order."""
        self._seal()
        return self._handed(wait=False)

    def rest(self) -> Iterator[EventBatch]:
        """Seal the batch being built; every batch held, in order, each once its work
        is done."""
        self._seal()
        return self._handed(wait=True)

    def _seal(self) -> None:
        if len(self.builder):
            self._held.append((self.builder.build(), self._waiting))
            self._waiting = []

    def _handed(self, wait: bool) -> Iterator[EventBatch]:
        held = self._held
        while held:
            batch, waiting = held[0]
            if not wait and not all(work.done() for _, work in waiting):
                return
            held.popleft()
            yield with_results(batch, [(row, work.result()) for row, work in waiting])


def with_results(batch: EventBatch, done: list[tuple[int, Results]]) -> EventBatch:
    """``batch`` with the results of the work on its events' covariances: a check (its
    problems join the event's warnings) and a correlation."""
    if not done:
        return batch
    extras = dict(batch.extras)
    for row, (check, correlation) in done:
        extra = extras.get(row, NO_EXTRAS)
        if check is not None:
            extra = replace(
                extra, covariance=check, warnings=extra.warnings + tuple(check.problems())
            )
        if correlation is not None:
            extra = replace(extra, correlation=correlation)
        extras[row] = extra
    return replace(batch, extras=extras)
