"""Outlines of covariance ellipses, as closed polylines ready for ``rr.LineStrips2D``.

Numpy only. Every point of an outline lies at Mahalanobis distance ``n_sigma`` from its
mean: the 3-sigma ellipse of a 2x2 covariance C has semi-axes 3 sqrt(eig(C)) along C's
eigenvectors (see docs/ekf-slam.md, "Evaluation against ground truth").
"""

from __future__ import annotations

import functools

import numpy as np

from ekfviz.core.types import FloatArray

N_SIGMA = 3.0
# 32 points (31 chords) keep an outline within about 0.5 % of its radius of the true ellipse,
# finer than a line's width at any useful zoom; 64 doubled the size of a recording and
# the CPU to encode it for nothing one could see.
N_POINTS = 32
MIN_POINTS = 16
# Above this many points per batch the outlines get coarser, so that a map of thousands
# of landmarks costs a bounded number of points per event (32 points up to 512 ellipses).
POINT_BUDGET = 16384


def outline_points(n_ellipses: int) -> int:
    """How many points per outline keep a batch of ``n_ellipses`` within the budget."""
    return max(MIN_POINTS, min(N_POINTS, POINT_BUDGET // max(n_ellipses, 1)))


@functools.cache
def _unit_circle_map(n_points: int) -> FloatArray:
    """(6, 2 n_points): [A00, A01, A10, A11, mx, my] @ this = the flattened outline
    mean + A [cos t, sin t], so that a whole batch is one matrix product (a tenth of the
    time of the same sums done array by array)."""
    t = np.linspace(0.0, 2.0 * np.pi, n_points)
    cos_t, sin_t = np.cos(t), np.sin(t)
    circle_map: FloatArray = np.zeros((6, 2 * n_points))
    circle_map[0, 0::2] = circle_map[2, 1::2] = cos_t
    circle_map[1, 0::2] = circle_map[3, 1::2] = sin_t
    circle_map[4, 0::2] = circle_map[5, 1::2] = 1.0
    circle_map.flags.writeable = False  # shared by every call
    return circle_map


def ellipse_axes(means_xy: FloatArray, covs: FloatArray, *, n_sigma: float = N_SIGMA) -> FloatArray:
    """The affine maps of the unit circle onto the ``n_sigma`` ellipses of many Gaussians.

    :param means_xy: (K, 2) means
    :param covs: (K, 2, 2) covariances (symmetric PSD; negative eigenvalues from round-off
        are clamped to 0, giving a flat ellipse rather than NaN)
    :return: (K, 6) rows [A00, A01, A10, A11, mx, my]: the ellipse is
        mean + A [cos t, sin t] with A = n_sigma V sqrt(L), C = V L V^T
    """
    means_xy = np.asarray(means_xy, dtype=np.float64).reshape(-1, 2)
    covs = np.asarray(covs, dtype=np.float64).reshape(-1, 2, 2)
    # The eigen-decomposition of [[a, b], [b, c]] in closed form, for all at once (a
    # batched eigh costs ten times as much): the larger eigenvalue (a+c)/2 + r with
    # r = hypot((a-c)/2, b), the smaller as det / larger (no cancellation), the major
    # axis at angle atan2(b, (a-c)/2) / 2.
    a, c = covs[:, 0, 0], covs[:, 1, 1]
    b = 0.5 * (covs[:, 0, 1] + covs[:, 1, 0])
    half_difference = 0.5 * (a - c)
    major = 0.5 * (a + c) + np.hypot(half_difference, b)
    minor = np.divide(a * c - b * b, major, out=np.zeros_like(major), where=major > 0.0)
    major_axis = n_sigma * np.sqrt(np.clip(major, 0.0, None))
    minor_axis = n_sigma * np.sqrt(np.clip(minor, 0.0, None))
    angle = 0.5 * np.arctan2(b, half_difference)
    cos_angle, sin_angle = np.cos(angle), np.sin(angle)
    coefficients: FloatArray = np.column_stack(
        [
            cos_angle * major_axis,
            -sin_angle * minor_axis,
            sin_angle * major_axis,
            cos_angle * minor_axis,
            means_xy,
        ]
    )
    return coefficients


def unit_circle(n_points: int = N_POINTS) -> FloatArray:
    """(n_points, 2) the closed unit circle that ``ellipse_axes`` maps onto an ellipse."""
    t = np.linspace(0.0, 2.0 * np.pi, n_points)
    circle: FloatArray = np.column_stack([np.cos(t), np.sin(t)])
    circle[-1] = circle[0]
    return circle


def ellipse_outlines(
    means_xy: FloatArray,
    covs: FloatArray,
    *,
    n_sigma: float = N_SIGMA,
    n_points: int = N_POINTS,
) -> FloatArray:
    """Closed outlines of the ``n_sigma`` ellipses of many 2-D Gaussians at once.

    :param means_xy: (K, 2) means
    :param covs: (K, 2, 2) covariances (symmetric PSD; negative eigenvalues from round-off
        are clamped to 0, giving a flat ellipse rather than NaN)
    :return: (K, n_points, 2) outlines, first point == last point,
        x = mean + n_sigma V sqrt(L) [cos t, sin t] with C = V L V^T
    """
    if n_points < 3:
        raise ValueError(f"an outline needs at least 3 points, got {n_points}")
    coefficients = ellipse_axes(means_xy, covs, n_sigma=n_sigma)
    outlines: FloatArray = (coefficients @ _unit_circle_map(n_points)).reshape(-1, n_points, 2)
    outlines[:, -1] = outlines[:, 0]  # cos(2 pi) is not exactly 1: close the loop exactly
    return outlines


def ellipse_extent(
    means_xy: FloatArray, covs: FloatArray, *, n_sigma: float = N_SIGMA
) -> FloatArray:
    """The corners of the boxes around many ``n_sigma`` ellipses, to frame a map by.

    :param means_xy: (K, 2) means
    :param covs: (K, 2, 2) covariances
    :return: (2K, 2) every box's lower-left then upper-right corner; the box of an
        ellipse has half-widths n_sigma sqrt(C_xx), n_sigma sqrt(C_yy)
    """
    means_xy = np.asarray(means_xy, dtype=np.float64).reshape(-1, 2)
    covs = np.asarray(covs, dtype=np.float64).reshape(-1, 2, 2)
    half = n_sigma * np.sqrt(np.clip(np.stack([covs[:, 0, 0], covs[:, 1, 1]], axis=1), 0.0, None))
    corners: FloatArray = np.concatenate([means_xy - half, means_xy + half])
    return corners


def ellipse_shapes(means_xy: FloatArray, covs: FloatArray) -> FloatArray:
    """(K, 6) rows [mx, my, 3 sqrt(C) flattened]: a 3-sigma ellipse by its mean and the
    symmetric square root of its covariance (unique, unlike the eigenvectors' signs),
    sqrt(C) = (C + sqrt(det C) I) / sqrt(tr C + 2 sqrt(det C)) for 2x2."""
    root_det = np.sqrt(np.clip(np.linalg.det(covs), 0.0, None))
    scale = np.sqrt(np.clip(np.trace(covs, axis1=1, axis2=2) + 2.0 * root_det, 0.0, None))
    roots = (covs + root_det[:, None, None] * np.eye(2)) / np.where(scale > 0, scale, 1.0)[
        :, None, None
    ]
    return np.column_stack([means_xy, 3.0 * roots.reshape(-1, 4)])


def ellipse_shape_columns(means_xy: FloatArray, covs: FloatArray) -> FloatArray:
    """:func:`ellipse_shapes` transposed, (6, K), to the bit: each quantity a contiguous
    row, so that the map's window search (:mod:`.layers.landmarks`) reads every landmark's
    shape in a few contiguous passes instead of strided slices of (K, 6) rows.

    The same operations in the same order as :func:`ellipse_shapes` (the determinant by
    ``np.linalg.det``, the trace as C00 + C11, C + sqrt(det C) I with the identity's
    zeros added too), one row at a time and written in place.
    """
    means_xy = np.asarray(means_xy, dtype=np.float64).reshape(-1, 2)
    covs = np.asarray(covs, dtype=np.float64).reshape(-1, 2, 2)
    root_det = np.sqrt(np.clip(np.linalg.det(covs), 0.0, None))
    entries = np.ascontiguousarray(covs.reshape(-1, 4).T)  # C00, C01, C10, C11
    scale = np.sqrt(np.clip(entries[0] + entries[3] + 2.0 * root_det, 0.0, None))
    columns: FloatArray = np.empty((6, len(covs)))
    columns[:2] = means_xy.T
    np.add(entries[0], root_det, out=columns[2])
    off_diagonal = root_det * 0.0  # sqrt(det C) times the identity's zeros (NaN stays)
    np.add(entries[1], off_diagonal, out=columns[3])
    np.add(entries[2], off_diagonal, out=columns[4])
    np.add(entries[3], root_det, out=columns[5])
    columns[2:] /= np.where(scale > 0, scale, 1.0)
    columns[2:] *= 3.0
    return columns
