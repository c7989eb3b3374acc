"""An innovation gate for known landmarks: reject an observation whose NIS is implausible.

Real logs have gross outliers a Gaussian filter cannot absorb: MRCLAM's camera now and
then reads a barcode wrongly and reports a landmark metres from where it is, whose
update turns the heading by a radian. With a gate, each observation of a known landmark
is checked against the state before its line: nu^T S^-1 nu with S = H P H^T + R (2 dof);
beyond the gate it is dropped from the update, with a warning. New landmarks are never
gated (there is nothing to check them against).
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.records import Sighting
from ekfviz.core.types import BoolArray, FloatArray
from ekfviz.models.angles import wrap_angles

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
