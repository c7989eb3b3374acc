"""Numerical health of the filter, read off each record in O(N).

A covariance that loses its symmetry or its positive semi-definiteness, or a state that
turns non-finite, makes every later picture a lie. The filter keeps P exactly symmetric
(see ``EkfSlam._correct``) and stops at the first non-finite value; what is left to
watch is how close the covariance comes to losing definiteness: the smallest eigenvalue
of the pose block and of every landmark's 2x2 block.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ekfviz.core.records import EventRecord

# An eigenvalue below -TOLERANCE times the block's largest one is a loss of
# definiteness, not round-off.
TOLERANCE = 1e-9


@dataclass(frozen=True, slots=True)
class Health:
    """Health figures of one record.

    :param pose_min_eigenvalue: smallest eigenvalue of the 3x3 pose covariance
    :param landmark_min_eigenvalue: smallest eigenvalue over all 2x2 landmark blocks
        (NaN without landmarks)
    :param pose_asymmetry: largest |P - P^T| in the pose block
    """

    pose_min_eigenvalue: float
    landmark_min_eigenvalue: float
    pose_asymmetry: float

    def problems(self) -> list[str]:
        """What is wrong, one phrase each; empty when all is well."""
        found = []
        if self.pose_asymmetry > 0.0:
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


def health(record: EventRecord) -> Health:
    """The health figures of a record; eigenvalues within round-off of 0 count as 0."""
    pose_cov = record.pose_cov
    eigenvalues = np.linalg.eigvalsh(0.5 * (pose_cov + pose_cov.T))
    pose_min = float(eigenvalues[0])
    if pose_min < 0.0 and -pose_min <= TOLERANCE * max(float(eigenvalues[-1]), 0.0):
        pose_min = 0.0
    landmark_min = float("nan")
    if record.n_landmarks:
        covs = record.landmark_covs
        a, b, d = covs[:, 0, 0], 0.5 * (covs[:, 0, 1] + covs[:, 1, 0]), covs[:, 1, 1]
        half_trace, root = 0.5 * (a + d), np.sqrt((0.5 * (a - d)) ** 2 + b * b)
        smallest, largest = half_trace - root, half_trace + root  # closed form for 2x2
        smallest = np.where(
            (smallest < 0.0) & (-smallest <= TOLERANCE * np.maximum(largest, 0.0)), 0.0, smallest
        )
        landmark_min = float(smallest.min())
    return Health(
        pose_min_eigenvalue=pose_min,
        landmark_min_eigenvalue=landmark_min,
        pose_asymmetry=float(np.abs(pose_cov - pose_cov.T).max()),
    )
