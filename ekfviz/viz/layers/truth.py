"""What needs the truth: the true landmarks and path (``world/truth/...``), the pose's
NEES, and each landmark's Euclidean error and Mahalanobis distance with their summary."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from ekfviz.core.records import EventKind, EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.evaluation.consistency import chi2_bounds, pose_nees
from ekfviz.evaluation.errors import landmark_errors
from ekfviz.viz import style
from ekfviz.viz.layers.arrow import in_parent_frame, positions, radius, robot_frame
from ekfviz.viz.layers.batch import Batch, landmark_rows
from ekfviz.viz.layers.canvas import Canvas, has_class_ids
from ekfviz.viz.layers.metrics import MetricsLayer


class TruthLayer:
    """The truth and the series measured against it."""

    def __init__(self, canvas: Canvas, metrics: MetricsLayer) -> None:
        self._canvas = canvas
        self._metrics = metrics
        self._last_true_xy: FloatArray | None = None  # (1, 2) the true path's last point
        self._last_true_step = 0  # the step of the last true pose logged

    def log_styling(self) -> None:
        """The styling of the plots of errors (with truth) and of the true landmarks."""
        entities = self._canvas.entities
        if self._canvas.truth is not None:
            for root in (style.LANDMARK_ERROR_SUMMARY, style.MAHALANOBIS_SUMMARY):
                for which, color in style.SUMMARY_COLORS.items():
                    entities.style(
                        f"{root}/{which}",
                        rr.SeriesLines(colors=color, names=f"{which} landmark", widths=2.0),
                    )

    def log_truth_styling(self) -> None:
        """The true landmarks' styling, sent static at the end if no truth comes."""
        self._canvas.entities.style(
            style.TRUTH_LANDMARKS,
            rr.Points2D.from_fields(
                colors=style.TRUTH_COLOR,
                radii=radius(style.TRUTH_RADIUS_UI),
                show_labels=False,
                draw_order=35.0,
            ),
        )

    def log_truth(self, truth: GroundTruth) -> None:
        """The true landmarks (static), and the styling of the true robot and path."""
        entities = self._canvas.entities
        if truth.has_poses:  # the true robot (a grey point) and path
            entities.style(
                style.TRUTH_ROBOT,
                rr.Points2D.from_fields(
                    colors=style.TRUTH_PATH_COLOR,
                    radii=radius(style.TRUTH_RADIUS_UI),
                    draw_order=36.0,
                ),
                in_parent_frame(entities.path(style.TRUTH_ROBOT)),  # see arrow.robot_frame
            )
            entities.style(
                style.TRUTH_TRAJECTORY,
                rr.LineStrips2D.from_fields(
                    colors=style.TRUTH_PATH_COLOR,
                    radii=radius(style.THIN_LINE_RADIUS_UI),
                    draw_order=5.0,
                ),
            )
        class_ids = truth.ids if has_class_ids(truth.ids) else None
        entities.log(  # with its styling: one static chunk
            style.TRUTH_LANDMARKS, rr.Points2D(truth.landmarks_xy, class_ids=class_ids), static=True
        )

    def send(self, batch: Batch) -> None:
        """The true pose of each step at its update (by step, or by time on a track), as
        a robot frame and a segment of the true path from the step before."""
        truth = self._canvas.truth
        if truth is None or not truth.has_poses:
            return
        records, rows = batch.records, batch.rows
        known = [
            (k, pose)
            for k in batch.corrected.tolist()
            if (pose := truth.pose_of(records[k].step, records[k].time)) is not None
        ]
        if not known:
            return
        at = np.array([k for k, _ in known])
        poses = np.array([pose for _, pose in known])
        self._canvas.send(style.TRUTH_ROBOT, rows.pick(at), [positions(poses), *robot_frame(poses)])
        starts = np.vstack([poses[:1, :2] if self._last_true_xy is None else self._last_true_xy,
                            poses[:-1, :2]])  # fmt: skip
        segments = np.stack([starts, poses[:, :2]], axis=1)
        # an offline filter's final record spans the run: the true path of every step
        # between, beside its whole estimated path (see RobotLayer)
        spans = {
            i: k
            for i, k in enumerate(at.tolist())
            if records[k].path_xytheta is not None and truth.poses_xytheta is not None
        }
        plain = np.array([i not in spans for i in range(len(at))], dtype=bool)
        self._canvas.send_strips(style.TRUTH_TRAJECTORY, rows, at[plain], segments[plain])
        for i, k in spans.items():
            first = records[known[i - 1][0]].step if i else self._last_true_step
            between = truth.poses_xytheta[first : records[k].step + 1, :2]  # type: ignore[index]
            self._canvas.send_strips(
                style.TRUTH_TRAJECTORY, rows, np.array([k], dtype=np.int64), between[None]
            )
        self._last_true_xy = poses[-1:, :2].copy()
        self._last_true_step = records[at[-1]].step

    def log_metrics(self, record: EventRecord, whole_map: bool, associated: bool) -> None:
        """The series of an update that need the truth, buffered.

        :param associated: the run associates id-less scans, whose ids are not the truth's
        """
        truth = self._canvas.truth
        if truth is None or record.kind is EventKind.PREDICT:
            return
        nees = pose_nees(record, truth)
        if nees is not None:
            self._metrics.add_statistic(style.NEES, record, nees, chi2_bounds(3))
        self.log_landmark_errors(record, None if whole_map else "observed", associated)

    def log_landmark_errors(self, record: EventRecord, which: str | None, associated: bool) -> None:
        """Euclidean error and Mahalanobis distance of the landmarks (see landmark_rows)."""
        truth = self._canvas.truth
        if truth is None or associated:
            return
        rows: IntArray = landmark_rows(record, which)
        ids = record.landmark_ids[rows]
        euclidean, mahalanobis = landmark_errors(
            record.landmarks_xy[rows], record.landmark_covs[rows], truth.lookup(ids)
        )
        add = self._canvas.series.add
        step, event, time = record.step, record.event, record.time
        known = np.isfinite(euclidean)
        if which is None and known.any():  # the whole map: its mean and worst landmark
            for root, values in (
                (style.LANDMARK_ERROR_SUMMARY, euclidean[known]),
                (style.MAHALANOBIS_SUMMARY, mahalanobis[known]),
            ):
                add(f"{root}/{style.MEAN}", step, event, float(values.mean()), time)
                add(f"{root}/{style.WORST}", step, event, float(values.max()), time)
        for landmark_id, error, distance in zip(
            ids.tolist(), euclidean.tolist(), mahalanobis.tolist(), strict=True
        ):
            if math.isfinite(error):
                add(f"{style.LANDMARK_ERROR}/{landmark_id}", step, event, error, time)
                add(f"{style.MAHALANOBIS}/{landmark_id}", step, event, distance, time)
