"""Predicted measurements, innovation covariances and individual compatibility.

For landmark i with measurement Jacobian H_i = [H_p (2x3) | H_l (2x2)] over the pose and
its own two rows of the state::

    S_i = H_p P_pp H_p^T + H_p P_pi H_l^T + (H_p P_pi H_l^T)^T + H_l P_ii H_l^T + R

and measurement j is individually compatible with landmark i when its Mahalanobis
distance squared nu^T S_i^-1 nu is below the chi-square quantile of the gate (2 dof).
All landmarks at once, O(N) per scan (and O(m N) for the distances).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import BoolArray, FloatArray
from ekfviz.models.angles import wrap_angles
from ekfviz.models.range_bearing import RangeBearing


def gate_threshold(probability: float) -> float:
    """The chi-square quantile of 2 dof at ``probability``: -2 ln(1 - p), exactly."""
    return -2.0 * math.log1p(-probability)


@dataclass(frozen=True, slots=True)
class Predictions:
    """What the map predicts the sensor sees, for every landmark of the state.

    :param z_pred: (N, 2) predicted (bearing, range)
    :param S: (N, 2, 2) innovation covariances
    :param H: (N, 2, 5) measurement Jacobians over (x, y, theta, l_x, l_y)
    """

    z_pred: FloatArray
    S: FloatArray
    H: FloatArray


def predict_landmarks(
    x: FloatArray, P: FloatArray, sensor: RangeBearing, R: FloatArray
) -> Predictions:
    """Predicted measurement and innovation covariance of every landmark; O(N).

    :param x: (3+2N,) state mean
    :param P: (3+2N, 3+2N) state covariance
    """
    n_landmarks = (x.shape[0] - 3) // 2
    landmarks_xy = x[3:].reshape(n_landmarks, 2)
    z_pred, H_p, H_l = sensor.predict_all(x[:3], landmarks_xy)
    P_pp = P[:3, :3]
    P_pl = P[:3, 3:].reshape(3, n_landmarks, 2).transpose(1, 0, 2)  # (N, 3, 2)
    idx = 3 + 2 * np.arange(n_landmarks)
    P_ll = np.empty((n_landmarks, 2, 2))
    P_ll[:, 0, 0] = P[idx, idx]
    P_ll[:, 0, 1] = P[idx, idx + 1]
    P_ll[:, 1, 0] = P[idx + 1, idx]
    P_ll[:, 1, 1] = P[idx + 1, idx + 1]
    cross = H_p @ P_pl @ H_l.transpose(0, 2, 1)
    S = (
        H_p @ P_pp @ H_p.transpose(0, 2, 1)
        + cross
        + cross.transpose(0, 2, 1)
        + H_l @ P_ll @ H_l.transpose(0, 2, 1)
        + R
    )
    S = 0.5 * (S + S.transpose(0, 2, 1))
    return Predictions(z_pred=z_pred, S=S, H=np.concatenate([H_p, H_l], axis=2))


def innovations(z: FloatArray, z_pred: FloatArray) -> FloatArray:
    """nu of every measurement against every landmark, bearing wrapped.

    :param z: (m, 2) measured; :param z_pred: (N, 2) predicted
    :return: (m, N, 2)
    """
    nu = z[:, None, :] - z_pred[None, :, :]
    nu[:, :, 0] = wrap_angles(nu[:, :, 0])
    return nu


def mahalanobis2(nu: FloatArray, S: FloatArray) -> FloatArray:
    """nu^T S^-1 nu of every (measurement, landmark) pair, with the 2x2 inverse written out.

    :param nu: (m, N, 2); :param S: (N, 2, 2)
    :return: (m, N); +inf where S is not positive definite
    """
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    det = a * d - b * b
    ok = (a > 0.0) & (det > 0.0)
    safe = np.where(ok, det, 1.0)
    u, v = nu[:, :, 0], nu[:, :, 1]
    d2 = (d * u * u - 2.0 * b * u * v + a * v * v) / safe
    return np.where(ok[None, :], d2, np.inf)


def compatible(d2: FloatArray, threshold: float) -> BoolArray:
    """Individual compatibility: the (m, N) distances below the gate."""
    return np.asarray(d2 < threshold)
