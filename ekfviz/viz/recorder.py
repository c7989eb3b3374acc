"""Log EKF-SLAM runs, or the plain arrays of any filter, to a Rerun recording stream.

``Recorder`` is the one code path from a filter state to Rerun: ``ekfviz replay`` feeds
it the run's batches of events (``log``), and a user with a filter of their own feeds it
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

The parts of the picture live in :mod:`ekfviz.viz.layers`, one module each over one
shared batch of events; this facade holds the events and hands them to the parts every
``FLUSH_EVERY`` events and at ``finish``, sent in columns (a ``rec.log`` per entity and
event would cost more than the filter). Every event sets both timelines: ``step`` (0 at
the initialisation, +1 per predict, or per update when the step had one) and ``event``
(+1 per event). Styling is logged once as static data.

What is logged when, by default: the robot and its ellipses at every event, a log line
a step, the observation rays at the updates with some, the map as
:mod:`ekfviz.viz.layers.landmarks` says; a timestamped log's predicts thinned
(:mod:`ekfviz.viz.thinning`). ``detail=True`` logs every ellipse and error at every update.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ekfviz import __version__
from ekfviz.core.batch import INIT, PREDICT, UPDATE, EventBatch
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.evaluation.errors import Evaluation
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.viz import style
from ekfviz.viz.axes import fitted_axes
from ekfviz.viz.blueprint import ASSOCIATION_SERIES, REFERENCE_SERIES, default_blueprint
from ekfviz.viz.correlation import CorrelationLayer
from ekfviz.viz.layers.arrays import CHECK_ALL_DIM, ArrayInput
from ekfviz.viz.layers.arrow import EPOCH_MIN_S, MIN_AXIS, frame_id, time_is_epoch
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import MAX_CLASS_ID, SHAPES_EVERY, Canvas
from ekfviz.viz.layers.history import HistoryLayer
from ekfviz.viz.layers.labels import LABEL_HEIGHT, LABEL_WIDTH, LabelsLayer, unclutter
from ekfviz.viz.layers.landmarks import (
    MAP_EVERY_S,
    MAP_EVERY_STEPS,
    MAP_POINTS,
    MAP_TOLERANCE,
    SMALL_MAP,
    MapLayer,
)
from ekfviz.viz.layers.metrics import MetricsLayer
from ekfviz.viz.layers.observations import ObservationsLayer
from ekfviz.viz.layers.pending import FLUSH_EVERY, FLUSH_LANDMARKS, PendingEvents
from ekfviz.viz.layers.robot import HEADING_LENGTH, RobotLayer
from ekfviz.viz.layers.text import TextLayer
from ekfviz.viz.layers.truth import TruthLayer
from ekfviz.viz.legend import ASSOCIATION_RAYS, GPS_TRACK, legend_markdown, markdown_document
from ekfviz.viz.thinning import PREDICT_INTERVAL_S, PredictThinning

if TYPE_CHECKING:  # made at a run's first scan: a log with ids never loads it
    from ekfviz.viz.association import AssociationView

__all__ = [  # the constants of the parts, where callers and tests have found them
    "CHECK_ALL_DIM", "EPOCH_MIN_S", "FLUSH_EVERY", "FLUSH_LANDMARKS", "FLUSH_TIMEOUT_S",
    "HEADING_LENGTH", "LABEL_HEIGHT", "LABEL_WIDTH", "MAP_EVERY_S", "MAP_EVERY_STEPS",
    "MAP_POINTS", "MAP_TOLERANCE", "MAX_CLASS_ID", "MIN_AXIS", "SHAPES_EVERY", "SMALL_MAP",
    "Recorder", "frame_id", "time_is_epoch", "unclutter",
]  # fmt: skip

FLUSH_TIMEOUT_S = 30.0  # how long finish() waits for a slow or absent viewer


class Recorder:
    """Log the state of an EKF-SLAM run to a ``RecordingStream`` the caller owns.

    :param rec: where to log; its sinks are the caller's business
    :param truth: true landmark positions, logged once and used for the error series
    :param landmark_ids: (N,) ids of the state's landmarks in state order, if known up
        front; otherwise the order of first sighting in ``initialise``/``update``, and
        1..N when no ids are ever given
    :param blueprint: send the default layout, at the start and, framing the whole run,
        again at ``finish``
    :param live_layout: send the layout at the start too, for a viewer watching live; a
        recording only saved to a file needs it once (each one sent costs some 100 kB)
    :param run_documents: the layout has tabs for the run information, input and
        evaluation documents (what ``open_run`` logs)
    :param heading_length: length in metres of the robot's heading arrow
    :param prefix: entity path under which to log everything (e.g. ``variants/a``), so
        that several runs share one recording; the default layout then does not fit
    :param detail: log every landmark's ellipse (and, with truth, its errors) at every
        update, however large the map (see the module for what is logged otherwise),
        and every predict
    :param history: the layout's map accumulates every predicted and updated robot
        ellipse up to the time cursor (the classic figure); the data is the same
    :param predict_interval_s: log time between two logged predicts of a timestamped
        log (see :mod:`ekfviz.viz.thinning`); None logs every predict
    :param sensor: the measurement model, to draw id-less scans from the sensor's position
    :param gps_reference: a GPS reference will be logged after ``finish`` (Victoria Park,
        see :func:`ekfviz.viz.reference.log_reference`): the layout has its plot
    :param offline: an offline filter's run (its start and its optimum): series as points
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        *,
        truth: GroundTruth | None = None,
        landmark_ids: Sequence[int] | IntArray | None = None,
        blueprint: bool = True,
        live_layout: bool = True,
        run_documents: bool = False,
        heading_length: float = HEADING_LENGTH,
        prefix: str = "",
        detail: bool = False,
        history: bool = False,
        predict_interval_s: float | None = PREDICT_INTERVAL_S,
        sensor: RangeBearing | None = None,
        gps_reference: bool = False,
        offline: bool = False,
    ) -> None:
        self._canvas = canvas = Canvas(rec, prefix, truth, detail, points=offline)
        self.value_extents = canvas.extents  # NIS and NEES values and bounds, see viz.axes
        self._rec = canvas.entities  # the stream under the prefix (log_reference uses it)
        self._gps_reference = gps_reference
        self._sensor = sensor if sensor is not None else RangeBearing()
        self.association: AssociationView | None = None  # made at the first scan
        self._history = history
        self._truth = truth
        self._arrays = ArrayInput(landmark_ids)
        self._thinning = PredictThinning(None if detail else predict_interval_s)
        # the parts of the picture (see ekfviz.viz.layers)
        self._robot = RobotLayer(canvas, heading_length)
        self._history_layer = HistoryLayer(canvas)
        # labels below the outlines, not in the small maps of a sweep (prefix) nor in a
        # large map, where they would cover it (the viewer shows a label on hover)
        self._labels = LabelsLayer(canvas, labels_off=bool(prefix.strip("/")), small_map=SMALL_MAP)
        self._map = MapLayer(canvas, self._labels, thinned=self._thinning.interval_s is not None)
        self._observations = ObservationsLayer(canvas)
        self._metrics = MetricsLayer(canvas)
        self._truth_layer = TruthLayer(canvas)
        self._text = TextLayer(canvas)
        self._correlation = CorrelationLayer(canvas)
        self.pending = PendingEvents()
        self._event = self._step = 0  # of the last event logged (where a note goes)
        self._blueprint = blueprint
        self._run_documents = run_documents
        if blueprint and live_layout:
            self._rec.send_blueprint(self._layout())
        if not prefix.strip("/") and not run_documents:  # a filter of the user's own
            properties = rr.AnyValues()
            properties.with_component_from_data("version", __version__)
            properties.with_component_from_data("kind", "recorder")
            rec.send_property("ekfviz", properties)
        self._log_styling()
        self._correlation.log_styling()
        seed_ids = list(self._arrays.order)
        if truth is not None:
            seed_ids += truth.ids.tolist()
            self._truth_layer.log_truth(truth)
        self._labels.annotate(np.asarray(seed_ids, dtype=np.int64))

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
        observations = self._arrays.observations(landmark_ids, z, None, None)
        self._arrays.add(x, P, INIT, line, observations)
        self._log_arrays()

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
        control = None if control is None else np.asarray(control, dtype=np.float64)
        self._arrays.add(x, P, PREDICT, line, control=control)
        self._log_arrays()

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
        observations = self._arrays.observations(landmark_ids, z, z_pred, S)
        self._arrays.add(x, P, UPDATE, line, observations)
        self._log_arrays()

    def _log_arrays(self, everything: bool = False) -> None:
        """Log the states handed in through the array API, once a send's worth is in
        (or ``everything``)."""
        builder = self._arrays.builder
        if len(builder) >= FLUSH_EVERY or (everything and len(builder)):
            self.log(builder.build())

    def finish(self, evaluation: Evaluation | None = None) -> None:
        """Send the buffered data, the whole map at the last update, the evaluation document
        if given, the layout framing the whole run, and flush."""
        self._log_held()
        self._map.mark_final()  # its map exactly, in the same send if pending
        self._send_pending()
        self._labels.finish()
        errors_due = self._map.finish()
        if errors_due is not None:
            self._truth_layer.log_landmark_errors(errors_due, None, self.association is not None)
        self._canvas.series.flush()
        if self.association is not None:
            self.association.flush()
        if evaluation is not None:
            document = markdown_document(evaluation.to_markdown())
            self._rec.log(style.RUN_EVALUATION, document, static=True)
        self._rec.send_styles()
        if self._blueprint:
            if legend := legend_markdown(self.entities_with_data):
                self._rec.log(style.RUN_LEGEND, markdown_document(legend), static=True)
            self._rec.send_blueprint(self._layout(self._canvas.bounds_xy, final=True))
        self._rec.flush(timeout_sec=FLUSH_TIMEOUT_S)

    def frame(self, points_xy: FloatArray, label_room: float = 0.0) -> None:
        """The layout sent by :meth:`finish` frames ``points_xy`` too (a source's reference
        track), see :meth:`~ekfviz.viz.layers.canvas.Canvas.frame`."""
        self._canvas.frame(points_xy, label_room)

    def note(self, text: str, level: str | rr.TextLogLevel = rr.TextLogLevel.WARN) -> None:
        """A line in the text log at the latest event: a warning, or why a run stopped."""
        self._log_held()
        self._send_pending()
        self._text.note(self._step, self._event, text, level)

    def _layout(self, bounds_xy: FloatArray | None = None, *, final: bool = False) -> rrb.Blueprint:
        if bounds_xy is not None:
            margin = 0.05 * max(float(np.max(bounds_xy[1] - bounds_xy[0])), 1.0)
            bounds_xy = bounds_xy + np.array([[-margin], [margin]])
        return default_blueprint(
            has=self.entities_with_data if final else None,
            value_axes=fitted_axes(self._canvas.extents),
            landmark_ids=sorted(self._map.seen_ids) if self._truth is not None else (),
            has_truth=self._truth is not None,
            has_true_poses=self._truth is not None and self._truth.has_poses,
            has_run_info=self._run_documents,
            bounds_xy=bounds_xy,
            has_time=self._canvas.clock.span is not None,
            history=self._history,
            offline=self.offline,
        )

    @property
    def offline(self) -> bool:
        """Whether the run is an offline filter's (its series drawn as points)."""
        return self._rec.points

    # -- events --------------------------------------------------------------------------

    @property
    def entities_with_data(self) -> frozenset[str]:
        """The entities (no prefix) given data so far, and a GPS reference's to come."""
        has = set(self._rec.sent)
        if self.association is not None:  # it logs through the stream itself
            has |= {f"{ASSOCIATION_SERIES}/matched", style.LOG, ASSOCIATION_RAYS}
        if self._gps_reference:
            has |= {f"{REFERENCE_SERIES}/gps_error", f"{REFERENCE_SERIES}/gps_rmse", GPS_TRACK}
        return frozenset(has)

    @property
    def time_span(self) -> tuple[float, float] | None:
        """The first and last log time (seconds) logged, or None for an untimed run."""
        return self._canvas.clock.span

    @property
    def time_is_epoch(self) -> bool:
        """Whether the ``time`` timeline is a timestamp (else a duration)."""
        return bool(self._canvas.clock.epoch)

    def log(self, events: EventBatch) -> None:
        """Log a batch of the run's events: the map, the metrics and a line of text a
        step (the predicts of a timestamped log thinned, see :mod:`ekfviz.viz.thinning`)."""
        self._log_admitted(self._thinning.admit(events))

    def _log_held(self) -> None:
        """Log what is held back: the array API's states, the predict the thinning holds
        (the run ended, or a note follows)."""
        self._log_arrays(everything=True)
        held = self._thinning.drain()
        if held is not None:
            self._log_admitted(held)

    def _log_admitted(self, events: EventBatch) -> None:
        if not len(events):
            return
        kinds = events.kinds
        if ((kinds == UPDATE) & ~events.observed.present).any():
            self._rec.series_as_points()  # an offline filter's optimum, after finish()
        whole = self._map.admit(events)
        if any(extra.association is not None for extra in events.extras.values()):
            if self.association is None:  # association ids are not the truth's ids
                from ekfviz.viz.association import AssociationView as View

                self.association = View(self._rec.rec, self._rec.path, self._sensor, self._truth)
            self.association.log(events)
        # where the events got to, though a signal raises in a send below
        self._event, self._step = int(events.events[-1]), int(events.steps[-1])
        self.pending.add(events, whole)
        while (due := self.pending.take_due(self._canvas.clock)) is not None:
            self._send(due, series=True)

    def _send_pending(self, series: bool = False) -> None:
        """Send the events held as one batch drawn by every part (then the series too)."""
        batch = self.pending.take(self._canvas.clock)
        if batch is not None:
            self._send(batch, series)

    def _send(self, batch: Batch, series: bool = False) -> None:
        """Send a batch, drawn by every part (then the series too)."""
        self._robot.send(batch)
        self._truth_layer.send(batch)
        for path, picked in (
            (style.POSE_PREDICTED, np.flatnonzero(batch.is_predict)),
            (style.POSE_UPDATED, batch.corrected),
        ):
            self._robot.send_pose_ellipses(path, batch, picked)
            if self._history:
                self._history_layer.send(path, batch, picked)
        self._observations.send(batch)
        self._metrics.send(batch)
        self._map.send(batch)
        self._metrics.send_health(batch)
        self._text.send(batch)
        self._correlation.send(batch)
        if series:
            self._canvas.series.flush()

    # -- static data -----------------------------------------------------------------------

    def _log_styling(self) -> None:
        """Every part's styling; the world mirrored in the root frame."""
        self._metrics.log_styling()
        self._truth_layer.log_styling()
        # a 2-D view draws y down: "world" mirrored in the root frame shows the map y up
        self._rec.log(style.WORLD, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        self._robot.log_styling()
        if self._history:
            self._history_layer.log_styling()
        self._map.log_styling()
        self._observations.log_styling()
        self._labels.log_styling()
        self._truth_layer.log_truth_styling()
