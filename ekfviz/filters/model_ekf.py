"""The built-in EKF-SLAM with pluggable models: a vehicle and a sensor off its origin.

:class:`ModelEkfSlam` is :class:`~ekfviz.filters.ekf.EkfSlam` (same buffers, records,
landmark removal) with the measurement model of :mod:`ekfviz.models.range_bearing` (a
sensor mounted ``a`` ahead and ``b`` left of the pose's origin) and, for :class:`Drive`
events, the vehicle of :mod:`ekfviz.models.ackermann`. Classic logs keep the classic
filter and its compiled kernel; these models run on numpy, sequentially (the
``--update joint`` option does not apply to them).

The state's pose is the vehicle's origin (the rear axle's centre for the Ackermann
vehicle), where the models are simplest. Its records may report another point of the
vehicle instead (``reported_point``): Victoria Park's GPS antenna sits above the laser,
so its path is the laser's, and so are the robot's pose and ellipses in the recording.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ekfviz.core.records import EventRecord
from ekfviz.core.types import FloatArray
from ekfviz.filters.ekf import (
    MIN_PREDICTED_RANGE,
    EkfSlam,
    FilterError,
    FilterParams,
    _not_definite,
    _zero_range,
)
from ekfviz.models.ackermann import Ackermann
from ekfviz.models.angles import wrap_angle
from ekfviz.models.range_bearing import RangeBearing


class ModelEkfSlam(EkfSlam):
    """EKF-SLAM with a vehicle model and an offset range-bearing sensor, on numpy.

    :param vehicle: drives :meth:`drive`; ``None``: only the classic :meth:`predict`
    :param sensor: the measurement model
    :param reported_point: (ahead, left) in metres: the point of the vehicle whose pose
        the records report (the state keeps the origin's); (0, 0) by default
    """

    def __init__(
        self,
        params: FilterParams | None = None,
        *,
        vehicle: Ackermann | None = None,
        sensor: RangeBearing | None = None,
        capacity: int = 0,
        reported_point: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        super().__init__(params, capacity=capacity, compiled=False)
        self.vehicle = vehicle
        self.sensor = sensor if sensor is not None else RangeBearing()
        self.reported_point = reported_point

    def record(self, **kwargs: Any) -> EventRecord:
        """The built-in's record, its pose moved to :attr:`reported_point`.

        The point p = (x, y) + R(theta) (a, b) and its covariance J P J^T, with J the
        identity but for the column of theta, (-a s - b c, a c - b s); the full
        covariance, where recorded, likewise (only the rows and columns of x and y).
        """
        record = super().record(**kwargs)
        a, b = self.reported_point
        if a == 0.0 and b == 0.0:
            return record
        x, y, theta = record.pose.tolist()
        c, s = math.cos(theta), math.sin(theta)
        J = np.eye(3)
        J[0, 2], J[1, 2] = -a * s - b * c, a * c - b * s
        pose = np.array((x + a * c - b * s, y + a * s + b * c, theta))
        pose_cov = J @ record.pose_cov @ J.T
        full_cov = record.full_cov
        if full_cov is not None:
            T = np.eye(len(full_cov))
            T[:3, :3] = J
            full_cov = T @ full_cov @ T.T
        for array in (pose, pose_cov, full_cov):
            if array is not None:
                array.setflags(write=False)
        return dataclasses.replace(record, pose=pose, pose_cov=pose_cov, full_cov=full_cov)

    def drive(self, segments: FloatArray) -> None:
        """Drive the vehicle through (speed, steering, dt) spans in one predict; O(N).

        Each span is linearised at the pose it starts from, as one predict per span
        would; the pose block is propagated span by span and the cross-covariances
        with the map once, with the product of the spans' G.
        """
        if self.vehicle is None:
            raise FilterError("this filter has no vehicle model for speed and steering controls")
        n = self._n
        x, P = self._x, self._P
        pose = x[:3].copy()
        P_rr = P[:3, :3].copy()
        G_all = np.eye(3)
        Q = self.vehicle.Q
        for speed, steering, dt in np.asarray(segments, dtype=np.float64).tolist():
            if dt <= 0.0:
                continue
            G, W = self.vehicle.jacobians(pose, speed, steering, dt)
            pose = self.vehicle.motion(pose, speed, steering, dt)
            P_rr = G @ P_rr @ G.T + W @ Q @ W.T
            G_all = G @ G_all
        if not (np.isfinite(pose).all() and np.isfinite(P_rr).all()):
            raise FilterError("the state became non-finite in predict")
        x[:3] = pose
        if n > 3:
            P_rm = G_all @ P[:3, 3:n]
            P[:3, 3:n] = P_rm
            P[3:n, :3] = P_rm.T
        P[:3, :3] = 0.5 * (P_rr + P_rr.T)

    def _update_sequential(
        self,
        ids: list[int],
        z: list[list[float]],
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """EKF updates with the known landmarks one after another, in file order, with
        the sensor model (H has the 5 non-zero columns 0, 1, 2, j, j+1)."""
        n = self._n
        x, P = self._x[:n], self._P[:n, :n]
        R = self._R
        for k in known:
            landmark_id = ids[k]
            j = self._slot[landmark_id]
            rows = np.array((0, 1, 2, j, j + 1))
            pose, landmark = x[:3], x[j : j + 2]
            z_pred = self.sensor.measure(pose, landmark)
            if not z_pred[1] > MIN_PREDICTED_RANGE:
                self._skip(k, landmark_id, skipped, _zero_range(float(z_pred[1])))
                continue
            z_D_pose, z_D_landmark = self.sensor.jacobians(pose, landmark)
            H = np.hstack([z_D_pose, z_D_landmark])
            HP = H @ P[rows]
            S = HP[:, rows] @ H.T + R
            S = 0.5 * (S + S.T)
            nu = np.array(z[k]) - z_pred
            nu[0] = wrap_angle(float(nu[0]))
            s00, s01, s11 = float(S[0, 0]), float(S[0, 1]), float(S[1, 1])
            if not math.isfinite(s00 + s01 + s11):
                raise FilterError(f"the covariance became non-finite (S of landmark {landmark_id})")
            try:
                L = np.linalg.cholesky(S)
            except np.linalg.LinAlgError:
                table[k] = (*z_pred.tolist(), *nu.tolist(), s00, s01, s01, s11, math.nan)
                self._skip(k, landmark_id, skipped, _not_definite(s00, s01, s11))
                continue
            A = np.linalg.solve(L, HP)
            w = np.linalg.solve(L, nu)
            x += w @ A
            P -= A.T @ A
            x[2] = wrap_angle(float(x[2]))
            table[k] = (*z_pred.tolist(), *nu.tolist(), s00, s01, s01, s11, float(w @ w))

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
