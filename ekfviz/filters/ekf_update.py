"""The updates of an observation line (see :mod:`ekfviz.filters.ekf`): sequential or joint.

Each landmark's h(x), H, innovation and S are the named operations of
:mod:`ekfviz.models.classic` and :mod:`ekfviz.models.kalman`, on the five non-zero columns
of H (the pose's and the landmark's); the mean and the covariance are corrected in the
factored form (:func:`~ekfviz.models.kalman.whitened_correction`: x += A^T w, P -= A^T A),
which a large map defers (:mod:`ekfviz.filters.ekf_pending`). Below ``KERNEL_MAX_DIM``
the sequential update runs in the compiled kernel (``_kernel.c``), whose Python reference
is this module's numpy loop.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import TABLE_COLUMNS, frozen
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.filters.ekf_pending import PendingCovariance
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import (
    expected_measurement,
    innovation,
    landmark_offset,
    measurement_jacobian_landmark,
    measurement_jacobian_pose,
)
from ekfviz.models.kalman import innovation_covariance, whitened_correction

try:
    from ekfviz.filters import _kernel
except ImportError:  # installed without a C compiler: numpy throughout
    _kernel = None  # type: ignore[assignment]

# A landmark predicted closer than this (metres) to the robot has no usable measurement
# Jacobian (it divides by the range): its observation is skipped with a warning.
MIN_PREDICTED_RANGE = 1e-6
# z_pred (2), innovation (2), S (4) and NIS of a landmark seen for the first time
NAN_ROW: tuple[float, ...] = (math.nan,) * TABLE_COLUMNS
# what the compiled update says of an observation, and of the whole line (see _kernel.c)
ZERO_RANGE, NOT_DEFINITE = 2, 3
_S_NOT_FINITE, _STATE_NOT_FINITE = 1, 2


class LineUpdates(PendingCovariance):
    """The update algebra of :class:`~ekfviz.filters.ekf.EkfSlam` (its state, as declared)."""

    params: FilterParams
    _R: FloatArray
    _r: tuple[float, float]
    _slot: dict[int, int]
    _rows: dict[int, IntArray]
    _warnings: list[str]
    _status: np.ndarray[tuple[int], np.dtype[np.int8]]

    def _update_compiled(
        self, ids: list[int], z: FloatArray, slots: IntArray
    ) -> tuple[FloatArray, BoolArray]:
        """:meth:`_update_sequential` in the compiled kernel; its table and skipped flags.

        :param slots: (m,) each landmark's row in the state, -1 for a new one
        """
        if self._rank:  # the kernel reads and writes P itself (a map shrunk below
            self._flush()  # KERNEL_MAX_DIM by removals: else nothing is pending here)
        m = len(ids)
        table = nan_table(m)
        status = self._status  # the kernel writes each of the line's first m
        if status.shape[0] < m:
            status = self._status = np.zeros(m, dtype=np.int8)
        r00, r11 = self._r
        code, k, n_skipped = _kernel.update_sequential(
            self._x, self._P, self._n, slots, z, table, status, r00, r11, MIN_PREDICTED_RANGE
        )
        if code == _S_NOT_FINITE:
            raise FilterError(f"the covariance became non-finite (S of landmark {ids[k]})")
        if code == _STATE_NOT_FINITE:
            raise FilterError("the state became non-finite in update")
        if n_skipped:  # the warnings, in file order
            status = status[:m]
            for k, why in enumerate(status.tolist()):
                if why == ZERO_RANGE:
                    self._warnings.append(skip_warning(ids[k], zero_range(table[k, 1])))
                    table[k] = np.nan
                elif why == NOT_DEFINITE:
                    s00, s01, _, s11 = table[k, 4:8].tolist()
                    self._warnings.append(skip_warning(ids[k], not_definite(s00, s01, s11)))
        return table, status >= ZERO_RANGE if n_skipped else no_flags(m)

    def _predicted(self, pose_and_landmark: FloatArray) -> tuple[FloatArray, FloatArray]:
        """h(x) (2,) of a landmark and H's five non-zero columns (2, 5): H_p over the pose,
        H_l over the landmark (a filter with another sensor model overrides this alone).

        :param pose_and_landmark: (5,) x, y, theta, lx, ly
        """
        offset = landmark_offset(pose_and_landmark[:3], pose_and_landmark[3:])
        z_pred = expected_measurement(offset, float(pose_and_landmark[2]))
        if not z_pred[1] > MIN_PREDICTED_RANGE:  # no Jacobian there: the caller skips it
            return z_pred, np.full((2, 5), np.nan)
        return z_pred, np.hstack(
            (measurement_jacobian_pose(offset), measurement_jacobian_landmark(offset))
        )

    def _update_sequential(
        self,
        ids: list[int],
        z: list[list[float]],
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """EKF updates with the known landmarks one after another, in file order.

        For landmark i, H has 5 non-zero columns c = (0, 1, 2, j, j+1), so H P (= (P H^T)^T,
        P symmetric) needs only the rows c of P, and S = H_c P_cc H_c^T + R. The mean and P
        are corrected in the factored form (see the module); large states defer the
        P -= A^T A (see :class:`PendingCovariance`).
        """
        n = self._n
        x = self._x[:n]
        # take() gathers from the contiguous buffer: on a view it would copy all of P first
        P_buffer = self._P
        spare = P_buffer.shape[0] > n
        U, rank = self._pending()  # P_current = P - U[:rank, :n]^T U[:rank, :n]
        for k in known:
            landmark_id = ids[k]
            j = self._slot[landmark_id]
            rows = self._rows.get(j)
            if rows is None:
                rows = self._rows[j] = np.array((0, 1, 2, j, j + 1))
            z_pred, H = self._predicted(x.take(rows))
            bearing, rng = z_pred.tolist()
            if not rng > MIN_PREDICTED_RANGE:
                self._skip(k, landmark_id, skipped, zero_range(rng))
                continue
            # ndarray methods (take, dot) cost about half of indexing and @ at small n
            P_c = P_buffer.take(rows, 0)  # the rows c of P (5 x capacity)
            HP = H.dot(P_c[:, :n] if spare else P_c)
            P_cc = P_c.take(rows, 1)
            if rank:
                U_r = U[:rank]  # contiguous rows of the buffer: take() copies no more
                U_c = U_r.take(rows, 1)
                HP -= H.dot(U_c.T).dot(U_r[:, :n])
                P_cc -= U_c.T.dot(U_c)
            S = innovation_covariance(H, P_cc, self._R)
            nu = innovation(np.array(z[k]), z_pred)
            (s00, s01), (_, s11) = S.tolist()
            nu0, nu1 = nu.tolist()
            corrected = whitened_correction(HP, S, nu)
            if corrected is None:  # also NaN; an infinite S ends as NaN in x
                if not math.isfinite(s00 + s01 + s11):
                    raise FilterError(
                        f"the covariance became non-finite (S of landmark {landmark_id})"
                    )
                table[k] = (bearing, rng, nu0, nu1, s00, s01, s01, s11, math.nan)
                self._skip(k, landmark_id, skipped, not_definite(s00, s01, s11))
                continue
            A, change, nis = corrected
            if not math.isfinite(nis):
                raise FilterError("the state became non-finite in update")
            np.add(x, change, out=x)
            rank = self._fold(A, U, rank)
            table[k] = (bearing, rng, nu0, nu1, s00, s01, s01, s11, nis)
        self._rank = rank  # left pending: see PendingCovariance
        x[2] = wrap_angle(float(x[2]))  # once per line: the bearings above are wrapped

    def _update_joint(
        self,
        ids: list[int],
        z: FloatArray,
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """EKF update with all known landmarks of a line at once (stacked H, one solve).

        H (2m x n) has its non-zero columns in (0, 1, 2) and the landmarks' own pairs;
        H P gathers those rows of P, S = H_c P_cc H_c^T + R (block-diagonal R), and the
        mean and P are corrected in the factored form (one blocked pass, exactly symmetric).
        """
        n = self._n
        x = self._x[:n]
        pose = x[:3].copy()
        slots_all = np.array([self._slot[ids[k]] for k in known], dtype=np.int64)
        offsets = landmark_offset(pose, np.column_stack([x[slots_all], x[slots_all + 1]]))
        z_pred_all = expected_measurement(offsets, float(pose[2])).reshape(-1, 2)
        usable = []
        for row, k in enumerate(known):
            rng_k = float(z_pred_all[row, 1])
            if rng_k > MIN_PREDICTED_RANGE:
                usable.append(row)
            else:
                self._skip(k, ids[k], skipped, zero_range(rng_k))
        if not usable:
            return
        if self._rank:  # H P below reads P's rows, and the gram below is P's
            self._flush()
        known = [known[row] for row in usable]
        m = len(known)
        slots, offsets, z_pred = slots_all[usable], offsets[usable], z_pred_all[usable]
        rows = np.concatenate(([0, 1, 2], np.column_stack([slots, slots + 1]).ravel()))
        nu = innovation(z[known], z_pred)
        H = np.zeros((2 * m, 3 + 2 * m))
        H[:, :3] = measurement_jacobian_pose(offsets).reshape(2 * m, 3)
        H_l = measurement_jacobian_landmark(offsets)
        for row in range(m):
            H[2 * row : 2 * row + 2, 3 + 2 * row : 5 + 2 * row] = H_l[row]
        P_c = self._P[rows, :n]
        R_all = np.kron(np.eye(m), self._R).astype(np.float64)
        S = innovation_covariance(H, P_c[:, rows], R_all)
        if not np.isfinite(S).all():
            raise FilterError("the covariance became non-finite (joint S)")
        blocks = S.reshape(m, 2, m, 2)[np.arange(m), :, np.arange(m), :]  # (m, 2, 2)
        corrected = whitened_correction(H @ P_c, S, nu.ravel())
        if corrected is None:
            # not one landmark's fault alone: the whole line is skipped
            for row, k in enumerate(known):
                (s00, s01), (_, s11) = blocks[row].tolist()
                table[k] = (*z_pred[row].tolist(), *nu[row].tolist(), s00, s01, s01, s11,
                            math.nan)  # fmt: skip
                skipped[k] = True
            self._warnings.append(
                f"the joint innovation covariance S of landmarks {[ids[k] for k in known]}"
                " is not positive definite: their observations were skipped"
            )
            return
        A, change, _ = corrected
        if not np.isfinite(change).all():
            raise FilterError("the state became non-finite in update")
        x += change
        x[2] = wrap_angle(float(x[2]))
        self._subtract_gram(A)
        nis = np.einsum("ki,ki->k", nu, np.linalg.solve(blocks, nu[:, :, None])[:, :, 0])
        for row, k in enumerate(known):
            table[k] = (*z_pred[row].tolist(), *nu[row].tolist(), *blocks[row].ravel().tolist(),
                        float(nis[row]))  # fmt: skip

    def _skip(self, k: int, landmark_id: int, skipped: list[bool], why: str) -> None:
        skipped[k] = True
        self._warnings.append(skip_warning(landmark_id, why))


_NAN_TABLES: dict[int, FloatArray] = {}


def nan_table(m: int) -> FloatArray:
    """(m, 9) NaN, a new array for an update's :attr:`~ekfviz.core.records.Observations.table`
    (a copy of a kept one: np.full costs more at small m)."""
    table = _NAN_TABLES.get(m)
    if table is None:
        table = _NAN_TABLES.setdefault(m, np.full((m, TABLE_COLUMNS), np.nan))
    copy: FloatArray = table.copy()
    return copy


_NO_FLAGS: dict[int, BoolArray] = {}


def no_flags(m: int) -> BoolArray:
    """(m,) False, read-only: shared by every observation line of m landmarks that
    initialised (or skipped) none, instead of a new array per line."""
    flags = _NO_FLAGS.get(m)
    if flags is None:
        flags = _NO_FLAGS.setdefault(m, frozen(np.zeros(m, dtype=bool)))
    return flags


def skip_warning(landmark_id: int, why: str) -> str:
    return f"landmark {landmark_id}: {why}: observation skipped"


def zero_range(rng: float) -> str:
    return (
        f"predicted {rng:.3g} m from the robot, where the measurement Jacobian"
        " (which divides by the range) is undefined"
    )


def not_definite(s00: float, s01: float, s11: float) -> str:
    return (
        f"innovation covariance S = [[{s00:.3g}, {s01:.3g}], [{s01:.3g}, {s11:.3g}]]"
        " is not positive definite"
    )
