"""(bearing, range) of a landmark seen from a sensor mounted off the vehicle's origin.

The sensor sits ``a`` metres ahead of the pose's origin and ``b`` metres to its left
(Victoria Park's laser: a = 3.78 m ahead of the rear axle, b = 0.50 m left); its
bearing is measured from the vehicle's heading. With a = b = 0 this is the classic
model of :mod:`ekfviz.models.classic`, whose operations it applies to the landmark's
offset from the sensor. Sensor position::

    s = (x + a cos(theta) - b sin(theta), y + a sin(theta) + b cos(theta))
    z = (atan2(l_y - s_y, l_x - s_x) - theta, |l - s|)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.models.classic import (
    expected_measurement,
    init_jacobian_measurement,
    init_jacobian_pose,
    landmark_from_measurement,
    landmark_offset,
    measurement_jacobian_landmark,
    measurement_jacobian_pose,
)


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
        """Noise-free (bearing, range) (2,), bearing wrapped to (-pi, pi]: the classic h(x)
        of the landmark's offset from the sensor."""
        sx, sy, _, _ = self.sensor(pose_xytheta)
        offset = landmark_offset(np.array([sx, sy]), landmark_xy)
        return expected_measurement(offset, float(pose_xytheta[2]))

    def jacobians(
        self, pose_xytheta: FloatArray, landmark_xy: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """The classic H_p and H_l of the landmark's offset from the sensor, H_p's heading
        column with the sensor's own motion (see :meth:`predict_all`).

        :return: (z_D_pose (2x3), z_D_landmark (2x2)), rows (bearing, range)
        """
        sx, sy, sx_D_theta, sy_D_theta = self.sensor(pose_xytheta)
        offset = landmark_offset(np.array([sx, sy]), landmark_xy)  # (2,): in floats below
        z_D_pose = measurement_jacobian_pose(offset)
        dx, dy = offset.tolist()
        z_D_pose[:, 2] = heading_column(dx, dy, sx_D_theta, sy_D_theta)
        return z_D_pose, measurement_jacobian_landmark(offset)

    def inverse(self, pose_xytheta: FloatArray, z: FloatArray) -> FloatArray:
        """Where a landmark seen at ``z`` = (bearing, range) lies (2,): the classic inverse
        from the sensor's position."""
        sx, sy, _, _ = self.sensor(pose_xytheta)
        return landmark_from_measurement(np.array([sx, sy, float(pose_xytheta[2])]), z)

    def inverse_jacobians(
        self, pose_xytheta: FloatArray, z: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """The classic J_p and J_z from the sensor's position, J_p's heading column with the
        sensor's own motion ds/dtheta added.

        :return: (l_D_pose (2x3), l_D_z (2x2)) of :meth:`inverse`, z = (bearing, range)
        """
        sx, sy, sx_D_theta, sy_D_theta = self.sensor(pose_xytheta)
        at_sensor = np.array([sx, sy, float(pose_xytheta[2])])
        l_D_pose = init_jacobian_pose(at_sensor, z)
        l_D_pose[:, 2] += (sx_D_theta, sy_D_theta)
        return l_D_pose, init_jacobian_measurement(at_sensor, z)

    def predict_all(
        self, pose_xytheta: FloatArray, landmarks_xy: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`measure` and :meth:`jacobians` of many landmarks at once: the classic h(x),
        H_p and H_l of each landmark's offset (dx, dy) from the sensor, H_p's heading column
        with the sensor's own motion (:func:`heading_column`).

        :param landmarks_xy: (N, 2)
        :return: z_pred (N, 2), z_D_pose (N, 2, 3), z_D_landmark (N, 2, 2)
        """
        sx, sy, sx_D_theta, sy_D_theta = self.sensor(pose_xytheta)
        offset = landmark_offset(np.array([sx, sy]), landmarks_xy).reshape(-1, 2)
        z_pred = expected_measurement(offset, float(pose_xytheta[2]))
        z_D_landmark = measurement_jacobian_landmark(offset)
        z_D_pose = measurement_jacobian_pose(offset)
        z_D_pose[:, 0, 2], z_D_pose[:, 1, 2] = heading_column(
            offset[:, 0], offset[:, 1], sx_D_theta, sy_D_theta
        )
        return z_pred, z_D_pose, z_D_landmark


Scalar = float | FloatArray


def heading_column(
    dx: Scalar, dy: Scalar, sx_D_theta: float, sy_D_theta: float
) -> tuple[Scalar, Scalar]:
    """H_p's heading column for a sensor that moves with the pose, of the landmark's
    offset (dx, dy) from the sensor (floats, or arrays (K,) of many landmarks):
    dz/dtheta = ((dy ds_x - dx ds_y) / q - 1, (-dx ds_x - dy ds_y) / sqrt(q)),
    q = dx^2 + dy^2, ds = ds/dtheta."""
    q = dx * dx + dy * dy
    return (dy * sx_D_theta - dx * sy_D_theta) / q - 1.0, (
        -dx * sx_D_theta - dy * sy_D_theta
    ) / q**0.5
