"""Log EKF-SLAM records, or the plain arrays of any filter, to a Rerun recording stream.

``Recorder`` is the one code path from a filter state to Rerun: ``ekfviz replay`` feeds
it the core's records (``log_record``), and a user with a filter of their own feeds it
numpy arrays in the classic layout x = [x, y, theta, l1x, l1y, ...] (``initialise``,
``predict``, ``update``)::

    rec = rr.RecordingStream("my_slam")
    rec.save("run.rrd")
    recorder = Recorder(rec)
    recorder.initialise(x, P, landmark_ids=ids, z=z)
    for control, (ids, z) in steps:
        ...  # the filter's predict
        recorder.predict(x, P, control=control)
        ...  # the filter's update
        recorder.update(x, P, landmark_ids=ids, z=z, z_pred=z_pred, S=S)
    recorder.finish()

Every call sets both timelines: ``step`` (0 at the initialisation, +1 per predict, or
per update when the step already had one) and ``event`` (+1 per call). Styling is
logged once as static data; metric series are buffered and sent in columns.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import rerun as rr
import rerun.blueprint as rrb

from ekfviz.core.consistency import chi2_bounds, pose_nees, update_nis
from ekfviz.core.evaluation import Evaluation, GroundTruth, landmark_errors
from ekfviz.core.models import wrap_angles
from ekfviz.core.records import EventKind, EventRecord, Observations, snapshot
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.blueprint import default_blueprint
from ekfviz.viz.ellipses import ellipse_outlines, outline_points

FLUSH_EVERY = 1024  # events between two sends of the buffered metric series
FLUSH_TIMEOUT_S = 30.0  # how long finish() waits for a slow or absent viewer
MAX_CLASS_ID = 65535  # Rerun class ids are u16
HEADING_LENGTH = 1.0  # metres


def _radius(ui_points: float) -> npt.ArrayLike:
    return rr.Radius.ui_points(ui_points)


def _f32(strips: FloatArray) -> npt.NDArray[np.float32]:
    """(K, n, 2) polylines in Rerun's own precision (saves a conversion in the SDK)."""
    return strips.astype(np.float32)


class _Entities:
    """The recording stream with every entity path under ``prefix`` (none when empty),
    so that several runs can share one recording (``variants/<key>/world/...``)."""

    def __init__(self, rec: rr.RecordingStream, prefix: str) -> None:
        self.rec = rec
        self._prefix = prefix.strip("/") + "/" if prefix.strip("/") else ""

    def path(self, entity: str) -> str:
        return self._prefix + entity

    def log(self, entity: str, data: Any, *, static: bool = False) -> None:
        self.rec.log(self.path(entity), data, static=static)

    def send_columns(self, entity: str, indexes: Sequence[rr.TimeColumn], columns: Any) -> None:
        self.rec.send_columns(self.path(entity), indexes=indexes, columns=columns)

    def set_time(self, timeline: str, *, sequence: int) -> None:
        self.rec.set_time(timeline, sequence=sequence)

    def send_blueprint(self, blueprint: rrb.Blueprint) -> None:
        self.rec.send_blueprint(blueprint)

    def flush(self, *, timeout_sec: float) -> None:
        self.rec.flush(timeout_sec=timeout_sec)


class _SeriesBuffer:
    """Scalar series gathered per entity path and sent with ``send_columns`` in chunks."""

    def __init__(self, rec: _Entities) -> None:
        self._rec = rec
        self._series: dict[str, tuple[list[int], list[int], list[float]]] = {}

    def add(self, path: str, step: int, event: int, value: float) -> None:
        steps, events, values = self._series.setdefault(path, ([], [], []))
        steps.append(step)
        events.append(event)
        values.append(value)

    def flush(self) -> None:
        for path, (steps, events, values) in self._series.items():
            if values:
                self._rec.send_columns(
                    path,
                    indexes=[
                        rr.TimeColumn(style.STEP, sequence=steps),
                        rr.TimeColumn(style.EVENT, sequence=events),
                    ],
                    columns=rr.Scalars.columns(scalars=values),
                )
        self._series.clear()


