"""Outlines of covariance ellipses, as closed polylines ready for ``rr.LineStrips2D``.

Numpy only. Every point of an outline lies at Mahalanobis distance ``n_sigma`` from its
mean: the 3-sigma ellipse of a 2x2 covariance C has semi-axes 3 sqrt(eig(C)) along C's
eigenvectors (see docs/ekf-slam.md, "Evaluation against ground truth").
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.types import FloatArray

N_SIGMA = 3.0
N_POINTS = 64
MIN_POINTS = 16
# Above this many points per batch the outlines get coarser, so that a map of thousands
# of landmarks costs a bounded number of points per event (64 points up to 256 ellipses).
POINT_BUDGET = 16384


def outline_points(n_ellipses: int) -> int:
    """How many points per outline keep a batch of ``n_ellipses`` within the budget."""
    return max(MIN_POINTS, min(N_POINTS, POINT_BUDGET // max(n_ellipses, 1)))


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
    means_xy = np.asarray(means_xy, dtype=np.float64).reshape(-1, 2)
    covs = np.asarray(covs, dtype=np.float64).reshape(-1, 2, 2)
    eigenvalues, eigenvectors = np.linalg.eigh(covs)
    axes = eigenvectors * (n_sigma * np.sqrt(np.clip(eigenvalues, 0.0, None)))[:, None, :]
    t = np.linspace(0.0, 2.0 * np.pi, n_points)
    circle = np.stack([np.cos(t), np.sin(t)])  # (2, n_points)
    outlines: FloatArray = means_xy[:, None, :] + np.einsum("kij,jn->kni", axes, circle)
    outlines[:, -1] = outlines[:, 0]  # cos(2 pi) is not exactly 1: close the loop exactly
    return outlines
