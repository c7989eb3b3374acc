"""The pending low-rank changes of a large map's covariance (see :mod:`ekfviz.filters.ekf`).

A sequential update of a large map subtracts A^T A (A = L^-1 H P, 2 x n) from P for every
landmark it folds in. :class:`PendingCovariance` keeps those rank-2 changes as the rows of
a factor U, so that the current covariance is P_s - U^T U, and applies them in one blocked
pass over P once U is full (or a reader asks for the whole P): the deferred form of the
covariance update of :func:`ekfviz.models.kalman.corrected_covariance`.
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.types import FloatArray

# From this state dimension on, the sequential update defers its rank-2 changes to one
# pass over P per DEFER_LANDMARKS landmarks (below it, one numpy call per change is
# cheaper than the bookkeeping). Both chosen with `make bench` on a 2-core machine.
DEFER_MIN_DIM = 64
DEFER_LANDMARKS = 32
# rows of the pending factor U: P -= U^T U is folded once DEFER_LANDMARKS observations
# (2 rows each) are pending, however many lines (scans) they span
DEFER_ROWS = 2 * DEFER_LANDMARKS
GRAM_STRIP_ROWS = 48  # rows of P per block of the blocked P -= U^T U (see _subtract_gram)

# the pending factor of a state too small to defer (see PendingCovariance._pending): no rows
_NO_ROWS: FloatArray = np.zeros((0, 0))
_NO_ROWS.flags.writeable = False


class PendingCovariance:
    """The covariance buffer P of a filter's state and its pending factor U.

    The state is in the leading ``_n`` rows and columns of the buffer ``_P``; the current
    covariance is ``_P[:n, :n] - U^T U`` with U the first ``_rank`` rows of ``_U``.
    """

    _x: FloatArray
    _P: FloatArray
    _n: int
    _U: FloatArray | None
    _rank: int

    def deferred_covariance(self) -> tuple[FloatArray, FloatArray | None]:
        """The covariance as stored and its pending factor: (P_s, U) with the current
        covariance P_s - U^T U, read-only views (3+2N, 3+2N) and (r, 3+2N), U None where
        nothing is pending. For a reader of a few entries of P (the association's gating
        and joint covariance), which corrects them in O(r n) instead of folding U into P
        (a pass over all of P). Valid until the filter next changes."""
        n = self._n
        P = self._P[:n, :n]
        P.flags.writeable = False
        if not self._rank:
            return P, None
        assert self._U is not None  # made with the first pending change
        U = self._U[: self._rank, :n]
        U.flags.writeable = False
        return P, U

    def _flush(self) -> None:
        """Fold the pending changes into P: P -= U^T U (one pass over P)."""
        rank = self._rank
        if rank:
            assert self._U is not None
            self._rank = 0
            self._subtract_gram(self._U[:rank, : self._n])

    def _pending_pose_gram(self) -> FloatArray:
        """U[:, :3]^T U[:, :3] of the pending factor (its rows in use), exactly
        symmetric: what the pose block of P lacks."""
        assert self._U is not None
        U_p = self._U[: self._rank, :3]
        gram: FloatArray = U_p.T.dot(U_p)
        # the lower triangle, the upper's floats (by hand: triu_indices costs 10 times more)
        gram[1, 0], gram[2, 0], gram[2, 1] = gram[0, 1], gram[0, 2], gram[1, 2]
        return gram

    def pose_rows(self) -> FloatArray:
        """The pose's rows of the current P (3, 3+2N): a new array, the pending changes
        taken off (O(rank n)), without folding them into P."""
        n = self._n
        rows: FloatArray = self._P[:3, :n].copy()
        if self._rank:
            assert self._U is not None
            U = self._U[: self._rank, :n]
            rows -= U[:, :3].T.dot(U)
            rows[:, :3] = self._P[:3, :3] - self._pending_pose_gram()  # exactly symmetric
        return rows

    def _predict_pending(self, a: float, b: float) -> None:
        """Carry the pending changes over a predict P' = F P F^T + Q, F = diag(G, I) with G
        the identity but for G[0, 2] = a and G[1, 2] = b: the stored P goes through the
        predict as the current one does, and F (P - U^T U) F^T + Q = (F P F^T + Q) -
        (U F^T)^T (U F^T), so U's pose columns become U[:, :3] G^T, O(rank)."""
        assert self._U is not None
        U = self._U[: self._rank]
        U[:, 0] += a * U[:, 2]
        U[:, 1] += b * U[:, 2]

    def _pending(self) -> tuple[FloatArray, int]:
        """The pending factor U (the buffer: DEFER_ROWS x capacity) and its rows in use,
        for a sequential update; no rows at all (and 0) where the state is too small to
        defer (below DEFER_MIN_DIM), with what was pending folded in."""
        if self._n < DEFER_MIN_DIM:
            if self._rank:  # a map shrunk by removals
                self._flush()
            return _NO_ROWS, 0
        if self._U is None:
            self._U = np.zeros((DEFER_ROWS, self._P.shape[0]))
        return self._U, self._rank

    def _fold(self, A: FloatArray, U: FloatArray, rank: int) -> int:
        """P -= A^T A for an observation's A = L^-1 H P (2 x n): with a factor ``U`` (see
        :meth:`_pending`), kept as its rows ``rank``, ``rank + 1`` and applied in one pass
        over P once U is full (see :meth:`_subtract_gram`); without rows, applied now (A
        C-contiguous: np.dot takes A^T A as a symmetric rank-k update). Returns the rows
        of U in use after it.

        Pending rows stay valid across the other changes of P, each linear: a predict
        (:meth:`_predict_pending`), a new landmark (its columns of U, J_pose U[:, :3]^T:
        see :meth:`_add_landmark`) and a removal (the same columns of U dropped).
        """
        n = A.shape[1]
        if not U.shape[0]:
            self._P[:n, :n] -= A.T.dot(A)
            return rank
        U[rank : rank + 2, :n] = A
        rank += 2
        if rank == U.shape[0]:
            self._subtract_gram(U[:, :n])
            rank = 0
        self._rank = rank  # at once: an error later in the line leaves P as it is
        return rank

    def _subtract_gram(self, U: FloatArray) -> None:
        """P -= U^T U for U (r x n), in place, in one pass over P, exactly symmetric.

        A plain ``P -= U.T @ U`` builds an n x n temporary and reads P twice. Here P goes by
        strips of rows: the diagonal block gets numpy's symmetric rank-k product, the
        block right of it a plain product, and the block below it is then copied as the
        transpose of the one to its right, so that P[i, j] and P[j, i] are the same float
        whatever the BLAS does.
        """
        n = U.shape[1]
        P = self._P
        if n <= GRAM_STRIP_ROWS:
            P[:n, :n] -= U.T @ U
            return
        for i0 in range(0, n, GRAM_STRIP_ROWS):
            i1 = min(i0 + GRAM_STRIP_ROWS, n)
            U_i = U[:, i0:i1]
            P[i0:i1, i0:i1] -= U_i.T @ U_i
            if i1 < n:
                right = P[i0:i1, i1:n]
                right -= U_i.T @ U[:, i1:]
                P[i1:n, i0:i1] = right.T
