"""What needs the truth: the true landmarks and path (``world/truth/...``), the pose's
NEES, and each landmark's Euclidean error and Mahalanobis distance with their summary."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from ekfviz.core.batch import ranges
from ekfviz.core.records import EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.evaluation.consistency import chi2_bounds, poses_nees
from ekfviz.evaluation.errors import landmark_errors
from ekfviz.viz import style
from ekfviz.viz.annotations import annotation_context
from ekfviz.viz.layers.arrow import in_parent_frame, positions, radius, robot_frame
from ekfviz.viz.layers.batch import Batch, landmark_rows
from ekfviz.viz.layers.canvas import Canvas, has_class_ids
from ekfviz.viz.layers.map_rows import JoinedIds, joined_rows
from ekfviz.viz.legend import KIND_CLASS


class TruthLayer:
    """The truth and the series measured against it."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas
        self._last_true_xy: FloatArray | None = None  # (1, 2) the true path's last point
        self._last_true_step = 0  # the step of the last true pose logged
        self._associated = False  # an update associated id-less scans: no errors from it on

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
                    class_ids=KIND_CLASS[style.TRUTH_ROBOT],
                    show_labels=False,
                ),
                in_parent_frame(entities.path(style.TRUTH_ROBOT)),  # see arrow.robot_frame
            )
            entities.style(
                style.TRUTH_TRAJECTORY,
                rr.LineStrips2D.from_fields(
                    colors=style.TRUTH_PATH_COLOR,
                    radii=radius(style.THIN_LINE_RADIUS_UI),
                    draw_order=5.0,
                    class_ids=KIND_CLASS[style.TRUTH_TRAJECTORY],
                    show_labels=False,
                ),
            )
        # named "true L<id>" on hover by a context of their own, in the same static chunk
        # as the points and their styling; an id beyond the class ids by a label
        ids = truth.ids.tolist()
        if has_class_ids(truth.ids):
            points = rr.Points2D(truth.landmarks_xy, class_ids=truth.ids)
            entities.log(
                style.TRUTH_LANDMARKS,
                points,
                annotation_context(ids, [f"true L{i}" for i in ids]),
                static=True,
            )
        else:
            labels = [f"true L{i}" for i in ids]
            entities.log(
                style.TRUTH_LANDMARKS, rr.Points2D(truth.landmarks_xy, labels=labels), static=True
            )

    def send(self, batch: Batch) -> None:
        """The landmarks' errors of the batch's updates (:meth:`send_landmark_errors`),
        and, at each update with a true pose (by step, or by time on a track), the pose's
        NEES, and that pose as a robot frame with a segment of the true path from the step
        before."""
        truth = self._canvas.truth
        if truth is None:
            return
        self.send_landmark_errors(batch)
        if not truth.has_poses:
            return
        rows, corrected = batch.rows, batch.corrected
        true_poses, known = truth.poses_of(rows.steps[corrected], batch.times[corrected])
        if not known.any():
            return
        at, poses = corrected[known], true_poses[known]
        self._send_nees(batch, at, poses)
        self._canvas.send(style.TRUTH_ROBOT, rows.pick(at), [positions(poses), *robot_frame(poses)])
        starts = np.vstack([poses[:1, :2] if self._last_true_xy is None else self._last_true_xy,
                            poses[:-1, :2]])  # fmt: skip
        segments = np.stack([starts, poses[:, :2]], axis=1)
        # an offline filter's final record spans the run: the true path of every step
        # between, beside its whole estimated path (see RobotLayer)
        spans = {
            i: k
            for i, k in enumerate(at.tolist())
            if batch.events.extra(k).path_xytheta is not None and truth.poses_xytheta is not None
        }
        plain = np.array([i not in spans for i in range(len(at))], dtype=bool)
        self._canvas.send_strips(style.TRUTH_TRAJECTORY, rows, at[plain], segments[plain])
        steps = rows.steps
        for i, k in spans.items():
            first = int(steps[at[i - 1]]) if i else self._last_true_step
            between = truth.poses_xytheta[first : int(steps[k]) + 1, :2]  # type: ignore[index]
            self._canvas.send_strips(
                style.TRUTH_TRAJECTORY, rows, np.array([k], dtype=np.int64), between[None]
            )
        self._last_true_xy = poses[-1:, :2].copy()
        self._last_true_step = int(steps[at[-1]])

    def _send_nees(self, batch: Batch, at: IntArray, true_poses: FloatArray) -> None:
        """The NEES of the poses at the rows ``at`` of a batch against ``true_poses``, with
        its chi-square bounds (3 dof), buffered: drawn in the same plot."""
        nees, defined = poses_nees(batch.poses[at], batch.pose_covs[at], true_poses)
        if not defined.any():
            return
        at, nees = at[defined], nees[defined]
        low, high = chi2_bounds(3)
        self._canvas.extent(style.NEES, nees, low, high)
        when = (batch.rows.steps[at].tolist(), batch.rows.events[at].tolist())
        times = batch.times[at].tolist()
        series = self._canvas.series
        series.extend(style.NEES, *when, nees.tolist(), times)
        series.extend(f"{style.NEES}/{style.LOWER}", *when, [low] * len(at), times)
        series.extend(f"{style.NEES}/{style.UPPER}", *when, [high] * len(at), times)

    def send_landmark_errors(self, batch: Batch) -> None:
        """:meth:`log_landmark_errors` of every update of a batch at once: of the whole
        map where the update logs it, else of the landmarks it observed; none from the
        first update of id-less scans on (their ids are not the truth's)."""
        truth, maps = self._canvas.truth, batch.maps
        if truth is None or not batch.corrected.size:
            return
        scans = np.zeros(len(maps.ids), dtype=bool)
        scans[list(maps.associations)] = True
        if self._associated or scans.any():
            associated = np.logical_or.accumulate(scans) | self._associated
            self._associated = bool(associated[-1])
            picks = np.flatnonzero(~associated)
        else:
            picks = np.arange(len(scans))
        whole = batch.whole[batch.corrected][picks]
        # the rows of each pick's landmarks in the joined maps, pick after pick
        every, seen = picks[whole], picks[~whole]
        rows_every = ranges(maps.starts[every], maps.starts[every + 1])
        rows_seen, counts_seen = joined_rows(maps, seen, "observed", {})
        owner = np.concatenate([np.repeat(every, maps.counts[every]), np.repeat(seen, counts_seen)])
        order = np.argsort(owner, kind="stable")
        rows, owner = np.concatenate([rows_every, rows_seen])[order], owner[order]
        ids = JoinedIds(maps.ids).of(rows)
        euclidean, mahalanobis = landmark_errors(maps.xy[rows], maps.covs[rows], truth.lookup(ids))
        at = batch.corrected[owner]  # each row's event in the batch
        steps, events = batch.rows.steps[at].tolist(), batch.rows.events[at].tolist()
        times = batch.times[at].tolist()
        known = np.isfinite(euclidean)
        self._send_summaries(batch, every, owner, euclidean, mahalanobis, known)
        series = self._canvas.series
        by_id = np.argsort(ids, kind="stable")  # each landmark's values, in event order
        starts = np.flatnonzero(np.r_[True, ids[by_id][1:] != ids[by_id][:-1]])
        for first, end in zip(starts.tolist(), [*starts[1:].tolist(), len(ids)], strict=True):
            picked = [k for k in by_id[first:end].tolist() if known[k]]
            if not picked:
                continue
            landmark_id = int(ids[by_id[first]])
            when = ([steps[k] for k in picked], [events[k] for k in picked])
            at_times = [times[k] for k in picked]
            for path, values in (
                (f"{style.LANDMARK_ERROR}/{landmark_id}", euclidean),
                (f"{style.MAHALANOBIS}/{landmark_id}", mahalanobis),
            ):
                series.extend(path, *when, values[picked].tolist(), at_times)

    def _send_summaries(
        self,
        batch: Batch,
        every: IntArray,
        owner: IntArray,
        euclidean: FloatArray,
        mahalanobis: FloatArray,
        known: BoolArray,
    ) -> None:
        """The mean and worst landmark of each whole map (``every``: its updates) with a
        landmark the truth knows, as :meth:`log_landmark_errors` takes them."""
        if not every.size:
            return
        first = np.searchsorted(owner, every)
        counts = np.searchsorted(owner, every, side="right") - first
        has = counts > 0
        every, first, counts = every[has], first[has], counts[has]
        if not len(first):
            return
        ends = first + counts
        # numpy's mean of a row of a (maps, landmarks) array is a map's own mean to the
        # bit (reduceat sums otherwise): the maps of one size whose landmarks the truth
        # all knows at once, each other map on its own
        groups: list[tuple[IntArray, IntArray]] = []  # the maps of a size, their rows
        alone: list[int] = []
        for size in np.unique(counts).tolist():
            maps_of = np.flatnonzero(counts == size)
            rows = first[maps_of][:, None] + np.arange(size)
            whole = known[rows].all(axis=1)
            groups.append((maps_of[whole], rows[whole]))
            alone += maps_of[~whole].tolist()
        at = batch.corrected[every]
        series = self._canvas.series
        for root, values in (
            (style.LANDMARK_ERROR_SUMMARY, euclidean),
            (style.MAHALANOBIS_SUMMARY, mahalanobis),
        ):
            means, worst = np.full(len(every), np.nan), np.full(len(every), np.nan)
            for maps_of, rows in groups:
                means[maps_of] = values[rows].mean(axis=1)
                worst[maps_of] = values[rows].max(axis=1)
            for i in alone:  # only its landmarks the truth knows, as log_landmark_errors
                span = slice(int(first[i]), int(ends[i]))
                mine = values[span][known[span]]
                if mine.size:
                    means[i], worst[i] = mine.mean(), mine.max()
            logged = np.isfinite(means)
            when = (batch.rows.steps[at][logged].tolist(), batch.rows.events[at][logged].tolist())
            at_times = batch.times[at][logged].tolist()
            series.extend(f"{root}/{style.MEAN}", *when, means[logged].tolist(), at_times)
            series.extend(f"{root}/{style.WORST}", *when, worst[logged].tolist(), at_times)

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
