"""The classic models of 2-D EKF-SLAM, one named operation each, with analytic Jacobians.

Every equation is the one in the project's reference (`docs/ekf-slam.md` of the shared
folder), in its symbols: a control (d, alpha) drives d metres along the heading and then
turns by alpha, its noise (e_x, e_y, e_a) in the robot frame; a landmark l = (lx, ly) is
seen as (bearing, range) from the pose (x, y, theta). The filter's algebra over these
(S, K, the corrected mean and covariance, a new landmark's covariance) is in
:mod:`ekfviz.models.kalman`.

The operations of a measurement take the landmark's offset from the robot, (dx, dy) =
(lx - x, ly - y), as their operand, so that one offset serves h(x), H_p and H_l; they
accept an offset (2,) or many (K, 2) alike.
"""

from __future__ import annotations

import math

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle, wrap_angles

# -- motion (predict) ------------------------------------------------------------------------


def motion(pose_xytheta: FloatArray, d: float, alpha: float) -> FloatArray:
    """The noise-free motion: drive ``d`` along the heading, then turn ``alpha``.

    :return: the new pose (3,), theta wrapped to (-pi, pi]:
        x' = x + d cos(theta), y' = y + d sin(theta), theta' = wrap(theta + alpha)
    """
    x, y, theta = (float(v) for v in pose_xytheta[:3])
    return np.array([x + d * math.cos(theta), y + d * math.sin(theta), wrap_angle(theta + alpha)])


def motion_jacobian(pose_xytheta: FloatArray, d: float) -> FloatArray:
    """G, the motion's Jacobian with respect to the pose, at the pose before the motion.

    :return: (3, 3) G = [[1, 0, -d sin(theta)], [0, 1, d cos(theta)], [0, 0, 1]]
    """
    theta = float(pose_xytheta[2])
    return np.array(
        [[1.0, 0.0, -d * math.sin(theta)], [0.0, 1.0, d * math.cos(theta)], [0.0, 0.0, 1.0]]
    )


def noise_jacobian(pose_xytheta: FloatArray) -> FloatArray:
    """W, the motion's Jacobian with respect to its noise (e_x, e_y, e_a), which acts in the
    robot frame: the rotation by the heading before the motion.

    :return: (3, 3) W = [[cos(theta), -sin(theta), 0], [sin(theta), cos(theta), 0], [0, 0, 1]]
    """
    theta = float(pose_xytheta[2])
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def motion_jacobians(pose_xytheta: FloatArray, d: float) -> tuple[FloatArray, FloatArray]:
    """(G, W): :func:`motion_jacobian` and :func:`noise_jacobian`, both (3, 3)."""
    return motion_jacobian(pose_xytheta, d), noise_jacobian(pose_xytheta)


# -- measurement (update) --------------------------------------------------------------------


def landmark_offset(pose_xytheta: FloatArray, landmark_xy: FloatArray) -> FloatArray:
    """The landmark's offset from the robot in the world frame.

    :param landmark_xy: (2,) or (K, 2)
    :return: the same shape: (dx, dy) = (lx - x, ly - y)
    """
    return np.asarray(landmark_xy, dtype=np.float64) - np.asarray(pose_xytheta[:2], np.float64)


def expected_measurement(offset_xy: FloatArray, theta: float) -> FloatArray:
    """h(x): the (bearing, range) a landmark at ``offset_xy`` from the robot is seen at.

    :param offset_xy: (2,) or (K, 2) :func:`landmark_offset`
    :return: the same shape: (wrap(atan2(dy, dx) - theta), sqrt(q)), q = dx^2 + dy^2
    """
    dx, dy = _components(offset_xy)
    return _assembled((_wrap(_atan2(dy, dx) - theta), _sqrt(dx * dx + dy * dy)))


def measurement_jacobian_pose(offset_xy: FloatArray) -> FloatArray:
    """H_p, the Jacobian of h(x) with respect to the pose, rows (bearing, range).

    :param offset_xy: (2,) or (K, 2) :func:`landmark_offset`
    :return: (2, 3) or (K, 2, 3): [[dy/q, -dx/q, -1], [-dx/sqrt(q), -dy/sqrt(q), 0]]
    """
    dx, dy = _components(offset_xy)
    q = dx * dx + dy * dy
    r = _sqrt(q)
    return _assembled(((dy / q, -dx / q, -1.0), (-dx / r, -dy / r, 0.0)))


def measurement_jacobian_landmark(offset_xy: FloatArray) -> FloatArray:
    """H_l, the Jacobian of h(x) with respect to the landmark, rows (bearing, range).

    :param offset_xy: (2,) or (K, 2) :func:`landmark_offset`
    :return: (2, 2) or (K, 2, 2): [[-dy/q, dx/q], [dx/sqrt(q), dy/sqrt(q)]]
    """
    dx, dy = _components(offset_xy)
    q = dx * dx + dy * dy
    r = _sqrt(q)
    return _assembled(((-dy / q, dx / q), (dx / r, dy / r)))


