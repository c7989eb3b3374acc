"""Predicted measurements, innovation covariances and individual compatibility.

For landmark i with measurement Jacobian H_i = [H_p (2x3) | H_l (2x2)] over the pose and
its own two rows of the state::

    S_i = H_p P_pp H_p^T + H_p P_pi H_l^T + (H_p P_pi H_l^T)^T + H_l P_ii H_l^T + R

and measurement j is individually compatible with landmark i when its Mahalanobis
distance squared nu^T S_i^-1 nu is below the chi-square quantile of the gate (2 dof).
All landmarks at once, O(N) per scan (and O(m N) for the distances). The associator
takes them through :func:`gate_scan`, which keeps only the candidates (the landmarks in
some gate) and, where ``_search.c`` was built, makes them in one compiled pass over the
map, the numpy functions' floats to the bit.

The same module holds the gate of known landmarks (:func:`gated`), used where the log
gives ids rather than the association choosing them: it rejects an observation whose NIS
is implausible.

Real logs have gross outliers a Gaussian filter cannot absorb: MRCLAM's camera now and
then reads a barcode wrongly and reports a landmark metres from where it is, whose
update turns the heading by a radian. With a gate, each observation of a known landmark
is checked against the state before its line: nu^T S^-1 nu with S = H P H^T + R (2 dof);
beyond the gate it is dropped from the update, with a warning. New landmarks are never
gated (there is nothing to check them against).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.records import Sighting
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.models.angles import wrap_angles
from ekfviz.models.range_bearing import RangeBearing

try:  # optional, built with the filter's kernel: without it the gate runs on numpy
    import ekfviz.association._search as _search
except ImportError:  # pragma: no cover - no C compiler at install time
    _search = None  # type: ignore[assignment]

HAVE_GATE = _search is not None  # is gate_scan's compiled pass here?


def gate_threshold(probability: float) -> float:
    """The chi-square quantile of 2 dof at ``probability``: -2 ln(1 - p), exactly."""
    return -2.0 * math.log1p(-probability)


@dataclass(frozen=True, slots=True)
class Predictions:
    """What the map predicts the sensor sees, for every landmark of the state.

    :param z_pred: (N, 2) predicted (bearing, range)
    :param S: (N, 2, 2) innovation covariances
    :param M: (6, N) the entries of each landmark's measurement Jacobian that are its own:
        H = [[-a0, -a1, a2, a0, a1], [-b0, -b1, b2, b0, b1]] over (x, y, theta, l_x, l_y),
        rows (a0, a1, a2, b0, b1, b2)
    """

    z_pred: FloatArray
    S: FloatArray
    M: FloatArray

    def H(self, rows: IntArray) -> FloatArray:
        """The (k, 2, 5) measurement Jacobians of the landmarks at ``rows``."""
        a0, a1, a2, b0, b1, b2 = self.M[:, rows]
        H = np.empty((len(rows), 2, 5))
        H[:, 0, 0], H[:, 0, 1], H[:, 0, 2], H[:, 0, 3], H[:, 0, 4] = -a0, -a1, a2, a0, a1
        H[:, 1, 0], H[:, 1, 1], H[:, 1, 2], H[:, 1, 3], H[:, 1, 4] = -b0, -b1, b2, b0, b1
        return H


def predict_landmarks(
    x: FloatArray, P: FloatArray, sensor: RangeBearing, R: FloatArray
) -> Predictions:
    """Predicted measurement and innovation covariance of every landmark; O(N).

    :param x: (3+2N,) state mean
    :param P: (3+2N, 3+2N) state covariance
    """
    return predict_landmarks_of(x, P[:3], np.diagonal(P)[3:], np.diagonal(P, 1)[3::2], sensor, R)


def predict_landmarks_of(
    x: FloatArray,
    pose_rows: FloatArray,
    variances: FloatArray,
    covariances: FloatArray,
    sensor: RangeBearing,
    R: FloatArray,
) -> Predictions:
    """Predicted measurement and innovation covariance of every landmark; O(N).

    H_i P_cc H_i^T is taken through the three quantities the measurement depends on,
    v = (l_x - x, l_y - y, theta): H_i = [-M_xy | m_theta | M_xy] with M = [M_xy | m_theta]
    (2x3), so S_i = M cov(v) M^T + R, where cov(v) (3x3) is P_ll - P_lp - P_pl + P_pp over
    x and y, P_l,theta - P_p,theta, and P_theta,theta. Written out per entry on the N
    landmarks at once: a few dozen vector operations, not N small matrix products. M is
    :meth:`RangeBearing.predict_all`'s z_D_landmark and z_D_pose[:, :, 2].

    All it reads of P: the pose's rows and each landmark's 2x2 marginal, which a filter
    may give without the whole P (see :meth:`~ekfviz.filters.ekf.EkfSlam.pose_rows`).

    :param x: (3+2N,) state mean
    :param pose_rows: (3, 3+2N) P's rows of the pose
    :param variances: (2N,) the landmarks' variances, P's diagonal past the pose
    :param covariances: (N,) P[l_x, l_y] of each landmark
    """
    n_landmarks = (x.shape[0] - 3) // 2
    sx, sy, sx_D_theta, sy_D_theta = sensor.sensor(x[:3])
    dx = x[3::2] - sx
    dy = x[4::2] - sy
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    z_pred = np.empty((n_landmarks, 2))
    z_pred[:, 0] = wrap_angles(np.arctan2(dy, dx) - float(x[2]))
    z_pred[:, 1] = r
    M = np.empty((6, n_landmarks))
    a0, a1, a2, b0, b1, b2 = M  # views: filled in place
    np.divide(-dy, q, out=a0)
    np.divide(dx, q, out=a1)
    np.subtract((dy * sx_D_theta - dx * sy_D_theta) / q, 1.0, out=a2)
    np.divide(dx, r, out=b0)
    np.divide(dy, r, out=b1)
    np.divide(-dx * sx_D_theta - dy * sy_D_theta, r, out=b2)
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = pose_rows[:, :3].tolist()
    P_pl = pose_rows[:, 3:]  # rows x, y, theta against the landmarks' columns
    diagonal, off = variances, covariances
    lx_x, ly_x = P_pl[0, 0::2], P_pl[0, 1::2]
    lx_y, ly_y = P_pl[1, 0::2], P_pl[1, 1::2]
    lx_t, ly_t = P_pl[2, 0::2], P_pl[2, 1::2]
    # cov(v), v = (l_x - x, l_y - y, theta)
    c00 = diagonal[0::2] - 2.0 * lx_x + p00
    c11 = diagonal[1::2] - 2.0 * ly_y + p11
    c01 = off - lx_y - ly_x + p01
    c02 = lx_t - p02
    c12 = ly_t - p12
    S = np.empty((n_landmarks, 2, 2))
    # (M C)_r . M_s for rows r, s of M
    ra0 = a0 * c00 + a1 * c01 + a2 * c02
    ra1 = a0 * c01 + a1 * c11 + a2 * c12
    ra2 = a0 * c02 + a1 * c12 + a2 * p22
    rb0 = b0 * c00 + b1 * c01 + b2 * c02
    rb1 = b0 * c01 + b1 * c11 + b2 * c12
    rb2 = b0 * c02 + b1 * c12 + b2 * p22
    S[:, 0, 0] = ra0 * a0 + ra1 * a1 + ra2 * a2 + float(R[0, 0])
    s01 = 0.5 * ((ra0 * b0 + ra1 * b1 + ra2 * b2) + (rb0 * a0 + rb1 * a1 + rb2 * a2))
    S[:, 0, 1] = s01 + 0.5 * (float(R[0, 1]) + float(R[1, 0]))
    S[:, 1, 0] = S[:, 0, 1]
    S[:, 1, 1] = rb0 * b0 + rb1 * b1 + rb2 * b2 + float(R[1, 1])
    return Predictions(z_pred=z_pred, S=S, M=M)


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
    return mahalanobis2_of(nu[:, :, 0], nu[:, :, 1], S)


def innovation_parts(z: FloatArray, z_pred: FloatArray) -> tuple[FloatArray, FloatArray]:
    """:func:`innovations` as its bearing (wrapped) and range parts, (m, N) each: the
    gate needs them apart, and only its candidates need them together."""
    bearing = wrap_angles(z[:, 0, None] - z_pred[None, :, 0])
    rng: FloatArray = z[:, 1, None] - z_pred[None, :, 1]
    return bearing, rng


def mahalanobis2_of(u: FloatArray, v: FloatArray, S: FloatArray) -> FloatArray:
    """:func:`mahalanobis2` of the innovations' bearing parts ``u`` and range parts ``v``
    (m, N) each."""
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    det = a * d - b * b
    ok = (a > 0.0) & (det > 0.0)
    safe = np.where(ok, det, 1.0)
    d2 = (d * u * u - 2.0 * b * u * v + a * v * v) / safe
    return np.where(ok[None, :], d2, np.inf)


def compatible(d2: FloatArray, threshold: float) -> BoolArray:
    """Individual compatibility: the (m, N) distances below the gate."""
    return np.asarray(d2 < threshold)


@dataclass(frozen=True, slots=True)
class ScanGate:
    """The gate of one scan: what the association reads of the map's predictions, for
    the *candidates* alone (the g landmarks in some measurement's gate, in map order).

    :param rows: (g,) the candidates' indices in the map
    :param z_pred: (g, 2) their predicted (bearing, range)
    :param S: (g, 2, 2) their innovation covariances
    :param H: (g, 2, 5) their measurement Jacobians over the pose and their own rows
        (:meth:`Predictions.H`)
    :param d2: (m, g) Mahalanobis distances squared of each measurement to each
    :param nu: (m, g, 2) the innovations (bearing wrapped, range)
    :param compatible: (m, g) ``d2`` below the gate
    :param near: (m,) each measurement's distance to some landmark of the whole map
        below the new-landmark gate
    """

    rows: IntArray
    z_pred: FloatArray
    S: FloatArray
    H: FloatArray
    d2: FloatArray
    nu: FloatArray
    compatible: BoolArray
    near: BoolArray


def marginals_of(P: FloatArray) -> FloatArray:
    """The landmarks' 2x2 marginal covariances (N, 2, 2) of a whole covariance ``P``."""
    n_landmarks = (P.shape[0] - 3) // 2
    diagonal, above = np.diagonal(P)[3:], np.diagonal(P, 1)[3::2]
    covs = np.empty((n_landmarks, 2, 2))
    covs[:, 0, 0], covs[:, 1, 1] = diagonal[0::2], diagonal[1::2]
    covs[:, 0, 1] = covs[:, 1, 0] = above
    return covs


def gate_scan(
    x: FloatArray,
    pose_rows: FloatArray,
    covs: FloatArray,
    sensor: RangeBearing,
    R: FloatArray,
    z: FloatArray,
    gate: float,
    new_gate: float,
    *,
    compiled: bool = True,
) -> ScanGate:
    """:func:`predict_landmarks_of`, :func:`innovation_parts`, :func:`mahalanobis2_of`
    and :func:`compatible` of a scan against the whole map, kept for its candidates.

    Compiled (``_search.c``, where it was built), one pass over the map in doubles,
    operation for operation the numpy functions' (the same floats: only the bearing's
    arctan2 is numpy's own, whose vectorised implementation libm's need not match), with
    nothing of size m x N made; else those functions, as defined.

    :param x: (3+2N,) state mean; :param pose_rows: (3, 3+2N) P's rows of the pose
    :param covs: (N, 2, 2) the landmarks' marginal covariances
    :param z: (m, 2) the scan's (bearing, range)
    :param gate: the individual gate (chi-square, 2 dof); :param new_gate: the gate of
        :attr:`ScanGate.near`
    """
    if _search is None or not compiled:
        return _gate_scan_numpy(x, pose_rows, covs, sensor, R, z, gate, new_gate)
    x = np.ascontiguousarray(x, dtype=np.float64)
    n_landmarks = (x.shape[0] - 3) // 2
    m = z.shape[0]
    sx, sy, sx_D_theta, sy_D_theta = sensor.sensor(x)
    bearing = np.arctan2(x[4::2] - sy, x[3::2] - sx)
    values = np.array(
        (sx, sy, sx_D_theta, sy_D_theta, float(x[2]), float(R[0, 0]),
         0.5 * (float(R[0, 1]) + float(R[1, 0])), float(R[1, 1]), gate, new_gate)
    )  # fmt: skip
    out = np.empty(n_landmarks * (16 + 3 * m))
    rows = np.empty(n_landmarks, dtype=np.int64)
    flags = np.empty(m * (n_landmarks + 1), dtype=bool)
    g = _search.gate(
        x, bearing, np.ascontiguousarray(pose_rows, dtype=np.float64),
        np.ascontiguousarray(covs, dtype=np.float64), np.ascontiguousarray(z, dtype=np.float64),
        values, out, rows, flags,
    )  # fmt: skip
    # out holds z_pred, S, H, d2 and nu of the g candidates one after another
    ends = list(itertools.accumulate((2 * g, 4 * g, 10 * g, m * g, 2 * m * g)))
    return ScanGate(
        rows=rows[:g],
        z_pred=out[: ends[0]].reshape(g, 2),
        S=out[ends[0] : ends[1]].reshape(g, 2, 2),
        H=out[ends[1] : ends[2]].reshape(g, 2, 5),
        d2=out[ends[2] : ends[3]].reshape(m, g),
        nu=out[ends[3] : ends[4]].reshape(m, g, 2),
        compatible=flags[: m * g].reshape(m, g),
        near=flags[m * n_landmarks :],
    )


def _gate_scan_numpy(
    x: FloatArray,
    pose_rows: FloatArray,
    covs: FloatArray,
    sensor: RangeBearing,
    R: FloatArray,
    z: FloatArray,
    gate: float,
    new_gate: float,
) -> ScanGate:
    """:func:`gate_scan` by its definition, with the numpy functions."""
    predictions = predict_landmarks_of(
        x, pose_rows, covs[:, (0, 1), (0, 1)].ravel(), covs[:, 0, 1], sensor, R
    )
    u, v = innovation_parts(z, predictions.z_pred)
    d2 = mahalanobis2_of(u, v, predictions.S)
    ic = compatible(d2, gate)
    rows = np.flatnonzero(ic.any(axis=0))
    return ScanGate(
        rows=rows,
        z_pred=predictions.z_pred[rows],
        S=predictions.S[rows],
        H=predictions.H(rows),
        d2=d2[:, rows],
        nu=np.stack((u[:, rows], v[:, rows]), axis=-1),
        compatible=ic[:, rows],
        near=np.asarray((d2 < new_gate).any(axis=1)),
    )


# --- the gate of known landmarks -----------------------------------------------------
CHI2_2_999 = 13.8155  # 99.9 % quantile of chi-square with 2 degrees of freedom


def gated(
    x: FloatArray,
    P: FloatArray,
    landmark_ids: list[int],
    sighting: Sighting,
    R: FloatArray,
    gate: float,
) -> tuple[Sighting, tuple[str, ...]]:
    """The sighting without its known landmarks whose NIS exceeds ``gate``, and a warning
    for each one dropped.

    :param x: (3+2N,) state mean before the line
    :param P: (3+2N, 3+2N) its covariance
    :param landmark_ids: (N,) ids in state order
    :param R: (2, 2) measurement noise of (bearing, range)
    """
    slot = {landmark_id: 3 + 2 * k for k, landmark_id in enumerate(landmark_ids)}
    rows = [k for k, i in enumerate(sighting.ids.tolist()) if i in slot]
    if not rows:
        return sighting, ()
    nis = landmark_nis(x, P, [slot[int(sighting.ids[k])] for k in rows], sighting.z[rows], R)
    rejected: BoolArray = np.zeros(len(sighting.ids), dtype=bool)
    rejected[rows] = ~(nis <= gate)  # NaN too
    if not rejected.any():
        return sighting, ()
    warnings = tuple(
        f"landmark {int(sighting.ids[k])}: NIS {value:.1f} beyond the gate {gate:g}:"
        " observation rejected as an outlier"
        for k, value in zip(rows, nis.tolist(), strict=True)
        if rejected[k]
    )
    keep = ~rejected
    kept = Sighting(
        line=sighting.line, ids=sighting.ids[keep], z=sighting.z[keep], time=sighting.time
    )
    return kept, warnings


def landmark_nis(
    x: FloatArray, P: FloatArray, slots: list[int], z: FloatArray, R: FloatArray
) -> FloatArray:
    """NIS of each observation against the state, one landmark at a time (2 dof each).

    :param slots: (m,) index in x of each landmark's x coordinate
    :param z: (m, 2) measured (bearing, range)
    :return: (m,) NIS, NaN where the landmark is predicted at the robot
    """
    j = np.asarray(slots, dtype=np.int64)
    dx, dy = x[j] - x[0], x[j + 1] - x[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_pred = np.column_stack([wrap_angles(np.arctan2(dy, dx) - x[2]), r])
        zeros, ones = np.zeros_like(q), np.ones_like(q)
        # H over the columns (x, y, theta, lx, ly), rows (bearing, range)
        H = np.stack(
            [
                np.stack([dy / q, -dx / q, -ones, -dy / q, dx / q], axis=1),
                np.stack([-dx / r, -dy / r, zeros, dx / r, dy / r], axis=1),
            ],
            axis=1,
        )  # (m, 2, 5)
        cols = np.stack([np.zeros_like(j), np.ones_like(j), 2 * np.ones_like(j), j, j + 1], 1)
        P_cc = P[cols[:, :, None], cols[:, None, :]]  # (m, 5, 5)
        S = H @ P_cc @ H.transpose(0, 2, 1) + R
        nu = z - z_pred
        nu[:, 0] = wrap_angles(nu[:, 0])
        nis: FloatArray = np.einsum("ka,ka->k", nu, np.linalg.solve(S, nu[:, :, None])[..., 0])
    return nis
