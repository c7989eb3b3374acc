"""Motion and measurement models of 2-D EKF-SLAM with their analytic Jacobians.

Every equation here is the one in the project's reference, `docs/ekf-slam.md` of the
shared folder: a control (d, alpha) drives d metres along the heading and then turns by
alpha; a landmark is seen as (bearing, range) from the robot pose.
"""

from __future__ import annotations

import math

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle


def motion(pose_xytheta: FloatArray, d: float, alpha: float) -> FloatArray:
    """Noise-free motion model: drive ``d`` along the heading, then turn ``alpha``.

    :return: new pose (3,), theta wrapped to (-pi, pi]
    """
    x, y, theta = pose_xytheta
    return np.array([x + d * math.cos(theta), y + d * math.sin(theta), wrap_angle(theta + alpha)])


def motion_jacobians(pose_xytheta: FloatArray, d: float) -> tuple[FloatArray, FloatArray]:
    """Jacobians of the motion model at zero noise.

    :return: (G, W): G = d(pose')/d(pose) (3x3), W = d(pose')/d(e_x, e_y, e_a) (3x3);
        the noise acts in the robot frame (reference, section "Motion")
    """
    theta = pose_xytheta[2]
    c, s = math.cos(theta), math.sin(theta)
    G = np.array([[1.0, 0.0, -d * s], [0.0, 1.0, d * c], [0.0, 0.0, 1.0]])
    W = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return G, W


def measure(pose_xytheta: FloatArray, landmark_xy: FloatArray) -> FloatArray:
    """Noise-free measurement model.

    :return: (bearing, range) (2,), bearing wrapped to (-pi, pi]
    """
    dx = landmark_xy[0] - pose_xytheta[0]
    dy = landmark_xy[1] - pose_xytheta[1]
    return np.array([wrap_angle(math.atan2(dy, dx) - pose_xytheta[2]), math.hypot(dx, dy)])


def measurement_jacobians(
    pose_xytheta: FloatArray, landmark_xy: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Jacobians of (bearing, range) with respect to the pose and the landmark.

    :return: (z_D_pose (2x3), z_D_landmark (2x2)), rows ordered (bearing, range)
    """
    dx = landmark_xy[0] - pose_xytheta[0]
    dy = landmark_xy[1] - pose_xytheta[1]
    q = dx * dx + dy * dy
    r = math.sqrt(q)
    z_D_landmark = np.array([[-dy / q, dx / q], [dx / r, dy / r]])
    z_D_pose = np.array([[dy / q, -dx / q, -1.0], [-dx / r, -dy / r, 0.0]])
    return z_D_pose, z_D_landmark


def landmark_from_measurement(pose_xytheta: FloatArray, z: FloatArray) -> FloatArray:
    """Inverse measurement model: where a landmark seen at ``z`` = (bearing, range) lies.

    :return: landmark position (2,)
    """
    x, y, theta = pose_xytheta
    bearing, rng = z
    phi = theta + bearing
    return np.array([x + rng * math.cos(phi), y + rng * math.sin(phi)])


def landmark_init_jacobians(
    pose_xytheta: FloatArray, z: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Jacobians of the inverse measurement model.

    :return: (l_D_pose (2x3), l_D_z (2x2)) with z = (bearing, range)
    """
    theta = pose_xytheta[2]
    bearing, rng = z
    c, s = math.cos(theta + bearing), math.sin(theta + bearing)
    l_D_pose = np.array([[1.0, 0.0, -rng * s], [0.0, 1.0, rng * c]])
    l_D_z = np.array([[-rng * s, c], [rng * c, s]])
    return l_D_pose, l_D_z