def innovation(z: FloatArray, z_pred: FloatArray) -> FloatArray:
    """nu = z - h(x), its bearing wrapped after the subtraction (a difference of two
    bearings near +-pi is small, not about 2 pi).

    :param z: (2,) or (K, 2) measured (bearing, range); ``z_pred`` the same shape
    :return: the same shape: (wrap(beta - beta_pred), r - r_pred)
    """
    nu = np.asarray(z, dtype=np.float64) - np.asarray(z_pred, dtype=np.float64)
    nu[..., 0] = _wrap(nu[..., 0] if nu.ndim > 1 else float(nu[0]))
    return nu


# Each operation of a measurement is written once, for one landmark (floats) and many
# (arrays of K) alike: these pick math's function for a float and numpy's for an array.

Scalars = tuple[float, float] | tuple[FloatArray, FloatArray]


def _components(offset_xy: FloatArray) -> Scalars:
    """(dx, dy): two floats of an offset (2,), two arrays (K,) of many (K, 2)."""
    offset = np.asarray(offset_xy, dtype=np.float64)
    if offset.ndim == 1:
        return float(offset[0]), float(offset[1])
    return offset[:, 0], offset[:, 1]


def _sqrt(value: float | FloatArray) -> float | FloatArray:
    return math.sqrt(value) if isinstance(value, float) else np.sqrt(value)


def _atan2(y: float | FloatArray, x: float | FloatArray) -> float | FloatArray:
    if isinstance(y, float) and isinstance(x, float):
        return math.atan2(y, x)
    return np.arctan2(y, x)


def _wrap(angle: float | FloatArray) -> float | FloatArray:
    return wrap_angle(angle) if isinstance(angle, float) else wrap_angles(angle)


def _assembled(entries: tuple[object, ...]) -> FloatArray:
    """An array from its entries (nested tuples of floats), or the stack (K, ...) of K
    such arrays where the entries are arrays (K,) (a float among them is broadcast)."""
    first: object = entries
    while isinstance(first, tuple):
        first = first[0]
    if isinstance(first, float):  # one landmark: every entry is a float
        return np.array(entries, dtype=np.float64)
    leaves: list[float | FloatArray] = []

    def flatten(item: object) -> tuple[int, ...]:
        if isinstance(item, tuple):
            shapes = [flatten(inner) for inner in item]
            return (len(item), *shapes[0])
        leaves.append(item)  # type: ignore[arg-type]
        return ()

    shape = flatten(entries)
    columns = np.broadcast_arrays(*[np.asarray(leaf, dtype=np.float64) for leaf in leaves])
    return np.stack(columns, axis=-1).reshape(*columns[0].shape, *shape)


def measure(pose_xytheta: FloatArray, landmark_xy: FloatArray) -> FloatArray:
    """h(x) of a landmark from a pose: :func:`expected_measurement` of its offset.

    :return: (bearing, range) (2,), bearing wrapped to (-pi, pi]
    """
    return expected_measurement(landmark_offset(pose_xytheta, landmark_xy), float(pose_xytheta[2]))


def measurement_jacobians(
    pose_xytheta: FloatArray, landmark_xy: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(H_p (2, 3), H_l (2, 2)) of a landmark from a pose, rows (bearing, range)."""
    offset = landmark_offset(pose_xytheta, landmark_xy)
    return measurement_jacobian_pose(offset), measurement_jacobian_landmark(offset)


# -- landmark initialisation -----------------------------------------------------------------


def landmark_from_measurement(pose_xytheta: FloatArray, z: FloatArray) -> FloatArray:
    """The inverse measurement: where a landmark seen at ``z`` = (bearing, range) lies.

    :return: (2,) l = (x + r cos(theta + beta), y + r sin(theta + beta))
    """
    x, y, theta = (float(v) for v in pose_xytheta[:3])
    bearing, rng = float(z[0]), float(z[1])
    phi = theta + bearing
    return np.array([x + rng * math.cos(phi), y + rng * math.sin(phi)])


def init_jacobian_pose(pose_xytheta: FloatArray, z: FloatArray) -> FloatArray:
    """J_p, the Jacobian of :func:`landmark_from_measurement` with respect to the pose.

    :return: (2, 3) [[1, 0, -r sin(theta + beta)], [0, 1, r cos(theta + beta)]]
    """
    phi = float(pose_xytheta[2]) + float(z[0])
    rng = float(z[1])
    return np.array([[1.0, 0.0, -rng * math.sin(phi)], [0.0, 1.0, rng * math.cos(phi)]])


def init_jacobian_measurement(pose_xytheta: FloatArray, z: FloatArray) -> FloatArray:
    """J_z, the Jacobian of :func:`landmark_from_measurement` with respect to (bearing, range).

    :return: (2, 2) [[-r sin(theta + beta), cos(theta + beta)],
        [r cos(theta + beta), sin(theta + beta)]]
    """
    phi = float(pose_xytheta[2]) + float(z[0])
    rng = float(z[1])
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[-rng * s, c], [rng * c, s]])


def landmark_init_jacobians(
    pose_xytheta: FloatArray, z: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(J_p (2, 3), J_z (2, 2)): :func:`init_jacobian_pose` and
    :func:`init_jacobian_measurement`."""
    return init_jacobian_pose(pose_xytheta, z), init_jacobian_measurement(pose_xytheta, z)
