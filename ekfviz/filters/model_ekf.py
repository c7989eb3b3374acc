"""The built-in EKF-SLAM with pluggable models: a vehicle and a sensor off its origin.

:class:`ModelEkfSlam` is :class:`~ekfviz.filters.ekf.EkfSlam` (same buffers, records,
landmark removal) with the measurement model of :mod:`ekfviz.models.range_bearing` (a
sensor mounted ``a`` ahead and ``b`` left of the pose's origin) and, for :class:`Drive`
events, the vehicle of :mod:`ekfviz.models.ackermann`. Classic logs keep the classic
filter and its compiled kernel; these models update sequentially (the ``--update joint``
option does not apply to them), on numpy, or in the kernel where the map is large
enough to keep P's changes pending (``model_update``: a landmark's H P and whitened rows
in a few vectorised passes, where numpy takes a dozen calls); the Ackermann vehicle's
spans are driven in the kernel too (``ackermann_drive``, the same floats).

The state's pose is the vehicle's origin (the rear axle's centre for the Ackermann
vehicle), where the models are simplest. Its records may report another point of the
vehicle instead (``reported_point``): Victoria Park's GPS antenna sits above the laser,
so its path is the laser's, and so are the robot's pose and ellipses in the recording.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ekfviz.core.batch import StateParts
from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.types import FloatArray
from ekfviz.filters.ekf import (
    _NOT_DEFINITE,
    _ZERO_RANGE,
    MIN_PREDICTED_RANGE,
    EkfSlam,
    _nan_table,
    _not_definite,
    _whitened,
    _zero_range,
)
from ekfviz.models.ackermann import Ackermann
from ekfviz.models.angles import wrap_angle
from ekfviz.models.range_bearing import RangeBearing

try:
    from ekfviz.filters import _kernel
except ImportError:  # installed without a C compiler: numpy throughout
    _kernel = None  # type: ignore[assignment]

_NO_SPANS = np.zeros((0, 3))  # where the kernel drove them
_NO_SPANS.flags.writeable = False

# what _kernel.model_update says of a line: S not finite, or U full (fold it, go on)
_S_NOT_FINITE, _U_FULL = 1, 3


class ModelEkfSlam(EkfSlam):
    """EKF-SLAM with a vehicle model and an offset range-bearing sensor, on numpy.

    :param vehicle: drives :meth:`drive`; ``None``: only the classic :meth:`predict`
    :param sensor: the measurement model
    :param reported_point: (ahead, left) in metres: the point of the vehicle whose pose
        the batches report (the state keeps the origin's); (0, 0) by default
    :param compiled: run the sequential update of a large map (where its changes of P are
        deferred) in the compiled kernel, where it was built (see :meth:`_update_sequential`)
    """

    def __init__(
        self,
        params: FilterParams | None = None,
        *,
        vehicle: Ackermann | None = None,
        sensor: RangeBearing | None = None,
        capacity: int = 0,
        reported_point: tuple[float, float] = (0.0, 0.0),
        compiled: bool = True,
    ) -> None:
        super().__init__(params, capacity=capacity, compiled=False)
        self._model_kernel = compiled and _kernel is not None
        self._kernel_wide = True  # the kernel's AVX2 loops where the CPU has them (tests: off)
        self.vehicle = vehicle
        self.sensor = sensor if sensor is not None else RangeBearing()
        self.reported_point = reported_point

    def pose_block(self) -> tuple[FloatArray, FloatArray]:
        """The built-in's pose block, moved to :attr:`reported_point`.

        The point p = (x, y) + R(theta) (a, b) and its covariance J P J^T, with J the
        identity but for the column of theta, (-a s - b c, a c - b s).
        """
        pose, pose_cov = super().pose_block()
        a, b = self.reported_point
        if a == 0.0 and b == 0.0:
            return pose, pose_cov
        x, y, theta = pose.tolist()
        c, s = math.cos(theta), math.sin(theta)
        j0, j1 = -a * s - b * c, a * c - b * s  # J's column of theta
        moved = np.array((x + a * c - b * s, y + a * s + b * c, theta))
        # J P J^T in floats (J the identity but for J[0, 2], J[1, 2]), exactly symmetric
        (p00, p01, p02), (_, p11, p12), (_, _, p22) = pose_cov.tolist()
        r02, r12 = p02 + j0 * p22, p12 + j1 * p22
        m00 = (p00 + j0 * p02) + j0 * r02
        m01 = (p01 + j0 * p12) + j1 * r02
        m11 = (p11 + j1 * p12) + j1 * r12
        return moved, np.array(((m00, m01, r02), (m01, m11, r12), (r02, r12, p22)))

    def state_parts(self, full_cov: bool = False) -> StateParts:
        """The built-in's state parts, the pose moved (:meth:`pose_block`); the full
        covariance, where asked for, likewise (only the rows and columns of x and y)."""
        parts = super().state_parts(full_cov)
        a, b = self.reported_point
        whole = parts.full_cov
        if whole is None or (a == 0.0 and b == 0.0):
            return parts
        theta = float(self._x[2])
        c, s = math.cos(theta), math.sin(theta)
        J = np.eye(3)
        J[0, 2], J[1, 2] = -a * s - b * c, a * c - b * s
        T = np.eye(len(whole))
        T[:3, :3] = J
        whole = T @ whole @ T.T
        whole[:3, :3] = parts.pose_cov  # the same floats as the pose block
        return parts._replace(full_cov=whole)

    def drive(self, segments: FloatArray) -> None:
        """Drive the vehicle through (speed, steering, dt) spans in one predict; O(N).

        Each span is linearised at the pose it starts from, as one predict per span
        would; the pose block is propagated span by span and the cross-covariances
        with the map once, with the product of the spans' G. The spans of the built-in
        :class:`Ackermann` run in the kernel (``ackermann_drive``) where it was built:
        the same float operations, the same results.
        """
        if self.vehicle is None:
            raise FilterError("this filter has no vehicle model for speed and steering controls")
        n = self._n
        x, P = self._x, self._P
        vehicle = self.vehicle
        qv, qs = vehicle.sigma_speed**2, vehicle.sigma_steering**2  # Q = diag(qv, qs)
        # the pose and the upper triangle of its covariance in floats: a span costs a few
        # dozen float operations where 3x3 products cost a few microseconds each
        px, py, pt = x[:3].tolist()
        (p00, p01, p02), (_, p11, p12), (_, _, p22) = P[:3, :3].tolist()
        # the product of the spans' G is the identity but for column theta: (a, b, 1)
        a_all = b_all = 0.0
        spans = np.asarray(segments, dtype=np.float64)
        if self._model_kernel and type(vehicle) is Ackermann:  # the same floats, in C
            (px, py, pt, p00, p01, p02, p11, p12, p22, a_all, b_all) = _kernel.ackermann_drive(
                np.ascontiguousarray(spans), px, py, pt, p00, p01, p02, p11, p12, p22,
                vehicle.wheelbase, vehicle.encoder_offset, qv, qs,
            )  # fmt: skip
            spans = _NO_SPANS
        for speed, steering, dt in spans.tolist():
            if dt <= 0.0:
                continue
            (nx, ny, nt, g02, g12, w00, w01, w10, w11, w20, w21) = vehicle.step(
                px, py, pt, speed, steering, dt
            )
            # G P G^T, G the identity but for G[0, 2] = g02 and G[1, 2] = g12
            r02 = p02 + g02 * p22
            r12 = p12 + g12 * p22
            m00 = (p00 + g02 * p02) + g02 * r02
            m01 = (p01 + g02 * p12) + g12 * r02
            m11 = (p11 + g12 * p12) + g12 * r12
            # + W Q W^T
            p00 = m00 + (qv * w00 * w00 + qs * w01 * w01)
            p01 = m01 + (qv * w00 * w10 + qs * w01 * w11)
            p02 = r02 + (qv * w00 * w20 + qs * w01 * w21)
            p11 = m11 + (qv * w10 * w10 + qs * w11 * w11)
            p12 = r12 + (qv * w10 * w20 + qs * w11 * w21)
            p22 = p22 + (qv * w20 * w20 + qs * w21 * w21)
            a_all += g02
            b_all += g12
            px, py, pt = nx, ny, nt
        if not math.isfinite(px + py + pt + p00 + p01 + p02 + p11 + p12 + p22):
            raise FilterError("the state became non-finite in predict")
        x[:3] = (px, py, pt)
        if self._rank:  # the pending changes of P through G_all (see EkfSlam._fold)
            self._predict_pending(a_all, b_all)
        if n > 3:
            # rows x and y of G_all P_rm (row theta unchanged), and their mirror
            P[0, 3:n] += a_all * P[2, 3:n]
            P[1, 3:n] += b_all * P[2, 3:n]
            P[3:n, 0] = P[0, 3:n]
            P[3:n, 1] = P[1, 3:n]
        P[:3, :3] = ((p00, p01, p02), (p01, p11, p12), (p02, p12, p22))

    def _update_sequential(
        self,
        ids: list[int],
        z: list[list[float]],
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """EKF updates with the known landmarks one after another, in file order, with
        the sensor model: :meth:`_update_numpy`, or, where P's changes are deferred (a
        large map) and the kernel was built, the same loop in ``_kernel.c``
        (``model_update``), which makes H P and the whitened rows in a few passes over
        the rows involved, where numpy takes a dozen calls per landmark. Its sums are
        numpy's to round-off (fused multiply-adds, another order), not to the bit.
        """
        U, rank = self._pending()
        if not (self._model_kernel and U.shape[0]):
            self._update_numpy(ids, z, known, table, skipped)
            return
        m = len(ids)
        slot = self._slot
        slots = [-1] * m
        for k in known:
            slots[k] = slot[ids[k]]
        slot_array = np.array(slots, dtype=np.int64)
        z_array = np.array(z, dtype=np.float64).reshape(m, 2)
        values = _nan_table(m)
        status = np.zeros(m, dtype=np.int8)
        n = self._n
        a, b = self.sensor.a, self.sensor.b
        r00, r01, r11 = (float(v) for v in (self._R[0, 0], self._R[0, 1], self._R[1, 1]))
        start = 0
        while True:
            code, k, rank = _kernel.model_update(
                self._x, self._P, U, n, rank, slot_array, z_array, values, status, start,
                a, b, r00, r01, r11, MIN_PREDICTED_RANGE, self._kernel_wide,
            )  # fmt: skip
            self._rank = rank  # at once: an error later in the line leaves P as it is
            if code != _U_FULL:
                break
            self._subtract_gram(U[:, :n])  # as _fold does once U is full
            self._rank = rank = 0
            if k >= m:
                break
            start = k
        if code == _S_NOT_FINITE:
            raise FilterError(f"the covariance became non-finite (S of landmark {ids[k]})")
        for k in known:  # in file order: the warnings as the numpy loop gives them
            why = int(status[k])
            if why == _ZERO_RANGE:
                self._skip(k, ids[k], skipped, _zero_range(float(values[k, 1])))
                continue  # its row stays NaN
            if why == _NOT_DEFINITE:
                s00, s01, _, s11 = values[k, 4:8].tolist()
                self._skip(k, ids[k], skipped, _not_definite(s00, s01, s11))
            table[k] = tuple(values[k].tolist())

    def _update_numpy(
        self,
        ids: list[int],
        z: list[list[float]],
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """EKF updates with the known landmarks one after another, in file order, with
        the sensor model (H has the 5 non-zero columns 0, 1, 2, j, j+1), on numpy.

        As in :meth:`EkfSlam._update_sequential`: with S = L L^T, A = L^-1 H P (2 x n) and
        w = L^-1 nu, x += A^T w at once and P -= A^T A deferred. The rank-2 changes are
        kept as the rows of U, so that the current P is P - U^T U: its rows c (all that
        H P needs) cost O(rank n), and P itself is changed once per ``DEFER_LANDMARKS``
        landmarks (one pass), across scans, instead of once per landmark or per scan
        (Victoria Park's state has 600 to 900 rows and a scan sees 5 landmarks).
        """
        n = self._n
        x = self._x[:n]
        P_buffer = self._P
        spare = P_buffer.shape[0] > n
        r00, r01, r11 = (float(v) for v in (self._R[0, 0], self._R[0, 1], self._R[1, 1]))
        U, rank = self._pending()  # the current P is P - U[:rank, :n]^T U[:rank, :n]
        a, b = self.sensor.a, self.sensor.b
        for k in known:
            landmark_id = ids[k]
            j = self._slot[landmark_id]
            rows = self._rows.get(j)
            if rows is None:
                rows = self._rows[j] = np.array((0, 1, 2, j, j + 1))
            # the sensor model's measure() and jacobians(), the same operations in floats
            px, py, theta, lx, ly = x.take(rows).tolist()
            c, s = math.cos(theta), math.sin(theta)
            ox, oy = a * c - b * s, a * s + b * c  # the sensor's offset; d/dtheta: (-oy, ox)
            dx, dy = lx - (px + ox), ly - (py + oy)
            bearing = wrap_angle(math.atan2(dy, dx) - theta)
            rng = math.hypot(dx, dy)
            if not rng > MIN_PREDICTED_RANGE:
                self._skip(k, landmark_id, skipped, _zero_range(rng))
                continue
            q = dx * dx + dy * dy
            r = math.sqrt(q)
            H = np.array(
                (
                    (dy / q, -dx / q, (dy * -oy - dx * ox) / q - 1.0, -dy / q, dx / q),
                    (-dx / r, -dy / r, (-dx * -oy - dy * ox) / r, dx / r, dy / r),
                )
            )
            P_c = P_buffer.take(rows, 0)  # the rows c of P (5 x capacity)
            HP = H.dot(P_c[:, :n] if spare else P_c)
            if rank:
                U_r = U[:rank]  # contiguous rows of the buffer: take() copies no more
                HP -= H.dot(U_r.take(rows, 1).T).dot(U_r[:, :n])
            (S00, S01), (S10, S11) = HP.take(rows, 1).dot(H.T).tolist()
            s00, s11 = S00 + r00, S11 + r11
            s01 = 0.5 * (S01 + S10) + r01
            if not math.isfinite(s00 + s01 + s11):
                raise FilterError(f"the covariance became non-finite (S of landmark {landmark_id})")
            z_bearing, z_range = z[k]
            nu0 = wrap_angle(z_bearing - bearing)
            nu1 = z_range - rng
            whitened = _whitened(HP, s00, s01, s11, nu0, nu1)
            if whitened is None:
                table[k] = (bearing, rng, nu0, nu1, s00, s01, s01, s11, math.nan)
                self._skip(k, landmark_id, skipped, _not_definite(s00, s01, s11))
                continue
            B, w0, w1 = whitened
            np.add(x, B[2], out=x)
            x[2] = wrap_angle(float(x[2]))
            rank = self._fold(B[:2], U, rank)
            table[k] = (bearing, rng, nu0, nu1, s00, s01, s01, s11, w0 * w0 + w1 * w1)
        self._rank = rank  # left pending (see ekfviz.filters.ekf)

    def _update_joint(
        self,
        ids: list[int],
        z: FloatArray,
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """The sensor models update sequentially (see the module)."""
        self._update_sequential(ids, np.asarray(z).tolist(), known, table, skipped)

    def _initial_landmark(
        self, pose_xytheta: FloatArray, z: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The sensor's inverse model and its Jacobians (the rest is the built-in's)."""
        l_D_pose, l_D_z = self.sensor.inverse_jacobians(pose_xytheta, z)
        return self.sensor.inverse(pose_xytheta, z), l_D_pose, l_D_z
