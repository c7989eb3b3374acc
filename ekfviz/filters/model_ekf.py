"""The built-in EKF-SLAM with pluggable models: a vehicle and a sensor off its origin.

:class:`ModelEkfSlam` is :class:`~ekfviz.filters.ekf.EkfSlam` (same buffers, records,
landmark removal) with the measurement model of :mod:`ekfviz.models.range_bearing` (a
sensor mounted ``a`` ahead and ``b`` left of the pose's origin) and, for :class:`Drive`
events, the vehicle of :mod:`ekfviz.models.ackermann`. Classic logs keep the classic
filter and its compiled kernel; these models update sequentially (the ``--update joint``
option does not apply to them), on numpy (the built-in's loop of named operations, with
the sensor's h(x) and H: :meth:`ModelEkfSlam._predicted`), or in the kernel where the map
is large enough to keep P's changes pending (``model_update``: a landmark's H P and
whitened rows in a few vectorised passes, where numpy takes a dozen calls); the
Ackermann vehicle's spans are driven in the kernel too (``ackermann_drive``, whose Python
reference is :meth:`ModelEkfSlam.drive`'s loop of the named operations).

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
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.ekf_update import (
    MIN_PREDICTED_RANGE,
    NOT_DEFINITE,
    ZERO_RANGE,
    nan_table,
    not_definite,
    zero_range,
)
from ekfviz.models.ackermann import Ackermann
from ekfviz.models.kalman import (
    predicted_cross_covariance,
    predicted_pose_covariance,
)
from ekfviz.models.range_bearing import RangeBearing

try:
    from ekfviz.filters import _kernel
except ImportError:  # installed without a C compiler: numpy throughout
    _kernel = None  # type: ignore[assignment]

_UPPER = np.triu_indices(3)  # the upper triangle of a 3x3 block, row by row

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
        would: P_rr' = G P_rr G^T + W Q W^T span by span, and the cross-covariances with
        the map once, P_rm' = G_all P_rm with G_all the product of the spans' G (the
        identity but for the sum of their heading columns). The spans of the built-in
        :class:`Ackermann` run in the kernel (``ackermann_drive``) where it was built; this
        loop of the named operations is its Python reference.
        """
        if self.vehicle is None:
            raise FilterError("this filter has no vehicle model for speed and steering controls")
        x, P = self._x, self._P
        vehicle = self.vehicle
        Q = vehicle.Q
        spans = np.asarray(segments, dtype=np.float64)
        if self._model_kernel and type(vehicle) is Ackermann:  # the same algebra, in C
            (px, py, pt), (p00, p01, p02, p11, p12, p22) = x[:3].tolist(), P[_UPPER].tolist()
            (px, py, pt, p00, p01, p02, p11, p12, p22, a_all, b_all) = _kernel.ackermann_drive(
                np.ascontiguousarray(spans), px, py, pt, p00, p01, p02, p11, p12, p22,
                vehicle.wheelbase, vehicle.encoder_offset, float(Q[0, 0]), float(Q[1, 1]),
            )  # fmt: skip
            if not math.isfinite(px + py + pt + p00 + p01 + p02 + p11 + p12 + p22):
                raise FilterError("the state became non-finite in predict")
            P_rr = ((p00, p01, p02), (p01, p11, p12), (p02, p12, p22))
            self._driven((px, py, pt), P_rr, a_all, b_all)
            return
        pose, P_rr_now = x[:3].copy(), P[:3, :3].copy()
        a_all = b_all = 0.0
        for speed, steering, dt in spans.tolist():
            if dt <= 0.0:
                continue
            G, W = vehicle.jacobians(pose, speed, steering, dt)
            P_rr_now = predicted_pose_covariance(P_rr_now, G, W, Q)
            pose = vehicle.motion(pose, speed, steering, dt)
            a_all, b_all = a_all + float(G[0, 2]), b_all + float(G[1, 2])
        if not (np.isfinite(pose).all() and np.isfinite(P_rr_now).all()):
            raise FilterError("the state became non-finite in predict")
        self._driven(pose, P_rr_now, a_all, b_all)

    def _driven(
        self,
        pose: FloatArray | tuple[float, float, float],
        P_rr: FloatArray | tuple[tuple[float, float, float], ...],
        a_all: float,
        b_all: float,
    ) -> None:
        """Write a drive's pose and pose covariance into the state, and take the cross-
        covariances with the map through G_all (the identity but for its heading column
        (a_all, b_all, 1)): P_rm' = G_all P_rm."""
        n, x, P = self._n, self._x, self._P
        x[:3] = pose
        if self._rank:  # the pending changes of P through G_all (see EkfSlam._fold)
            self._predict_pending(a_all, b_all)
        if n > 3:
            G_all = np.array(((1.0, 0.0, a_all), (0.0, 1.0, b_all), (0.0, 0.0, 1.0)))
            P_rm = predicted_cross_covariance(G_all, P[:3, 3:n])
            P[:3, 3:n] = P_rm
            P[3:n, :3] = P_rm.T
        P[:3, :3] = P_rr

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
            super()._update_sequential(ids, z, known, table, skipped)
            return
        m = len(ids)
        slot = self._slot
        slots = [-1] * m
        for k in known:
            slots[k] = slot[ids[k]]
        slot_array = np.array(slots, dtype=np.int64)
        z_array = np.array(z, dtype=np.float64).reshape(m, 2)
        values = nan_table(m)
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
            if why == ZERO_RANGE:
                self._skip(k, ids[k], skipped, zero_range(float(values[k, 1])))
                continue  # its row stays NaN
            if why == NOT_DEFINITE:
                s00, s01, _, s11 = values[k, 4:8].tolist()
                self._skip(k, ids[k], skipped, not_definite(s00, s01, s11))
            table[k] = tuple(values[k].tolist())

    def _predicted(self, pose_and_landmark: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The sensor model's h(x) (2,) and H's five non-zero columns (2, 5) (see
        :meth:`~ekfviz.filters.ekf_update.LineUpdates._predicted`)."""
        pose, landmark = pose_and_landmark[:3], pose_and_landmark[3:]
        z_pred = self.sensor.measure(pose, landmark)
        if not z_pred[1] > MIN_PREDICTED_RANGE:  # no Jacobian there: the caller skips it
            return z_pred, np.full((2, 5), np.nan)
        z_D_pose, z_D_landmark = self.sensor.jacobians(pose, landmark)
        return z_pred, np.hstack((z_D_pose, z_D_landmark))

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
