"""Evaluation of landmark estimates against ground truth.

Euclidean error |l_est - l_true| and Mahalanobis distance sqrt(e^T P_ll^-1 e) per
landmark; "inside its 3-sigma ellipse" means a Mahalanobis distance below 3. A map can
be inside its ellipses because it is right or because the ellipses are huge: the summary
(:class:`MapSummary`) gives the mean 3-sigma semi-major axis beside the errors.

Absolute errors depend on the frame the first pose fixes: a small error of the start
heading turns the whole map about it. The summary also gives the errors after the best
rigid alignment (rotation and translation, no scale) of the estimated map to the true
one, in the least-squares sense (Umeyama, 1991; Horn, 1987; evo's ``-a``): the shape of
the map, whatever frame it ended in.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.records import EventRecord
from ekfviz.core.tables import Cell, Styled, TextTable
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.evaluation.consistency import Consistency
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
    try:
        whitened = np.linalg.solve(landmark_covs, e[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:  # a singular block (a run gone wrong): NaN for it alone
        whitened = np.full_like(e, np.nan)
        for k in range(len(e)):
            with contextlib.suppress(np.linalg.LinAlgError):
                whitened[k] = np.linalg.solve(landmark_covs[k], e[k])
    mahalanobis = np.sqrt(np.einsum("ij,ij->i", e, whitened))
    return euclidean, mahalanobis


def semi_major_3sigma(covs: FloatArray) -> FloatArray:
    """The semi-major axes (N,) of the 3-sigma ellipses of (N, 2, 2) covariances (m)."""
    if len(covs) == 0:
        return np.zeros(0)
    a, b, c = covs[:, 0, 0], covs[:, 0, 1], covs[:, 1, 1]
    # the larger eigenvalue of [[a, b], [b, c]], written out
    largest = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    out: FloatArray = 3.0 * np.sqrt(np.maximum(largest, 0.0))
    return out


def rigid_alignment(source_xy: FloatArray, target_xy: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The rotation R (2, 2) and translation t (2,) minimising sum |R s + t - target|^2.

    Umeyama (1991) without scale: R from the SVD of the cross-covariance of the centred
    point sets (a reflection is refused with the sign of the last singular vector).

    :param source_xy: (N, 2) points to move, N >= 2 for a rotation (else R = I)
    :param target_xy: (N, 2) where they should go
    """
    if len(source_xy) == 0:
        return np.eye(2), np.zeros(2)
    mu_s, mu_t = source_xy.mean(axis=0), target_xy.mean(axis=0)
    if len(source_xy) < 2:
        return np.eye(2), mu_t - mu_s
    H = (target_xy - mu_t).T @ (source_xy - mu_s)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    R: FloatArray = U @ D @ Vt
    t: FloatArray = mu_t - R @ mu_s
    return R, t


@dataclass(frozen=True, slots=True)
class MapSummary:
    """A map against its truth in a few numbers: errors, ellipse size, and the errors
    after the best rigid alignment.

    :param landmarks: landmarks with truth
    :param inside: of them, inside their 3-sigma ellipse
    :param mean_error: mean landmark error (m), in the truth's frame
    :param worst_error: largest landmark error (m)
    :param mean_semi_major: mean semi-major axis of the 3-sigma ellipses (m)
    :param aligned_mean_error: mean landmark error after the rigid alignment (m)
    :param aligned_worst_error: largest one after it (m)
    :param rotation_deg: the alignment's rotation (degrees)
    :param translation: the alignment's translation (m)
    :param pose_error: the final pose's position error (m), None without a true pose
    :param aligned_pose_error: the same after the map's alignment
    """

    landmarks: int
    inside: int
    mean_error: float
    worst_error: float
    mean_semi_major: float
    aligned_mean_error: float
    aligned_worst_error: float
    rotation_deg: float
    translation: float
    pose_error: float | None = None
    aligned_pose_error: float | None = None

    def to_json(self) -> dict[str, object]:
        def value(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "landmarks": self.landmarks,
            "inside_3sigma": self.inside,
            "mean_error": value(self.mean_error),
            "worst_error": value(self.worst_error),
            "mean_semi_major_3sigma": value(self.mean_semi_major),
            "aligned_mean_error": value(self.aligned_mean_error),
            "aligned_worst_error": value(self.aligned_worst_error),
            "alignment_rotation_deg": value(self.rotation_deg),
            "alignment_translation": value(self.translation),
            "final_pose_error": value(self.pose_error),
            "aligned_final_pose_error": value(self.aligned_pose_error),
        }