class Recorder:
    """Log the state of an EKF-SLAM run to a ``RecordingStream`` the caller owns.

    :param rec: where to log; its sinks are the caller's business
    :param truth: true landmark positions, logged once and used for the error series
    :param landmark_ids: (N,) ids of the state's landmarks in state order, if known up
        front; otherwise the order of first sighting in ``initialise``/``update``, and
        1..N when no ids are ever given
    :param blueprint: send the default layout, at the start and, framing the whole run,
        again at ``finish``
    :param run_documents: the layout has tabs for the run information, input and
        evaluation documents (what ``open_run`` logs)
    :param heading_length: length in metres of the robot's heading arrow
    :param prefix: entity path under which to log everything (e.g. ``variants/a``), so
        that several runs share one recording; the default layout then does not fit
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        *,
        truth: GroundTruth | None = None,
        landmark_ids: Sequence[int] | None = None,
        blueprint: bool = True,
        run_documents: bool = False,
        heading_length: float = HEADING_LENGTH,
        prefix: str = "",
    ) -> None:
        self._rec = _Entities(rec, prefix)
        self._truth = truth
        self._heading_length = heading_length
        self._order: list[int] = [int(i) for i in landmark_ids] if landmark_ids else []
        self._in_order: set[int] = set(self._order)
        self._seen: set[int] = set()  # ids observed so far through the array API
        self._annotated: set[int] = set()
        self._series = _SeriesBuffer(self._rec)
        self._since_flush = 0
        self._event = 0
        self._step = 0
        self._step_has_update = True  # the initialisation counts as step 0's update
        self._last_xy: FloatArray | None = None
        self._blueprint = blueprint
        self._run_documents = run_documents
        self._bounds_xy: FloatArray | None = None  # [[x_min, y_min], [x_max, y_max]] so far
        if blueprint:
            self._rec.send_blueprint(self._layout())
        self._log_styling()
        seed_ids = list(self._order)
        if truth is not None:
            seed_ids += truth.ids.tolist()
            self._log_truth(truth)
        self._annotate(np.asarray(seed_ids, dtype=np.int64))

    # -- the API for any filter --------------------------------------------------------

    def initialise(
        self,
        x: FloatArray,
        P: FloatArray,
        *,
        landmark_ids: Sequence[int] | IntArray | None = None,
        z: FloatArray | None = None,
        line: int = 0,
    ) -> None:
        """Log the initial state (step 0, event 0), with the landmarks seen to build it.

        :param x: (3+2N,) state mean, classic layout
        :param P: (3+2N, 3+2N) state covariance
        :param landmark_ids: (m,) ids of the landmarks initialised from ``z``
        :param z: (m, 2) their measured (bearing, range)
        """
        observations = self._observations(landmark_ids, z, None, None)
        self._event = self._step = 0
        self.log_record(
            snapshot(
                x, P, event=0, step=0, kind=EventKind.INIT, line=line,
                landmark_ids=self._state_ids(x), observations=observations,
            )
        )  # fmt: skip

    def predict(
        self,
        x: FloatArray,
        P: FloatArray,
        *,
        control: FloatArray | Sequence[float] | None = None,
        line: int = 0,
    ) -> None:
        """Log the state after a predict: a new step and a new event.

        :param x: (3+2N,) state mean, classic layout
        :param P: (3+2N, 3+2N) state covariance
        :param control: (2,) the (d, alpha) applied, for the text log
        """
        self.log_record(
            snapshot(
                x, P, event=self._event + 1, step=self._step + 1, kind=EventKind.PREDICT,
                line=line, landmark_ids=self._state_ids(x),
                control=None if control is None else np.asarray(control, dtype=np.float64),
            )
        )  # fmt: skip

    def update(
        self,
        x: FloatArray,
        P: FloatArray,
        *,
        landmark_ids: Sequence[int] | IntArray | None = None,
        z: FloatArray | None = None,
        z_pred: FloatArray | None = None,
        S: FloatArray | None = None,
        line: int = 0,
    ) -> None:
        """Log the state after an update; a landmark id not seen before counts as initialised.

        :param x: (3+2N,) state mean, classic layout
        :param P: (3+2N, 3+2N) state covariance
        :param landmark_ids: (m,) ids of the landmarks observed
        :param z: (m, 2) their measured (bearing, range)
        :param z_pred: (m, 2) the predicted (bearing, range), for the innovation
        :param S: (m, 2, 2) innovation covariances, for the NIS
        """
        observations = self._observations(landmark_ids, z, z_pred, S)
        step = self._step + 1 if self._step_has_update else self._step
        self.log_record(
            snapshot(
                x, P, event=self._event + 1, step=step, kind=EventKind.UPDATE, line=line,
                landmark_ids=self._state_ids(x), observations=observations,
            )
        )  # fmt: skip

    def finish(self, evaluation: Evaluation | None = None) -> None:
        """Send the buffered series, the evaluation document if given, the layout framing
        the whole run, and flush."""
        self._series.flush()
        self._since_flush = 0
        if evaluation is not None:
            self._rec.log(
                style.RUN_EVALUATION,
                rr.TextDocument(evaluation.to_markdown(), media_type=rr.MediaType.MARKDOWN),
                static=True,
            )
        if self._blueprint and self._bounds_xy is not None:
            self._rec.send_blueprint(self._layout(self._bounds_xy))
        self._rec.flush(timeout_sec=FLUSH_TIMEOUT_S)

    def note(self, text: str, level: str | rr.TextLogLevel = rr.TextLogLevel.WARN) -> None:
        """A line in the text log at the latest event: a warning, or why a run stopped."""
        self._rec.set_time(style.STEP, sequence=self._step)
        self._rec.set_time(style.EVENT, sequence=self._event)
        self._rec.log(style.LOG, rr.TextLog(text, level=level))

    def _layout(self, bounds_xy: FloatArray | None = None) -> rrb.Blueprint:
        if bounds_xy is not None:
            margin = 0.05 * max(float(np.max(bounds_xy[1] - bounds_xy[0])), 1.0)
            bounds_xy = bounds_xy + np.array([[-margin], [margin]])
        return default_blueprint(
            has_truth=self._truth is not None,
            has_true_poses=self._truth is not None and self._truth.poses_xytheta is not None,
            has_run_info=self._run_documents,
            bounds_xy=bounds_xy,
        )

    # -- records -------------------------------------------------------------------------

    def log_record(self, record: EventRecord) -> None:
        """Log one record of the core: the map, the metrics and a line of text."""
        rec = self._rec
        self._event, self._step = record.event, record.step
        self._step_has_update = record.kind is not EventKind.PREDICT
        rec.set_time(style.STEP, sequence=record.step)
        rec.set_time(style.EVENT, sequence=record.event)

        xy = record.pose[:2]
        theta = float(record.pose[2])
        rec.log(style.ROBOT, rr.Points2D(xy[None]))
        heading = self._heading_length * np.array([[np.cos(theta), np.sin(theta)]])
        rec.log(style.HEADING, rr.Arrows2D(origins=xy[None], vectors=heading))
        if self._last_xy is not None:
            rec.log(style.TRAJECTORY, rr.LineStrips2D(_f32(np.stack([self._last_xy, xy])[None])))
        self._last_xy = np.array(xy)
        self._grow_bounds(xy[None])
        if record.n_landmarks:
            self._grow_bounds(record.landmarks_xy)

        pose_outline = ellipse_outlines(xy[None], record.pose_cov[None, :2, :2])
        if record.kind is EventKind.PREDICT:
            rec.log(style.POSE_PREDICTED, rr.LineStrips2D(_f32(pose_outline)))
            rec.log(style.OBSERVATIONS, rr.LineStrips2D([]))
        else:
            rec.log(style.POSE_UPDATED, rr.LineStrips2D(_f32(pose_outline)))
            self._log_landmarks(record)

        self._log_metrics(record)
        rec.log(style.LOG, rr.TextLog(self._describe(record), level=rr.TextLogLevel.INFO))
        self._since_flush += 1
        if self._since_flush >= FLUSH_EVERY:
            self._series.flush()
            self._since_flush = 0

    def _log_landmarks(self, record: EventRecord) -> None:
        rec = self._rec
        ids = record.landmark_ids
        self._annotate(ids)
        class_ids = ids if self._has_class_ids(ids) else None
        labels = None if class_ids is not None else [f"L{i}" for i in ids.tolist()]
        rec.log(
            style.LANDMARKS,
            rr.Points2D(record.landmarks_xy, class_ids=class_ids, labels=labels),
        )
        n_points = outline_points(record.n_landmarks)
        outlines = ellipse_outlines(record.landmarks_xy, record.landmark_covs, n_points=n_points)
        rec.log(
            style.LANDMARK_ELLIPSES,
            rr.LineStrips2D(_f32(outlines), class_ids=class_ids),
        )

        observations = record.observations
        if observations is None or len(observations) == 0:
            rec.log(style.OBSERVATIONS, rr.LineStrips2D([]))
            return
        bearing_world = record.pose[2] + observations.z[:, 0]
        seen_xy = record.pose[:2] + observations.z[:, 1:2] * np.column_stack(
            [np.cos(bearing_world), np.sin(bearing_world)]
        )
        rays = np.stack([np.broadcast_to(record.pose[:2], seen_xy.shape), seen_xy], axis=1)
        rec.log(style.OBSERVATIONS, rr.LineStrips2D(_f32(rays)))

        if observations.initialised.any():
            new_ids = observations.ids[observations.initialised]
            rows = np.flatnonzero(np.isin(ids, new_ids))
            initial = ellipse_outlines(
                record.landmarks_xy[rows], record.landmark_covs[rows], n_points=n_points
            )
            new_class_ids = ids[rows] if class_ids is not None else None
            rec.log(
                style.LANDMARK_INITIAL,
                rr.LineStrips2D(_f32(initial), class_ids=new_class_ids),
            )

    def _grow_bounds(self, points_xy: FloatArray) -> None:
        box = np.stack([points_xy.min(axis=0), points_xy.max(axis=0)])
        if self._bounds_xy is not None:
            box = np.stack(
                [np.minimum(box[0], self._bounds_xy[0]), np.maximum(box[1], self._bounds_xy[1])]
            )
        self._bounds_xy = box

    def _log_metrics(self, record: EventRecord) -> None:
        add = self._series.add
        step, event = record.step, record.event
        for name, sigma in zip(("x", "y", "theta"), np.sqrt(np.diag(record.pose_cov)), strict=True):
            add(f"{style.POSE_SIGMA}/{name}", step, event, float(sigma))
        nis = update_nis(record)
        if nis is not None:
            self._add_statistic(style.NIS, step, event, nis[0], chi2_bounds(nis[1]))
        if self._truth is not None and record.kind is not EventKind.PREDICT:
            nees = pose_nees(record, self._truth)
            if nees is not None:
                self._add_statistic(style.NEES, step, event, nees, chi2_bounds(3))
        if self._truth is not None and record.kind is not EventKind.PREDICT:
            truth_xy = self._truth.lookup(record.landmark_ids)
            euclidean, mahalanobis = landmark_errors(
                record.landmarks_xy, record.landmark_covs, truth_xy
            )
            for landmark_id, error, distance in zip(
                record.landmark_ids.tolist(), euclidean.tolist(), mahalanobis.tolist(), strict=True
            ):
                if np.isfinite(error):
                    add(f"{style.LANDMARK_ERROR}/{landmark_id}", step, event, error)
                    add(f"{style.MAHALANOBIS}/{landmark_id}", step, event, distance)

    def _add_statistic(
        self, path: str, step: int, event: int, value: float, bounds: tuple[float, float]
    ) -> None:
        """A NIS or NEES value with its chi-square bounds, drawn in the same plot."""
        self._series.add(path, step, event, value)
        self._series.add(f"{path}/{style.LOWER}", step, event, bounds[0])
        self._series.add(f"{path}/{style.UPPER}", step, event, bounds[1])

    @staticmethod
    def _describe(record: EventRecord) -> str:
        where = f"step {record.step} {record.kind.value}"
        if record.line:
            where += f" line {record.line}"
        if record.kind is EventKind.PREDICT:
            if record.control is None:
                return where
            d, alpha = record.control
            return f"{where}: d {d:.3f}, alpha {alpha:.4f}"
        observations = record.observations
        if observations is None:
            return f"{where}: {record.n_landmarks} landmarks in the map"
        new = int(observations.initialised.sum())
        text = f"{where}: {len(observations)} landmarks"
        if new:
            text += f" ({new} new)"
        nis = observations.nis[np.isfinite(observations.nis)]
        if nis.size:
            text += f", NIS {nis.sum():.2f}"
        return text

    # -- static data -----------------------------------------------------------------------

    def _log_styling(self) -> None:
        rec = self._rec
        for path, name in ((style.NIS, "NIS"), (style.NEES, "NEES")):
            rec.log(path, rr.SeriesLines(colors=style.STATISTIC_COLOR, names=name), static=True)
            for bound, label in ((style.LOWER, "95% lower"), (style.UPPER, "95% upper")):
                rec.log(
                    f"{path}/{bound}",
                    rr.SeriesLines(colors=style.BOUND_COLOR, names=label, widths=1.0),
                    static=True,
                )
        # A 2-D view draws y down; mirroring "world" in the root frame shows the map y up
        # as in the classic plots, while every entity keeps its true world coordinates.
        rec.log(style.WORLD, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        line = _radius(style.LINE_RADIUS_UI)
        rec.log(
            style.ROBOT,
            rr.Points2D.from_fields(
                colors=style.ROBOT_COLOR, radii=_radius(style.ROBOT_RADIUS_UI), draw_order=40.0
            ),
            static=True,
        )
        rec.log(
            style.HEADING,
            rr.Arrows2D.from_fields(colors=style.ROBOT_COLOR, radii=line, draw_order=40.0),
            static=True,
        )
        rec.log(
            style.TRAJECTORY,
            rr.LineStrips2D.from_fields(colors=style.TRAJECTORY_COLOR, radii=line, draw_order=10.0),
            static=True,
        )
        for path, color in (
            (style.POSE_PREDICTED, style.PREDICTED_COLOR),
            (style.POSE_UPDATED, style.UPDATED_COLOR),
            (style.LANDMARK_ELLIPSES, style.LANDMARK_COLOR),
            (style.LANDMARK_INITIAL, style.INITIAL_COLOR),
        ):
            rec.log(
                path,
                rr.LineStrips2D.from_fields(
                    colors=color, radii=line, show_labels=False, draw_order=20.0
                ),
                static=True,
            )
        rec.log(
            style.OBSERVATIONS,
            rr.LineStrips2D.from_fields(
                colors=style.OBSERVATION_COLOR,
                radii=_radius(style.THIN_LINE_RADIUS_UI),
                draw_order=15.0,
            ),
            static=True,
        )
        rec.log(
            style.LANDMARKS,
            rr.Points2D.from_fields(
                colors=style.LANDMARK_COLOR, radii=_radius(style.POINT_RADIUS_UI), draw_order=30.0
            ),
            static=True,
        )
        rec.log(
            style.TRUTH_LANDMARKS,
            rr.Points2D.from_fields(
                colors=style.TRUTH_COLOR,
                radii=_radius(style.TRUTH_RADIUS_UI),
                show_labels=False,
                draw_order=35.0,
            ),
            static=True,
        )

    def _log_truth(self, truth: GroundTruth) -> None:
        class_ids = truth.ids if self._has_class_ids(truth.ids) else None
        self._rec.log(
            style.TRUTH_LANDMARKS, rr.Points2D(truth.landmarks_xy, class_ids=class_ids), static=True
        )

    def _annotate(self, ids: IntArray) -> None:
        """Give every landmark id a class with its label, re-logging the context rarely.

        New ids extend the annotated set by as many consecutive ids again after the
        largest, so landmarks met one at a time cost O(log N) re-logs, not O(N).
        """
        new = {int(i) for i in ids.tolist() if 0 <= i <= MAX_CLASS_ID} - self._annotated
        if not new:
            return
        wanted = self._annotated | new
        top = max(wanted)
        wanted |= set(range(top + 1, min(top + len(wanted), MAX_CLASS_ID) + 1))
        self._annotated = wanted
        self._rec.log(
            style.WORLD,
            rr.AnnotationContext([(i, f"L{i}") for i in sorted(wanted)]),
            static=True,
        )

    @staticmethod
    def _has_class_ids(ids: IntArray) -> bool:
        return ids.size == 0 or bool(ids.min() >= 0 and ids.max() <= MAX_CLASS_ID)

    # -- the bookkeeping of the array API -------------------------------------------------

    def _state_ids(self, x: FloatArray) -> IntArray:
        n = (len(x) - 3) // 2
        if len(self._order) < n:
            start = max(self._order, default=0) + 1
            self._order += range(start, start + n - len(self._order))
            self._in_order.update(self._order)
        return np.asarray(self._order[:n], dtype=np.int64)

    def _observations(
        self,
        landmark_ids: Sequence[int] | IntArray | None,
        z: FloatArray | None,
        z_pred: FloatArray | None,
        S: FloatArray | None,
    ) -> Observations | None:
        """Build what an update did from plain arrays; ids not met before are new."""
        if landmark_ids is None or z is None:
            return None
        ids = np.asarray(landmark_ids, dtype=np.int64).reshape(-1)
        m = len(ids)
        z = np.asarray(z, dtype=np.float64).reshape(m, 2)
        initialised = np.array([i not in self._seen for i in ids.tolist()], dtype=bool)
        for landmark_id in ids[initialised].tolist():
            self._seen.add(landmark_id)
            if landmark_id not in self._in_order:
                self._order.append(landmark_id)
                self._in_order.add(landmark_id)
        nan2 = np.full((m, 2), np.nan)
        z_pred = nan2.copy() if z_pred is None else np.asarray(z_pred, np.float64).reshape(m, 2)
        innovation = z - z_pred
        innovation[:, 0] = wrap_angles(innovation[:, 0])
        S = np.full((m, 2, 2), np.nan) if S is None else np.asarray(S, np.float64).reshape(m, 2, 2)
        nis = np.full(m, np.nan)
        known = ~initialised & np.isfinite(innovation).all(axis=1) & np.isfinite(S).all(axis=(1, 2))
        if known.any():
            whitened = np.linalg.solve(S[known], innovation[known][:, :, None])[:, :, 0]
            nis[known] = np.einsum("ij,ij->i", innovation[known], whitened)
        z_pred[initialised] = innovation[initialised] = np.nan
        S[initialised] = np.nan
        return Observations(
            ids=ids, z=z, z_pred=z_pred, innovation=innovation, S=S, nis=nis,
            initialised=initialised,
        )  # fmt: skip
