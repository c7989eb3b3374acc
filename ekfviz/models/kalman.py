"""The EKF's algebra on the SLAM state, one named operation each (numpy only).

The state is x = [x, y, theta, l1x, l1y, ...] (3 + 2N) with covariance P; the robot's
rows and columns come first (``r``), the map's after them (``m``). The symbols are those
of the project's reference (`docs/ekf-slam.md`): G, W, Q of a predict; H, R, S, K and the
innovation nu of an update; J_p, J_z of a new landmark. The models that give G, W, H, J_p
and J_z are in :mod:`ekfviz.models.classic` (and the vehicle and sensor models beside it).

Every covariance returned is exactly symmetric (its two triangles the same floats), so
that rounding does not drift P from symmetric event after event.
"""

from __future__ import annotations

import math

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle


def _symmetric(M: FloatArray) -> FloatArray:
    """(M + M^T) / 2, which keeps a symmetric matrix's floats as they are."""
    symmetric: FloatArray = 0.5 * (M + M.T)
    return symmetric


# -- noise -----------------------------------------------------------------------------------


def motion_noise(sigma_x: float, sigma_y: float, sigma_alpha: float) -> FloatArray:
    """Q, the covariance of a control's noise in the robot frame.

    :return: (3, 3) Q = diag(sigma_x^2, sigma_y^2, sigma_alpha^2): variances, m^2 and rad^2
    """
    return np.diag(np.square([sigma_x, sigma_y, sigma_alpha]).astype(np.float64))


def measurement_noise(sigma_bearing: float, sigma_range: float) -> FloatArray:
    """R, the covariance of a measurement's noise, rows (bearing, range).

    :return: (2, 2) R = diag(sigma_bearing^2, sigma_range^2)
    """
    return np.diag(np.square([sigma_bearing, sigma_range]).astype(np.float64))


def prior_covariance(sigmas: tuple[float, ...] | FloatArray) -> FloatArray:
    """The covariance of the start pose from its standard deviations.

    :return: (3, 3) P_0 = diag(sigma^2)
    """
    return np.diag(np.square(np.asarray(sigmas, dtype=np.float64)))


# -- predict ---------------------------------------------------------------------------------


def predicted_pose_covariance(
    P_rr: FloatArray, G: FloatArray, W: FloatArray, Q: FloatArray
) -> FloatArray:
    """The pose block of P after a predict.

    :param P_rr: (3, 3) the pose block before it; G (3, 3), W (3, k), Q (k, k)
    :return: (3, 3) P_rr' = G P_rr G^T + W Q W^T
    """
    return _symmetric(G @ P_rr @ G.T + W @ Q @ W.T)


def predicted_cross_covariance(G: FloatArray, P_rm: FloatArray) -> FloatArray:
    """The pose-map cross-covariance after a predict (only the robot's rows and columns of
    P change: P' = F P F^T with F the identity but for G in its pose block).

    :param P_rm: (3, 2N) the pose rows of P over the map's columns
    :return: (3, 2N) P_rm' = G P_rm
    """
    return G @ P_rm


# -- update ----------------------------------------------------------------------------------


def innovation_covariance(
    H: FloatArray, P: FloatArray, R: FloatArray, *, symmetrised: bool = True
) -> FloatArray:
    """S, the covariance of the innovation.

    :param H: (k, n) the measurement Jacobian over the n entries of P it reads (all of x,
        or only the columns where H is not zero: the pose's and the landmark's)
    :param P: (n, n) P over the same entries; R (k, k)
    :param symmetrised: made exactly symmetric (else as the product leaves it: the S of a
        P some code left asymmetric)
    :return: (k, k) S = H P H^T + R
    """
    S: FloatArray = H @ P @ H.T + R
    return _symmetric(S) if symmetrised else S


