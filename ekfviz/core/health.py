"""Numerical health of the filter: is the covariance still a covariance?

A covariance that loses its symmetry or its positive semi-definiteness, or a state that
turns non-finite, makes every later picture a lie. The filter keeps P exactly symmetric
by construction (see ``EkfSlam._update_sequential``), stops at the first non-finite value,
and skips, with a warning, an observation it cannot use (a landmark predicted at zero
range, an innovation covariance that is not positive definite). What is left to watch:

- cheaply, at every record: the smallest eigenvalue of the pose block and of every
  landmark's 2x2 block (:func:`health`, :func:`pose_min_eigenvalues`,
  :func:`landmark_min_eigenvalues`);
- at a cadence that keeps its O(n^3) cost small against the filter's
  (:func:`check_interval`): the symmetry, finiteness and smallest eigenvalue of the
  whole P (:func:`check_covariance`).

An eigenvalue below zero by less than ``TOLERANCE`` times the largest one of its
matrix is round-off, reported as 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ekfviz.core.types import FloatArray

TOLERANCE = 1e-9
# |P - P^T| up to this share of P's largest |eigenvalue| is the round-off of a plain
# filter (a dense P = F P F^T + Q is symmetric to about 1e-16 of its size): not a problem.
ASYMMETRY_TOLERANCE = 1e-9

# The whole P is checked every CHECK_EVERY_STEPS steps while it is small, and more rarely
# as it grows: an eigen-decomposition costs about n^3 and a step about m n^2.
CHECK_EVERY_STEPS = 50
CHECK_SCALE_DIM = 400  # beyond this dimension the interval grows in proportion

NOT_FINITE = "the covariance P holds NaN or infinity"  # what a check says of such a P


def check_interval(dim: int) -> int:
    """Steps between two checks of the whole covariance of dimension ``dim``."""
    return CHECK_EVERY_STEPS * max(1, dim // CHECK_SCALE_DIM)


def _clip_round_off(
    smallest: npt.NDArray[np.floating], largest: npt.NDArray[np.floating]
) -> FloatArray:
    """Negative eigenvalues within round-off of zero, as zero."""
    clipped: FloatArray = np.where(
        (smallest < 0.0) & (-smallest <= TOLERANCE * np.maximum(largest, 0.0)), 0.0, smallest
    )
    return clipped


def pose_min_eigenvalues(pose_covs: FloatArray) -> FloatArray:
    """Smallest eigenvalue of each (k, 3, 3) pose covariance, round-off clipped."""
    if len(pose_covs) == 0:
        return np.zeros(0)
    symmetric = 0.5 * (pose_covs + np.swapaxes(pose_covs, 1, 2))
    eigenvalues = np.linalg.eigvalsh(symmetric)
    return _clip_round_off(eigenvalues[:, 0], eigenvalues[:, -1])


def landmark_min_eigenvalues(covs: FloatArray) -> FloatArray:
    """Smallest eigenvalue of each (N, 2, 2) landmark covariance (closed form), clipped."""
    a, b, d = covs[:, 0, 0], 0.5 * (covs[:, 0, 1] + covs[:, 1, 0]), covs[:, 1, 1]
    half_trace, root = 0.5 * (a + d), np.sqrt((0.5 * (a - d)) ** 2 + b * b)
    return _clip_round_off(half_trace - root, half_trace + root)


@dataclass(frozen=True, slots=True)
class Health:
    """Health figures of one record, from its pose and landmark blocks.

    :param pose_min_eigenvalue: smallest eigenvalue of the 3x3 pose covariance
    :param landmark_min_eigenvalue: smallest eigenvalue over all 2x2 landmark blocks
        (NaN without landmarks)
    :param pose_asymmetry: largest |P - P^T| in the pose block
    """

    pose_min_eigenvalue: float
    landmark_min_eigenvalue: float
    pose_asymmetry: float
    pose_scale: float = 0.0  # the largest |entry| of the pose block, for the asymmetry

    def problems(self) -> list[str]:
        """What is wrong, one phrase each; empty when all is well."""
        found = []
        if self.pose_asymmetry > ASYMMETRY_TOLERANCE * self.pose_scale:
            found.append(f"the pose covariance is not symmetric ({self.pose_asymmetry:.3g})")
        if self.pose_min_eigenvalue < 0.0:
            found.append(
                f"the pose covariance has a negative eigenvalue ({self.pose_min_eigenvalue:.3g})"
            )
        if self.landmark_min_eigenvalue < 0.0:
            found.append(
                "a landmark covariance has a negative eigenvalue"
                f" ({self.landmark_min_eigenvalue:.3g})"
            )
        return found


def health(pose_cov: FloatArray, landmark_covs: FloatArray) -> Health:
    """The health figures of a record's (3, 3) pose and (N, 2, 2) landmark covariances;
    eigenvalues within round-off of 0 count as 0."""
    landmark_min = float("nan")
    if len(landmark_covs):
        landmark_min = float(landmark_min_eigenvalues(landmark_covs).min())
    return Health(
        pose_min_eigenvalue=float(pose_min_eigenvalues(pose_cov[None])[0]),
        landmark_min_eigenvalue=landmark_min,
        pose_asymmetry=float(np.abs(pose_cov - pose_cov.T).max()),
        pose_scale=float(np.abs(pose_cov).max()),
    )


@dataclass(frozen=True, slots=True)
class CovarianceCheck:
    """A check of the whole state covariance P.

    :param dim: its dimension 3 + 2N
    :param min_eigenvalue: its smallest eigenvalue (of its symmetric part), round-off
        clipped; NaN when P is not finite
    :param max_eigenvalue: its largest eigenvalue, for scale
    :param asymmetry: the largest |P - P^T|; 0 whenever the filter works as designed
    :param finite: whether every entry is finite
    """

    dim: int
    min_eigenvalue: float
    max_eigenvalue: float
    asymmetry: float
    finite: bool

    @property
    def condition(self) -> float:
        """max / min eigenvalue: how close P is to singular (inf once it is)."""
        if not self.min_eigenvalue > 0.0:
            return float("inf")
        return self.max_eigenvalue / self.min_eigenvalue

    @property
    def relative_asymmetry(self) -> float:
        """|P - P^T| against the size of P (its largest |eigenvalue|)."""
        scale = max(abs(self.max_eigenvalue), abs(self.min_eigenvalue))
        if self.asymmetry == 0.0:
            return 0.0
        return self.asymmetry / scale if scale > 0.0 else float("inf")

    @property
    def round_off_asymmetry(self) -> bool:
        """Whether P is not exactly symmetric, but only by round-off for its size."""
        return 0.0 < self.relative_asymmetry <= ASYMMETRY_TOLERANCE

    def problems(self, *, round_off: bool = False) -> list[str]:
        """What is wrong, one phrase each; empty when all is well.

        :param round_off: also name an asymmetry within round-off of P's size (a plain
            filter's; say it once a run, not at every event)
        """
        if not self.finite:
            return [NOT_FINITE]
        found = []
        if self.relative_asymmetry > ASYMMETRY_TOLERANCE:
            found.append(
                f"the covariance P is not symmetric (|P - P^T| up to {self.asymmetry:.3g},"
                f" {self.relative_asymmetry:.2g} of its largest eigenvalue)"
            )
        elif round_off and self.round_off_asymmetry:
            found.append(
                f"the covariance P is symmetric only up to round-off (|P - P^T| up to"
                f" {self.asymmetry:.3g}, {self.relative_asymmetry:.2g} of its largest"
                " eigenvalue): harmless, said once"
            )
        if self.min_eigenvalue < 0.0:
            found.append(
                "the covariance P is not positive semi-definite"
                f" (smallest eigenvalue {self.min_eigenvalue:.3g})"
            )
        return found


def check_covariance(P: FloatArray) -> CovarianceCheck:
    """Symmetry, finiteness and extreme eigenvalues of a covariance; O(n^3)."""
    dim = int(P.shape[0])
    if not np.isfinite(P).all():
        nan = float("nan")
        return CovarianceCheck(dim, nan, nan, nan, finite=False)
    # exactly symmetric by construction as a rule: one comparison, the difference only if not
    asymmetry = 0.0 if not dim or np.array_equal(P, P.T) else float(np.abs(P - P.T).max())
    eigenvalues = np.linalg.eigvalsh(0.5 * (P + P.T)) if asymmetry else np.linalg.eigvalsh(P)
    smallest, largest = float(eigenvalues[0]), float(eigenvalues[-1])
    smallest = float(_clip_round_off(np.array(smallest), np.array(largest)))
    return CovarianceCheck(dim, smallest, largest, asymmetry, finite=True)