def summarise_map(
    landmarks_xy: FloatArray,
    landmark_covs: FloatArray,
    truth_xy: FloatArray,
    pose: FloatArray | None = None,
    true_pose: FloatArray | None = None,
) -> MapSummary | None:
    """The summary of a map (see :class:`MapSummary`); None when no landmark has truth.

    :param landmarks_xy: (N, 2) estimates
    :param landmark_covs: (N, 2, 2) their marginal covariances
    :param truth_xy: (N, 2) true positions, NaN rows: no truth (left out)
    :param pose: (3,) the final pose estimate, with ``true_pose`` (3,) its truth
    """
    known = np.isfinite(truth_xy).all(axis=1)
    if not known.any():
        return None
    est, true, covs = landmarks_xy[known], truth_xy[known], landmark_covs[known]
    euclidean, mahalanobis = landmark_errors(est, covs, true)
    R, t = rigid_alignment(est, true)
    aligned = np.hypot(*((est @ R.T + t) - true).T)
    pose_error = aligned_pose_error = None
    if pose is not None and true_pose is not None:
        pose_error = float(np.hypot(*(pose[:2] - true_pose[:2])))
        aligned_pose_error = float(np.hypot(*(R @ pose[:2] + t - true_pose[:2])))
    return MapSummary(
        landmarks=int(known.sum()),
        inside=int(np.count_nonzero(mahalanobis < INSIDE_SIGMA)),
        mean_error=float(euclidean.mean()),
        worst_error=float(euclidean.max()),
        mean_semi_major=float(semi_major_3sigma(covs).mean()),
        aligned_mean_error=float(aligned.mean()),
        aligned_worst_error=float(aligned.max()),
        rotation_deg=math.degrees(math.atan2(R[1, 0], R[0, 0])),
        translation=float(np.hypot(*t)),
        pose_error=pose_error,
        aligned_pose_error=aligned_pose_error,
    )


