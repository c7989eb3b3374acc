"""(bearing, range) of a landmark seen from a sensor mounted off the vehicle's origin.

The sensor sits ``a`` metres ahead of the pose's origin and ``b`` metres to its left
(Victoria Park's laser: a = 3.78 m ahead of the rear axle, b = 0.50 m left); its
bearing is measured from the vehicle's heading. With a = b = 0 this is the classic
model of :mod:`ekfviz.models.classic`. Sensor position::

    s = (x + a cos(theta) - b sin(theta), y + a sin(theta) + b cos(theta))
    z = (atan2(l_y - s_y, l_x - s_x) - theta, |l - s|)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle, wrap_angles


@dataclass(frozen=True, slots=True)
class RangeBearing:
    """The measurement model of a sensor at (``a``, ``b``) in the vehicle frame."""

    a: float = 0.0
    b: float = 0.0

    @property
    def classic(self) -> bool:
        return self.a == 0.0 and self.b == 0.0

    def sensor(self, pose_xytheta: FloatArray) -> tuple[float, float, float, float]:
        """The sensor's position and its derivative with respect to theta.

        :return: (s_x, s_y, ds_x/dtheta, ds_y/dtheta)
        """
        # one conversion to Python floats (a generator of float() cost more than the rest)
        x, y, theta = np.asarray(pose_xytheta[:3], dtype=np.float64).tolist()
        c, s = math.cos(theta), math.sin(theta)
        ox, oy = self.a * c - self.b * s, self.a * s + self.b * c
        return x + ox, y + oy, -oy, ox

    def measure(self, pose_xytheta: FloatArray, landmark_xy: FloatArray) -> FloatArray:
        """Noise-free (bearing, range) (2,), bearing wrapped to (-pi, pi]."""
        sx, sy, _, _ = self.sensor(pose_xytheta)
        dx, dy = float(landmark_xy[0]) - sx, float(landmark_xy[1]) - sy
        return np.array(
            [wrap_angle(math.atan2(dy, dx) - float(pose_xytheta[2])), math.hypot(dx, dy)]
        )

    def jacobians(
        self, pose_xytheta: FloatArray, landmark_xy: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """:return: (z_D_pose (2x3), z_D_landmark (2x2)), rows (bearing, range)"""
        sx, sy, sx_D_theta, sy_D_theta = self.sensor(pose_xytheta)
        dx, dy = float(landmark_xy[0]) - sx, float(landmark_xy[1]) - sy
        q = dx * dx + dy * dy
        r = math.sqrt(q)
        z_D_landmark = np.array([[-dy / q, dx / q], [dx / r, dy / r]])
        # the sensor moves with the pose: d/ds = -d/dl, and ds/dtheta from the offset
        z_D_pose = np.array(
            [
                [dy / q, -dx / q, (dy * sx_D_theta - dx * sy_D_theta) / q - 1.0],
                [-dx / r, -dy / r, (-dx * sx_D_theta - dy * sy_D_theta) / r],
            ]
        )
        return z_D_pose, z_D_landmark

    def inverse(self, pose_xytheta: FloatArray, z: FloatArray) -> FloatArray:
        """Where a landmark seen at ``z`` = (bearing, range) lies (2,)."""
        sx, sy, _, _ = self.sensor(pose_xytheta)
        phi = float(pose_xytheta[2]) + float(z[0])
        return np.array([sx + float(z[1]) * math.cos(phi), sy + float(z[1]) * math.sin(phi)])

    def inverse_jacobians(
        self, pose_xytheta: FloatArray, z: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """:return: (l_D_pose (2x3), l_D_z (2x2)) of :meth:`inverse`, z = (bearing, range)"""
        _, _, sx_D_theta, sy_D_theta = self.sensor(pose_xytheta)
        rng = float(z[1])
        phi = float(pose_xytheta[2]) + float(z[0])
        c, s = math.cos(phi), math.sin(phi)
        l_D_pose = np.array([[1.0, 0.0, sx_D_theta - rng * s], [0.0, 1.0, sy_D_theta + rng * c]])
        l_D_z = np.array([[-rng * s, c], [rng * c, s]])
        return l_D_pose, l_D_z

    def predict_all(
        self, pose_xytheta: FloatArray, landmarks_xy: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`measure` and :meth:`jacobians` of many landmarks at once.

        :param landmarks_xy: (N, 2)
        :return: z_pred (N, 2), z_D_pose (N, 2, 3), z_D_landmark (N, 2, 2)
        """
        sx, sy, sx_D_theta, sy_D_theta = self.sensor(pose_xytheta)
        dx = landmarks_xy[:, 0] - sx
        dy = landmarks_xy[:, 1] - sy
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        n = len(dx)
        z_pred = np.empty((n, 2))
        z_pred[:, 0] = wrap_angles(np.arctan2(dy, dx) - float(pose_xytheta[2]))
        z_pred[:, 1] = r
        z_D_landmark = np.empty((n, 2, 2))
        z_D_landmark[:, 0, 0] = -dy / q
        z_D_landmark[:, 0, 1] = dx / q
        z_D_landmark[:, 1, 0] = dx / r
        z_D_landmark[:, 1, 1] = dy / r
        z_D_pose = np.empty((n, 2, 3))
        z_D_pose[:, :, :2] = -z_D_landmark
        z_D_pose[:, 0, 2] = (dy * sx_D_theta - dx * sy_D_theta) / q - 1.0
        z_D_pose[:, 1, 2] = (-dx * sx_D_theta - dy * sy_D_theta) / r
        return z_pred, z_D_pose, z_D_landmark