def kalman_gain(P_Ht: FloatArray, S: FloatArray) -> FloatArray:
    """K, the gain of an update, by solving with S (never forming S^-1).

    :param P_Ht: (n, k) P H^T; S (k, k)
    :return: (n, k) K = P H^T S^-1
    """
    # (S^-T H P)^T = P H^T S^-1, also for an S some code left asymmetric
    K: FloatArray = np.linalg.solve(S.T, P_Ht.T).T
    return K


def corrected_mean(x: FloatArray, K: FloatArray, nu: FloatArray) -> FloatArray:
    """The mean after an update, its heading wrapped.

    :param x: (n,), K (n, k), nu (k,)
    :return: (n,) x' = x + K nu, theta' = wrap(theta + (K nu)_theta)
    """
    corrected = x + K @ nu
    corrected[2] = wrap_angle(float(corrected[2]))
    return corrected


def corrected_covariance(P: FloatArray, K: FloatArray, S: FloatArray) -> FloatArray:
    """The covariance after an update (with K the gain of that same P, H and S).

    :param P: (n, n), K (n, k), S (k, k)
    :return: (n, n) P' = P - K S K^T (= (I - K H) P for K = P H^T S^-1)
    """
    return _symmetric(P - K @ S @ K.T)


def whitened_correction(
    HP: FloatArray, S: FloatArray, nu: FloatArray
) -> tuple[FloatArray, FloatArray, float] | None:
    """The update in factored form: with S = L L^T (Cholesky), A = L^-1 H P and
    w = L^-1 nu, K nu = A^T w and K S K^T = A^T A, so that the filter adds A^T w to x and
    subtracts A^T A from P (exactly symmetric, a rank-k change) without forming K.

    :param HP: (k, n) H P; S (k, k), nu (k,)
    :return: (A (k, n), A^T w (n,), NIS = w^T w = nu^T S^-1 nu), or None where S is not
        positive definite (NaN included)
    """
    if S.shape == (2, 2):  # one landmark: the 2x2 Cholesky in floats
        s00, s01, s11 = float(S[0, 0]), float(S[0, 1]), float(S[1, 1])
        l00 = math.sqrt(s00) if s00 > 0.0 else 0.0
        l10 = s01 / l00 if l00 > 0.0 else 0.0
        d11 = s11 - l10 * l10
        if not (l00 > 0.0 and d11 > 0.0):  # "not >" also catches NaN
            return None
        l11 = math.sqrt(d11)
        w0 = float(nu[0]) / l00
        w1 = (float(nu[1]) - l10 * w0) / l11
        i00, i11 = 1.0 / l00, 1.0 / l11
        i10 = -l10 * i00 * i11
        # the rows of A and, below them, w^T A: one product with H P
        B: FloatArray = np.array(((i00, 0.0), (i10, i11), (w0 * i00 + w1 * i10, w1 * i11))).dot(HP)
        return B[:2], B[2], w0 * w0 + w1 * w1
    if not np.isfinite(S).all():
        return None
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return None
    A: FloatArray = np.asarray(np.linalg.solve(L, HP), dtype=np.float64)
    w: FloatArray = np.linalg.solve(L, nu)
    return A, w @ A, float(w @ w)


# -- landmark initialisation -----------------------------------------------------------------


def new_landmark_covariance(
    J_p: FloatArray, P_rr: FloatArray, J_z: FloatArray, R: FloatArray
) -> FloatArray:
    """P_ll, a new landmark's covariance: the pose's uncertainty and the measurement's.

    :param J_p: (2, 3), P_rr (3, 3) the pose block, J_z (2, 2), R (2, 2)
    :return: (2, 2) P_ll = J_p P_rr J_p^T + J_z R J_z^T
    """
    return _symmetric(J_p @ P_rr @ J_p.T + J_z @ R @ J_z.T)


def new_landmark_cross_covariance(J_p: FloatArray, P_r: FloatArray) -> FloatArray:
    """P_lx, a new landmark's cross-covariance with the pose and every landmark already in
    the map (it was measured from that uncertain pose).

    :param P_r: (3, n) the pose rows of P
    :return: (2, n) P_lx = J_p P_r
    """
    return J_p @ P_r
