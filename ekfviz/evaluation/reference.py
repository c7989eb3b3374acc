"""A reference trajectory (GPS) against the estimate: rigid 2-D fit and errors over time.

The reference lives in a frame of its own, so it is fitted to the estimate with the
rotation and translation that minimise the squared distances of matched points
(Kabsch/Umeyama without scale): the estimate is interpolated at the reference's times,
within the time the estimate spans.

A receiver sometimes reports a fix far off its track for a moment (Victoria Park has one
137 m away): :func:`jumps` finds the fixes more than ``JUMP_M`` off the line between
their neighbours, which the fit reports beside the plain RMSE (it counts them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import BoolArray, FloatArray

JUMP_M = 50.0  # a fix this far off the line between its neighbours is a jump


def jumps(times: FloatArray, xy: FloatArray, limit: float = JUMP_M) -> BoolArray:
    """(K,) which fixes lie more than ``limit`` metres off the line between the fixes
    before and after them (at their time), the worst first: once a jump is set aside,
    its neighbours are judged against the fixes beyond it. The first and the last fix
    are never jumps."""
    found = np.zeros(len(times), dtype=bool)
    while True:
        kept = np.flatnonzero(~found)
        if len(kept) < 3:
            return found
        t, p = times[kept], xy[kept]
        span = np.maximum(t[2:] - t[:-2], 1e-9)
        w = ((t[1:-1] - t[:-2]) / span)[:, None]
        off = np.hypot(*(p[1:-1] - (p[:-2] + w * (p[2:] - p[:-2]))).T)
        worst = int(np.argmax(off))
        if off[worst] <= limit:
            return found
        found[kept[worst + 1]] = True


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
    jumps: BoolArray  # (K,) fixes off their neighbours' line by over JUMP_M (see jumps)
    rmse_without_jumps: float  # of a fit of the other fixes alone

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
    jumped = jumps(times, moved)
    kept = ~jumped
    without = math.nan
    if kept.sum() >= 2:
        R_kept, t_kept = fit_rigid(reference_xy[inside][kept], at[kept])
        off = reference_xy[inside][kept] @ R_kept.T + t_kept - at[kept]
        without = math.sqrt(float(np.mean(np.sum(off**2, axis=1))))
    return ReferenceFit(times, moved, at, np.hypot(*(moved - at).T), jumped, without)
