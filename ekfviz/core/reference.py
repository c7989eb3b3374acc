"""A reference trajectory (GPS) against the estimate: rigid 2-D fit and errors over time.

The reference lives in a frame of its own, so it is fitted to the estimate with the
rotation and translation that minimise the squared distances of matched points
(Kabsch/Umeyama without scale): the estimate is interpolated at the reference's times,
within the time the estimate spans.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray


def fit_rigid(source_xy: FloatArray, target_xy: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rotation R (2x2) and translation t (2,) minimising sum |R s + t - target|^2.

    :param source_xy: (K, 2); :param target_xy: (K, 2), matched row by row
    """
    mu_s, mu_t = source_xy.mean(axis=0), target_xy.mean(axis=0)
    H = (source_xy - mu_s).T @ (target_xy - mu_t)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, float(np.sign(np.linalg.det(Vt.T @ U.T))) or 1.0])
    R = Vt.T @ D @ U.T
    return R, mu_t - R @ mu_s


@dataclass(frozen=True, slots=True)
class ReferenceFit:
    """The reference fitted to the estimate.

    :param times: (K,) the reference's times within the estimate's span
    :param reference_xy: (K, 2) the reference, moved into the estimate's frame
    :param estimate_xy: (K, 2) the estimate interpolated at those times
    :param errors: (K,) their distances
    """

    times: FloatArray
    reference_xy: FloatArray
    estimate_xy: FloatArray
    errors: FloatArray

    @property
    def rmse(self) -> float:
        return math.sqrt(float(np.mean(self.errors**2))) if self.errors.size else math.nan


def fit_reference(
    estimate_t: FloatArray,
    estimate_xy: FloatArray,
    reference_t: FloatArray,
    reference_xy: FloatArray,
) -> ReferenceFit:
    """Fit the reference to the estimate rigidly and measure the distances.

    :param estimate_t: (T,) non-decreasing times of the estimate
    :raises ValueError: fewer than two reference points within the estimate's span
    """
    inside = (reference_t >= estimate_t[0]) & (reference_t <= estimate_t[-1])
    times = reference_t[inside]
    if times.size < 2:
        raise ValueError("fewer than two reference points fall within the estimate's time span")
    at = np.column_stack(
        [
            np.interp(times, estimate_t, estimate_xy[:, 0]),
            np.interp(times, estimate_t, estimate_xy[:, 1]),
        ]
    )
    R, t = fit_rigid(reference_xy[inside], at)
    moved = reference_xy[inside] @ R.T + t
    return ReferenceFit(times, moved, at, np.hypot(*(moved - at).T))
