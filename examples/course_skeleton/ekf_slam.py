"""A course-style EKF-SLAM in functions, the shape many courses hand out, filled in correctly.

The state is a column vector X = [x, y, theta, l1x, l1y, ...]^T (3 + 2k, 1) and P its
covariance; k landmarks, all seen on the first line of a classic log. Controls are
(d, alpha): drive d along the heading, then turn alpha; the motion noise
control_cov = diag(sigma_x^2, sigma_y^2, sigma_alpha^2) is in the robot frame. A
measurement is (bearing, range) per landmark, stacked into a (2k, 1) column, with
measure_cov = diag(sigma_bearing^2, sigma_range^2).

ekfviz runs a module of these functions as it is, in a worker process of its own::

    ekfviz check --filter examples/course_skeleton/ekf_slam.py

compares them with the reference event by event. ``init_cross_covariance`` is this
module's own addition to the handout: where a module has it, ekfviz puts the new
landmarks' cross-covariance with the pose into P (the handout's ``main()`` builds
P = block_diag(pose_cov, landmark_cov) and so drops it).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def warp2pi(angle: float) -> float:
    """The angle wrapped to [-pi, pi)."""
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def init_landmarks(
    init_measure: Array, init_measure_cov: Array, init_pose: Array, init_pose_cov: Array
) -> tuple[int, Array, Array]:
    """Landmarks from the first observation.

    :param init_measure: (2k, 1) bearing, range of each landmark
    :return: k, the landmarks (2k, 1) and their covariance (2k, 2k): J_p P_pp J_p^T +
        J_z R J_z^T per landmark and J_p_i P_pp J_p_j^T between two landmarks (they were
        measured from the same uncertain pose)
    """
    k = init_measure.shape[0] // 2
    x, y, theta = init_pose.reshape(3)
    landmark = np.zeros((2 * k, 1))
    jacobians = []
    for i in range(k):
        bearing, rng = init_measure[2 * i : 2 * i + 2, 0]
        phi = theta + bearing
        landmark[2 * i : 2 * i + 2, 0] = [x + rng * np.cos(phi), y + rng * np.sin(phi)]
        jacobians.append(np.array([[1, 0, -rng * np.sin(phi)], [0, 1, rng * np.cos(phi)]]))
    landmark_cov = np.zeros((2 * k, 2 * k))
    for i in range(k):
        bearing, rng = init_measure[2 * i : 2 * i + 2, 0]
        phi = theta + bearing
        J_z = np.array([[-rng * np.sin(phi), np.cos(phi)], [rng * np.cos(phi), np.sin(phi)]])
        for j in range(k):
            block = jacobians[i] @ init_pose_cov @ jacobians[j].T
            if i == j:
                block = block + J_z @ init_measure_cov @ J_z.T
            landmark_cov[2 * i : 2 * i + 2, 2 * j : 2 * j + 2] = block
    return k, landmark, landmark_cov


def init_cross_covariance(init_measure: Array, init_pose: Array, init_pose_cov: Array) -> Array:
    """The landmarks' cross-covariance with the pose they were measured from (2k, 3).

    Many skeletons build P = block_diag(pose_cov, landmark_cov) and so drop it: the
    landmarks then look independent of the pose, which they are not.
    """
    k = init_measure.shape[0] // 2
    theta = float(init_pose.reshape(3)[2])
    cross = np.zeros((2 * k, 3))
    for i in range(k):
        bearing, rng = init_measure[2 * i : 2 * i + 2, 0]
        phi = theta + bearing
        J_p = np.array([[1, 0, -rng * np.sin(phi)], [0, 1, rng * np.cos(phi)]])
        cross[2 * i : 2 * i + 2] = J_p @ init_pose_cov
    return cross


def predict(X: Array, P: Array, control: Array, control_cov: Array, k: int) -> tuple[Array, Array]:
    """Drive d, turn alpha; only the robot rows and columns of P change.

    :param control: (2, 1) d, alpha, a column as the handout passes it
    :return: the predicted X (3 + 2k, 1) and P
    """
    d, alpha = control[0, 0], control[1, 0]
    theta = float(X[2, 0])
    X = X.copy()
    X[0, 0] += d * np.cos(theta)
    X[1, 0] += d * np.sin(theta)
    X[2, 0] = warp2pi(theta + alpha)
    G = np.eye(3 + 2 * k)
    G[0, 2] = -d * np.sin(theta)
    G[1, 2] = d * np.cos(theta)
    W = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    P = G @ P @ G.T
    P[:3, :3] += W @ control_cov @ W.T  # the noise is in the robot frame: rotate it
    return X, P


def update(
    X_pre: Array, P_pre: Array, measure: Array, measure_cov: Array, k: int
) -> tuple[Array, Array]:
    """Fold in every landmark's (bearing, range), one after another.

    :param measure: (2k, 1) bearing, range of each landmark, in landmark order
    :return: the corrected X and P
    """
    X, P = X_pre.copy(), P_pre.copy()
    n = 3 + 2 * k
    for i in range(k):
        j = 3 + 2 * i
        dx, dy = X[j, 0] - X[0, 0], X[j + 1, 0] - X[1, 0]
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        H = np.zeros((2, n))
        H[:, :3] = [[dy / q, -dx / q, -1], [-dx / r, -dy / r, 0]]
        H[:, j : j + 2] = [[-dy / q, dx / q], [dx / r, dy / r]]
        S = H @ P @ H.T + measure_cov
        K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 without forming the inverse
        innovation = measure[2 * i : 2 * i + 2, 0] - [np.arctan2(dy, dx) - X[2, 0], r]
        innovation[0] = warp2pi(innovation[0])  # a bearing difference lives on the circle
        X = X + (K @ innovation).reshape(-1, 1)
        X[2, 0] = warp2pi(X[2, 0])
        P = P - K @ S @ K.T
        P = 0.5 * (P + P.T)
    return X, P
