"""Evaluation of landmark estimates against ground truth.

Euclidean error |l_est - l_true| and Mahalanobis distance sqrt(e^T P_ll^-1 e) per
landmark; "inside its 3-sigma ellipse" means a Mahalanobis distance below 3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ekfviz.core.consistency import Consistency
from ekfviz.core.records import EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle

INSIDE_SIGMA = 3.0


def landmark_errors(
    landmarks_xy: FloatArray, landmark_covs: FloatArray, truth_xy: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Euclidean and Mahalanobis distance of every estimate to its true position.

    :param landmarks_xy: (N, 2) estimates
    :param landmark_covs: (N, 2, 2) their marginal covariances
    :param truth_xy: (N, 2) true positions, NaN rows give NaN distances
    :return: (euclidean (N,), mahalanobis (N,))
    """
    e = landmarks_xy - truth_xy
    euclidean = np.hypot(e[:, 0], e[:, 1])
    if len(e) == 0:
        return euclidean, euclidean.copy()
    # solve, not inv: e^T C^-1 e for every 2x2 block at once
    whitened = np.linalg.solve(landmark_covs, e[:, :, None])[:, :, 0]
    mahalanobis = np.sqrt(np.einsum("ij,ij->i", e, whitened))
    return euclidean, mahalanobis


@dataclass(frozen=True, slots=True)
class LandmarkResult:
    """One landmark's final estimate and, with truth, its errors."""

    id: int
    estimate: FloatArray
    cov: FloatArray
    truth: FloatArray | None = None
    euclidean: float | None = None
    mahalanobis: float | None = None

    @property
    def sigma(self) -> FloatArray:
        """Standard deviations (2,) of x and y."""
        return np.sqrt(np.diag(self.cov))

    @property
    def inside_3sigma(self) -> bool | None:
        return None if self.mahalanobis is None else bool(self.mahalanobis < INSIDE_SIGMA)


@dataclass(frozen=True, slots=True)
class Evaluation:
    """The final state of a run, judged against ground truth where it is known."""

    pose: FloatArray
    pose_cov: FloatArray
    landmarks: tuple[LandmarkResult, ...]
    has_truth: bool
    consistency: Consistency | None = None  # NEES and NIS counts over the whole run

    @property
    def pose_sigma(self) -> FloatArray:
        return np.sqrt(np.diag(self.pose_cov))

    def to_json(self) -> dict[str, object]:
        """The evaluation as plain JSON values (theta wrapped to (-pi, pi])."""
        pose = [float(self.pose[0]), float(self.pose[1]), wrap_angle(float(self.pose[2]))]
        landmarks: list[dict[str, object]] = []
        for result in self.landmarks:
            entry: dict[str, object] = {
                "id": result.id,
                "estimate": result.estimate.tolist(),
                "cov": result.cov.tolist(),
                "sigma": result.sigma.tolist(),
            }
            if result.truth is not None:
                entry["truth"] = result.truth.tolist()
                entry["euclidean"] = result.euclidean
                entry["mahalanobis"] = result.mahalanobis
                entry["inside_3sigma"] = result.inside_3sigma
            landmarks.append(entry)
        document: dict[str, object] = {
            "final_pose": pose,
            "final_pose_cov": self.pose_cov.tolist(),
            "final_pose_sigma": self.pose_sigma.tolist(),
            "landmarks": landmarks,
        }
        if self.consistency is not None:
            document["consistency"] = self.consistency.to_json()
        return document

    def to_markdown(self) -> str:
        """The evaluation as a markdown table, for a recording's document."""
        x, y, theta = self.pose
        sx, sy, st = self.pose_sigma
        rows = [
            "## Final pose",
            "",
            "| x | y | theta | σ x | σ y | σ theta |",
            "|---|---|---|---|---|---|",
            f"| {x:.4f} | {y:.4f} | {theta:.4f} | {sx:.4f} | {sy:.4f} | {st:.4f} |",
            "",
            "## Landmarks",
            "",
        ]
        header = "| id | x | y | σ x | σ y |"
        if self.has_truth:
            header += " error (m) | Mahalanobis | in 3σ |"
        rows += [header, "|" + "---|" * (header.count("|") - 1)]
        for r in self.landmarks:
            cells = [str(r.id), *(f"{v:.4f}" for v in (*r.estimate, *r.sigma))]
            if self.has_truth:
                if r.euclidean is None or r.mahalanobis is None:
                    cells += ["-", "-", "no truth"]
                else:
                    cells += [
                        f"{r.euclidean:.4f}",
                        f"{r.mahalanobis:.3f}",
                        "yes" if r.inside_3sigma else "**no**",
                    ]
            rows.append("| " + " | ".join(cells) + " |")
        if self.consistency is not None and self.consistency.summary():
            rows += [
                "",
                "## Consistency",
                "",
                *(f"- {line}" for line in self.consistency.summary()),
            ]
        return "\n".join(rows) + "\n"


def evaluate(
    record: EventRecord,
    truth: GroundTruth | None = None,
    consistency: Consistency | None = None,
) -> Evaluation:
    """Judge a record (usually the last of a run) against the truth, if given.

    :param consistency: the NEES and NIS counts gathered over the run, to report with it
    """
    results: list[LandmarkResult] = []
    if truth is not None:
        truth_xy = truth.lookup(record.landmark_ids)
        euclidean, mahalanobis = landmark_errors(
            record.landmarks_xy, record.landmark_covs, truth_xy
        )
    for row, landmark_id in enumerate(record.landmark_ids):
        has = truth is not None and bool(np.isfinite(truth_xy[row]).all())
        results.append(
            LandmarkResult(
                id=int(landmark_id),
                estimate=record.landmarks_xy[row],
                cov=record.landmark_covs[row],
                truth=truth_xy[row] if has else None,
                euclidean=float(euclidean[row]) if has else None,
                mahalanobis=float(mahalanobis[row]) if has else None,
            )
        )
    return Evaluation(
        pose=record.pose,
        pose_cov=record.pose_cov,
        landmarks=tuple(results),
        has_truth=truth is not None,
        consistency=consistency,
    )