@dataclass(frozen=True, slots=True)
class LandmarkResult:
    """One landmark's final estimate and, with truth, its errors."""

    id: int
    estimate: FloatArray
    cov: FloatArray
    truth: FloatArray | None = None
    euclidean: float | None = None
    mahalanobis: float | None = None
    aligned: float | None = None  # the error after the map's best rigid alignment

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
    summary: MapSummary | None = None  # the map in a few numbers, with truth

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
                entry["aligned_error"] = result.aligned
                entry["inside_3sigma"] = result.inside_3sigma
            landmarks.append(entry)
        document: dict[str, object] = {
            "final_pose": pose,
            "final_pose_cov": self.pose_cov.tolist(),
            "final_pose_sigma": self.pose_sigma.tolist(),
            "landmarks": landmarks,
        }
        if self.summary is not None:
            document["summary"] = self.summary.to_json()
        if self.consistency is not None:
            document["consistency"] = self.consistency.to_json()
        return document

    def table(self, truth: GroundTruth | None) -> TextTable:
        """The landmarks at the end of the run, with their errors when the truth is known."""
        columns = ["id", "x", "y", "σ x", "σ y"]
        if truth is not None:
            columns += ["error (m)", "aligned (m)", "Mahalanobis", "in 3σ"]
        rows = []
        for r in self.landmarks:
            cells: list[Cell] = [str(r.id), *(f"{v:.4f}" for v in (*r.estimate, *r.sigma))]
            if truth is not None:
                if r.mahalanobis is None or r.euclidean is None:
                    cells += ["-", "-", "-", "no truth"]
                else:
                    verdict = (
                        Styled("yes", "green") if r.inside_3sigma else Styled("no", "bold red")
                    )
                    aligned = "-" if r.aligned is None else f"{r.aligned:.4f}"
                    cells += [f"{r.euclidean:.4f}", aligned, f"{r.mahalanobis:.3f}", verdict]
            rows.append(tuple(cells))
        return TextTable("Landmarks at the end of the run", tuple(columns), tuple(rows))

    def lines(self, truth: GroundTruth | None) -> list[Cell]:
        """The final pose and, with truth, how many landmarks are inside 3 sigma, the map's
        errors and the landmarks never observed; the consistency sentences."""
        x, y, theta = self.pose
        sx, sy, st = self.pose_sigma
        lines: list[Cell] = [
            f"Final pose: x {x:.4f} ± {sx:.4f} m, y {y:.4f} ± {sy:.4f} m, "
            f"theta {theta:.4f} ± {st:.4f} rad (± one sigma)"
        ]
        if truth is not None:
            inside = sum(bool(r.inside_3sigma) for r in self.landmarks)
            lines.append(
                f"{inside} of {len(self.landmarks)} landmarks inside their 3-sigma ellipse"
            )
            if self.summary is not None:  # inside because right, or because huge?
                lines += [Styled(line, wrap=False) for line in summary_lines(self.summary)]
            missing = set(truth.ids.tolist()) - {r.id for r in self.landmarks}
            if missing:
                lines.append(Styled(f"never observed: landmarks {sorted(missing)}", "yellow"))
        if self.consistency is not None:
            lines += self.consistency.summary()
        return lines

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
            header += " error (m) | aligned (m) | Mahalanobis | in 3σ |"
        rows += [header, "|" + "---|" * (header.count("|") - 1)]
        for r in self.landmarks:
            cells = [str(r.id), *(f"{v:.4f}" for v in (*r.estimate, *r.sigma))]
            if self.has_truth:
                if r.euclidean is None or r.mahalanobis is None:
                    cells += ["-", "-", "-", "no truth"]
                else:
                    cells += [
                        f"{r.euclidean:.4f}",
                        "-" if r.aligned is None else f"{r.aligned:.4f}",
                        f"{r.mahalanobis:.3f}",
                        "yes" if r.inside_3sigma else "**no**",
                    ]
            rows.append("| " + " | ".join(cells) + " |")
        if self.summary is not None:
            rows += ["", "## Summary", "", *(f"- {line}" for line in summary_lines(self.summary))]
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
        known = np.isfinite(truth_xy).all(axis=1)
        R, t = rigid_alignment(record.landmarks_xy[known], truth_xy[known])
        aligned = np.hypot(*((record.landmarks_xy @ R.T + t) - truth_xy).T)
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
                aligned=float(aligned[row]) if has else None,
            )
        )
    summary = None
    if truth is not None:
        true_pose = truth.pose_of(record.step, record.time) if truth.has_poses else None
        summary = summarise_map(
            record.landmarks_xy, record.landmark_covs, truth_xy, record.pose, true_pose
        )
    return Evaluation(
        pose=record.pose,
        pose_cov=record.pose_cov,
        landmarks=tuple(results),
        has_truth=truth is not None,
        consistency=consistency,
        summary=summary,
    )


def summary_lines(summary: MapSummary) -> list[str]:
    """The summary in two sentences, for the terminal and the evaluation document."""
    lines = [
        f"Landmark error: mean {summary.mean_error:.3f} m, worst {summary.worst_error:.3f} m"
        f" (truth frame); mean 3σ semi-major axis {summary.mean_semi_major:.3f} m",
        f"After the best rigid alignment to the truth (rotation"
        f" {summary.rotation_deg:+.1f}°, shift {summary.translation:.3f} m): mean"
        f" {summary.aligned_mean_error:.3f} m, worst {summary.aligned_worst_error:.3f} m",
    ]
    if summary.pose_error is not None and summary.aligned_pose_error is not None:
        lines[-1] += (
            f"; final pose {summary.pose_error:.3f} m off ({summary.aligned_pose_error:.3f} m"
            " aligned)"
        )
    return lines
