"""The replay's work on the whole covariance, done beside the filter on a large map.

At its cadence a replay checks the whole covariance P (its eigenvalues: O(n^3), see
:func:`~ekfviz.core.health.check_covariance`) and takes its correlation matrix (O(n^2),
:func:`~ekfviz.core.correlation.correlation_of`). On a large map these cost as much as a
good share of the filter's updates (Victoria Park's state has 600 to 900 rows: some 0.7 s
of eigenvalues), yet nothing the filter does next depends on them: only their event's
extras read them. So they run in a thread, on a copy of P, while the filter goes on:
numpy releases the GIL in its LAPACK calls and its loops over large arrays, and a replay
leaves the second core to Rerun's encoder, idle most of the time. The batch that holds
the event waits for the results before it is handed on (see
:mod:`ekfviz.runner.batches`): the consumers get the same events, a little later.

What must stop the run at its line is checked at once (a P that is not finite, see
:meth:`Beside.finite`), and a small P is done at once: handing it over would cost more
than the work (a classic log's P has a few dozen rows).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ekfviz.core.correlation import Correlation, correlation_of
from ekfviz.core.health import CovarianceCheck, check_covariance
from ekfviz.core.types import FloatArray, IntArray

if TYPE_CHECKING:  # the thread is made at the first large P: a classic run imports none
    from concurrent.futures import Future, ThreadPoolExecutor

# From this dimension on, the work on P goes to the thread: the eigenvalues of 128 x 128
# take ~0.5 ms here, a hand-over some 0.05 ms (below it: the classic sizes).
BESIDE_MIN_DIM = 128

Results = tuple[CovarianceCheck | None, Correlation | None]


def whole_covariance_work(
    P: FloatArray, check: bool, ids: IntArray | None, pending: FloatArray | None = None
) -> Results:
    """The check of ``P`` (where ``check``) and its correlation (given the landmark
    ``ids``); with ``pending`` rows U, of P - U^T U (:func:`pending_taken_off`)."""
    if pending is not None:
        P = pending_taken_off(P, pending)
    return (
        check_covariance(P) if check else None,
        None if ids is None else correlation_of(P, ids),
    )


def pending_taken_off(P_s: FloatArray, U: FloatArray) -> FloatArray:
    """P_s - U^T U (n, n), a new array, exactly symmetric as the filter keeps its P: U^T U
    is numpy's symmetric rank-k product (one triangle computed, copied to the other),
    P_s is symmetric, and the difference is taken in place of the product.

    :param P_s: (n, n) the covariance as stored
    :param U: (r, n) the rows of the changes pending (see :mod:`ekfviz.filters.ekf_pending`)
    """
    gram: FloatArray = U.T @ U
    return np.subtract(P_s, gram, out=gram)


class Beside:
    """A thread for the work on large covariances, one copy of P at a time."""

    def __init__(self) -> None:
        self._executor: ThreadPoolExecutor | None = None
        self._running: Future[Results] | None = None  # the work given last

    @staticmethod
    def takes(dim: int) -> bool:
        """Whether the work on a P of ``dim`` rows goes to the thread (else the caller
        does it now)."""
        return dim >= BESIDE_MIN_DIM

    @staticmethod
    def finite(P: FloatArray) -> bool:
        """Whether every entry of ``P`` is finite: checked at once, the rest of the check
        (:func:`check_covariance`) later."""
        return bool(np.isfinite(P).all())

    def wait(self) -> None:
        """Wait for the work given last, if it is not done: one copy of P at a time beside
        the filter's own (N = 2000: 128 MB each), however fast the work is asked for."""
        if self._running is not None:
            self._running.result()
            self._running = None

    def submit(
        self,
        P: FloatArray,
        check: bool,
        ids: IntArray | None,
        *,
        copy: bool = True,
        pending: FloatArray | None = None,
    ) -> Future[Results]:
        """The check and (given ``ids``) the correlation of ``P``, or of P - U^T U given
        the ``pending`` rows U (taken off in the thread: O(r n^2) the filter does not
        wait for): on copies made now where ``copy`` (the filter goes on changing its P
        and U), else on ``P`` itself (the caller's to give away). The work given before
        is waited for first."""
        self.wait()
        if self._executor is None:
            from concurrent.futures import ThreadPoolExecutor

            self._executor = ThreadPoolExecutor(1, thread_name_prefix="ekfviz-whole-P")
        if copy:
            P = np.array(P, dtype=np.float64)
            pending = None if pending is None else pending.copy()
        self._running = self._executor.submit(whole_covariance_work, P, check, ids, pending)
        return self._running

    def close(self) -> None:
        """End the thread, the work not begun dropped (the replay stopped), and wait
        for it: a thread left to end by itself would keep the process from leaving at
        once (see ``ekfviz.__main__``)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None
