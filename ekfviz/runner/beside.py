"""The replay's work on the whole covariance, done beside the filter on a large map.

At its cadence a replay checks the whole covariance P (its eigenvalues: O(n^3), see
:func:`~ekfviz.core.health.check_covariance`) and takes its correlation matrix (O(n^2),
:func:`~ekfviz.core.correlation.correlation_of`). On a large map these cost as much as a
good share of the filter's updates (Victoria Park's state has 600 to 900 rows: some 0.7 s
of eigenvalues), yet nothing the filter does next depends on them: only the record of
their event reads them. So they run in a thread, on a copy of P, while the filter goes
on: numpy releases the GIL in its LAPACK calls and its loops over large arrays, and a
replay leaves the second core to Rerun's encoder, idle most of the time. The replay holds
its records back, in order, from the first one that waits for its results until they are
in: the consumers get the same records in the same order, a few events later.

What must stop the run at its line is checked at once (a P that is not finite, see
:meth:`Beside.finite`), and a small P is done at once as before: handing it over would
cost more than the work (a classic log's P has a few dozen rows).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ekfviz.core.correlation import Correlation, correlation_of
from ekfviz.core.health import CovarianceCheck, check_covariance
from ekfviz.core.records import EventRecord
from ekfviz.core.types import FloatArray, IntArray

if TYPE_CHECKING:  # the thread is made at the first large P: a classic run imports none
    from concurrent.futures import Future, ThreadPoolExecutor

# From this dimension on, the work on P goes to the thread: the eigenvalues of 128 x 128
# take ~0.5 ms here, a hand-over some 0.05 ms (below it: the classic sizes).
BESIDE_MIN_DIM = 128

_Results = tuple[CovarianceCheck | None, Correlation | None]


def _work(P: FloatArray, check: bool, ids: IntArray | None) -> _Results:
    """The check and the correlation of ``P``, each where asked."""
    return (
        check_covariance(P) if check else None,
        None if ids is None else correlation_of(P, ids),
    )


class Beside:
    """The work on P asked for at the events of a replay, and the records that wait for
    it, in event order.

    At an event the replay asks for the work (:meth:`ask`) before it hands the record
    on; while :attr:`busy`, it passes every record through :meth:`hold` (which yields
    those whose results are in, in order) instead of yielding it; :meth:`rest` waits for
    the rest. The thread is made at the first work given to it, and ends with
    :meth:`close`.
    """

    def __init__(self) -> None:
        self.busy = False  # records are held, or work was asked for the next record
        self._held: deque[tuple[EventRecord, Future[_Results] | None]] = deque()
        self._P: FloatArray | None = None  # the copy the next record's work reads
        self._check = False
        self._ids: IntArray | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._running: Future[_Results] | None = None  # the work given last

    @staticmethod
    def takes(P: FloatArray) -> bool:
        """Whether the work on ``P`` goes to the thread (else the caller does it now)."""
        return int(P.shape[0]) >= BESIDE_MIN_DIM

    @staticmethod
    def finite(P: FloatArray) -> bool:
        """Whether every entry of ``P`` is finite: checked at once, the rest of the check
        (:func:`check_covariance`) later."""
        return bool(np.isfinite(P).all())

    def ask(self, P: FloatArray, *, check: bool = False, ids: IntArray | None = None) -> None:
        """Ask for the check of ``P`` and (given the landmark ``ids``) its correlation,
        for the record handed to :meth:`hold` next: ``P`` is copied now (one copy for
        both), since the filter goes on changing it."""
        if self._P is None:
            self._one_at_a_time()
            self._P = np.array(P, dtype=np.float64)
        self._check |= check
        if ids is not None:
            self._ids = ids
        self.busy = True

    def _one_at_a_time(self) -> None:
        """Wait for the work given to the thread, if it is not done: one copy of P at a
        time beside the filter's own (N = 2000: 128 MB each), however fast the work is
        asked for."""
        running = self._running
        if running is not None:
            running.result()
            self._running = None

    def hold(self, record: EventRecord) -> Iterator[EventRecord]:
        """Hold ``record`` (with the work asked for it, if any) behind those held; the
        held records whose work is done, in order."""
        future = None
        if self._P is not None:
            if self._executor is None:
                from concurrent.futures import ThreadPoolExecutor

                self._executor = ThreadPoolExecutor(1, thread_name_prefix="ekfviz-whole-P")
            future = self._running = self._executor.submit(_work, self._P, self._check, self._ids)
            self._P, self._check, self._ids = None, False, None
        self._held.append((record, future))
        return self._ready(wait=False)

    def rest(self) -> Iterator[EventRecord]:
        """Every record still held, in order, each once its work is done."""
        return self._ready(wait=True)

    def _ready(self, wait: bool) -> Iterator[EventRecord]:
        held = self._held
        while held:
            record, future = held[0]
            if future is not None:
                if not wait and not future.done():
                    return
                record = _finished(record, *future.result())
            held.popleft()
            self.busy = bool(held)
            yield record

    def close(self) -> None:
        """End the thread, the work not begun dropped (the replay stopped), and wait
        for it: a thread left to end by itself would keep the process from leaving at
        once (see ``ekfviz.__main__``)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None


def _finished(
    record: EventRecord, check: CovarianceCheck | None, correlation: Correlation | None
) -> EventRecord:
    """``record`` with its check (whose problems join its warnings) and its correlation."""
    if check is not None:
        record = replace(
            record, covariance=check, warnings=record.warnings + tuple(check.problems())
        )
    if correlation is not None:
        record = replace(record, correlation=correlation)
    return record
