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
logged once as static data. Everything else is buffered and sent in columns
(``send_columns``) every ``FLUSH_EVERY`` events and at ``finish``: a ``rec.log`` per
entity and event would cost more than the filter itself.

What is logged when, by default: the robot and its ellipses at every event, a log line
a step, the observation rays at the updates with some; all landmark positions where the
map grew or some landmark moved by over ``MAP_TOLERANCE`` of its ellipse (the viewer
shows the latest). The 3-sigma ellipses of all landmarks likewise while the map holds
at most ``SMALL_MAP`` landmarks; beyond that, at
every update only those of the landmarks observed (``world/landmarks/ellipses/observed``)
and the whole map every ``MAP_EVERY_STEPS`` steps and at the end (the viewer shows the
latest of each, so every landmark keeps an ellipse at any time). A timestamped log
(high-rate odometry) logs its predicts thinned (:mod:`ekfviz.viz.thinning`) and its map
like a large one, the whole map every ``MAP_EVERY_S`` seconds of log time. With truth, the error
series of a landmark get a value whenever its ellipse is logged. ``detail=True`` logs
every ellipse and error at every update.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr
import rerun.blueprint as rrb

from ekfviz import __version__
from ekfviz.core.correlation import Correlation, CorrelationCadence, correlation_of
from ekfviz.core.health import (
    CovarianceCheck,
    check_covariance,
    check_interval,
    landmark_min_eigenvalues,
    pose_min_eigenvalues,
)
from ekfviz.core.records import EventKind, EventRecord, Observations, snapshot
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.evaluation.consistency import chi2_bounds, pose_nees
from ekfviz.evaluation.errors import Evaluation, landmark_errors
from ekfviz.models.angles import wrap_angles
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.viz import style
from ekfviz.viz.association import AssociationView
from ekfviz.viz.blueprint import ASSOCIATION_SERIES, REFERENCE_SERIES, default_blueprint
from ekfviz.viz.correlation import log_correlation, log_correlation_styling
from ekfviz.viz.ellipses import (
    ellipse_axes,
    ellipse_extent,
    ellipse_outlines,
    outline_points,
    unit_circle,
)
from ekfviz.viz.flush import flush_interruptibly
from ekfviz.viz.thinning import PREDICT_INTERVAL_S, PredictThinning

# Events between two sends of the buffered data, one chunk per entity: each chunk costs
# ~0.1 ms in the main thread and as much in Rerun's encoder, whatever its size.
FLUSH_EVERY = 4096
SHAPES_EVERY = 256  # ... but line strips in chunks of at most this many events (_send_strips)
FLUSH_LANDMARKS = 1 << 20  # ... or sooner, once the buffered records hold this many landmarks
SMALL_MAP = 32  # up to this many landmarks, every ellipse at every update
# A landmark label's box as a fraction of the map's span, at the zoom that frames the map
# (about "L12" at 14 px on a 700 px map): closer labels are stacked (see unclutter)
LABEL_WIDTH = 0.05
LABEL_HEIGHT = 0.03
MAP_EVERY_STEPS = 25  # beyond: the whole map every this many steps
# A small map is logged again only once some landmark's point or outline would move by
# more than this fraction of its ellipse's semi-major axis (the viewer shows the latest).
MAP_TOLERANCE = 0.02
MAP_POINTS = 16  # points of a landmark outline: within 2 % of its radius, as MAP_TOLERANCE
MAP_EVERY_S = 5.0  # ... and in a thinned timestamped log, every this many seconds of log time
FLUSH_TIMEOUT_S = 30.0  # how long finish() waits for a slow or absent viewer
MAX_CLASS_ID = 65535  # Rerun class ids are u16
HEADING_LENGTH = 1.0  # metres
CHECK_ALL_DIM = 64  # the array API checks a covariance up to this size at every call
MIN_AXIS = 1e-9  # metres: the shortest semi-axis a pose ellipse's transform gets
EPOCH_MIN_S = 1e9  # log times from here on are Unix time (see time_is_epoch)


def _radius(ui_points: float) -> npt.ArrayLike:
    return rr.Radius.ui_points(ui_points)


def unclutter(anchors_xy: FloatArray, width: float, height: float) -> FloatArray:
    """Label anchors moved down (y up) until no two labels' boxes overlap.

    :param anchors_xy: (n, 2) where each label hangs (its top centre), in world units
    :param width: a label's width, in world units; ``height`` likewise
    :return: (n, 2) the anchors, the higher of two overlapping ones kept in place
    """
    n = len(anchors_xy)
    if n < 2:
        return anchors_xy
    dx = np.abs(anchors_xy[:, None, 0] - anchors_xy[None, :, 0])
    dy = np.abs(anchors_xy[:, None, 1] - anchors_xy[None, :, 1])
    overlap = (dx < width) & (dy < height)
    np.fill_diagonal(overlap, False)
    if not overlap.any():  # the common case, without a loop
        return anchors_xy
    placed: FloatArray = anchors_xy.copy()
    done: list[int] = []
    for i in np.argsort(-anchors_xy[:, 1], kind="stable").tolist():
        x, y = placed[i]
        moved = True
        while moved:  # below every label already placed that it would cover
            moved = False
            for j in done:
                if abs(placed[j, 0] - x) < width and abs(placed[j, 1] - y) < height:
                    y = placed[j, 1] - 1.001 * height  # clear of it despite round-off
                    moved = True
        placed[i, 1] = y
        done.append(i)
    return placed


# Arrow types of the components built here (see _column), from the SDK's own conversion
_XY = rr.components.Position2DBatch([[0.0, 0.0]]).as_arrow_array().type
_VECTOR = rr.components.Vector2DBatch([[0.0, 0.0]]).as_arrow_array().type
_STRIP = rr.components.LineStrip2DBatch([[[0.0, 0.0], [0.0, 0.0]]]).as_arrow_array().type
_VEC3 = rr.components.Translation3DBatch([[0.0, 0.0, 0.0]]).as_arrow_array().type
_MAT3 = rr.components.TransformMat3x3Batch([np.eye(3)]).as_arrow_array().type
_QUAT = rr.components.RotationQuatBatch([[0.0, 0.0, 0.0, 1.0]]).as_arrow_array().type


@dataclass(frozen=True, slots=True)
class _Arrow:
    """An Arrow array built here, as the SDK's ``ComponentBatchLike``."""

    array: pa.Array

    def as_arrow_array(self) -> pa.Array:
        return self.array


def _column(
    descriptor: rr.ComponentDescriptor, values: pa.Array, counts: IntArray | None = None
) -> rr.ComponentColumn:
    """``values`` as a column of rows of ``counts[i]`` values each (one each by default).

    Built straight from Arrow: the SDK's archetype ``columns`` check and convert their
    input in Python at every call, which cost more than the rest of a send, a dozen
    sends per flush.
    """
    offsets = np.zeros(len(values) + 1 if counts is None else len(counts) + 1, dtype=np.int32)
    if counts is None:
        offsets[1:] = np.arange(1, len(values) + 1)
    else:
        np.cumsum(counts, out=offsets[1:])
    return rr.ComponentColumn(descriptor, _Arrow(values), offsets=offsets)


def _run_ends(values: npt.NDArray[Any]) -> IntArray:
    """Indices of the first and last value of every run of equal values.

    A series that only changes now and then (chi-square bounds, counts of skipped
    observations) plots exactly the same from these alone: the viewer draws straight
    lines between the points it has, flat along a run.
    """
    n = len(values)
    if n <= 2:
        return np.arange(n)
    changes = values[1:] != values[:-1]
    keep = np.ones(n, dtype=bool)
    keep[1:-1] = changes[:-1] | changes[1:]  # differs from the one before or after
    return np.flatnonzero(keep)


def _shapes(means_xy: FloatArray, covs: FloatArray) -> FloatArray:
    """(K, 6) rows [mx, my, 3 sqrt(C) flattened]: a 3-sigma ellipse by its mean and the
    symmetric square root of its covariance (unique, unlike the eigenvectors' signs),
    sqrt(C) = (C + sqrt(det C) I) / sqrt(tr C + 2 sqrt(det C)) for 2x2."""
    root_det = np.sqrt(np.clip(np.linalg.det(covs), 0.0, None))
    scale = np.sqrt(np.clip(np.trace(covs, axis1=1, axis2=2) + 2.0 * root_det, 0.0, None))
    roots = (covs + root_det[:, None, None] * np.eye(2)) / np.where(scale > 0, scale, 1.0)[
        :, None, None
    ]
    return np.column_stack([means_xy, 3.0 * roots.reshape(-1, 4)])


def _scalars(values: npt.ArrayLike) -> list[rr.ComponentColumn]:
    """One ``Scalars`` value per row."""
    array = pa.array(np.asarray(values, dtype=np.float64))
    return [_column(rr.Scalars.descriptor_scalars(), array)]


def _xy(points: FloatArray, vector_type: pa.DataType = _XY) -> pa.Array:
    """(K, 2) points (or vectors) as Rerun's float32 pairs."""
    flat = pa.array(np.ascontiguousarray(points, dtype=np.float32).reshape(-1))
    return pa.FixedSizeListArray.from_arrays(flat, type=vector_type)


def _strips(polylines: FloatArray) -> pa.Array:
    """(K, n, 2) polylines as Rerun's line strips, in its own float32.

    Built as the Arrow array Rerun would make, with offsets from numpy: the SDK's own
    conversion walks the strips in Python, which costs more than the rest of logging them.
    """
    k, n = polylines.shape[:2]
    offsets = pa.array(
        np.arange(0, (k + 1) * n, n, dtype=np.int32) if n else np.zeros(k + 1, np.int32)
    )
    return pa.ListArray.from_arrays(offsets, _xy(polylines.reshape(-1, 2)), type=_STRIP)


def _fixed(values: npt.NDArray[Any], arrow_type: pa.DataType) -> pa.Array:
    """(K, n) values as Rerun's fixed-size lists of n float32."""
    flat = pa.array(np.ascontiguousarray(values, dtype=np.float32).reshape(-1))
    return pa.FixedSizeListArray.from_arrays(flat, type=arrow_type)


def _positions(poses: FloatArray) -> rr.ComponentColumn:
    """(K, 3) poses as a ``Points2D`` column of their positions, one point a row."""
    return _column(rr.Points2D.descriptor_positions(), _xy(poses[:, :2]))


def _robot_frame(poses: FloatArray) -> list[rr.ComponentColumn]:
    """(K, 3) poses as ``Transform3D`` columns placing the robot frame in the world:
    translation (x, y, 0) and the rotation theta about z as a quaternion (x, y, z, w).

    Logged on the robot's point (``world/robot``), whose rows they share: they place
    what is under it (``world/robot/frame/...``), while the point itself stays in the
    world's frame (its ``CoordinateFrame``, see ``Recorder._log_styling``). One row an
    event instead of two: a row costs some 20 bytes of row id and timelines.
    """
    k = len(poses)
    translations = np.zeros((k, 3))
    translations[:, :2] = poses[:, :2]
    half = 0.5 * poses[:, 2]
    quaternions = np.zeros((k, 4))
    quaternions[:, 2], quaternions[:, 3] = np.sin(half), np.cos(half)
    return [
        _column(rr.Transform3D.descriptor_translation(), _fixed(translations, _VEC3)),
        _column(rr.Transform3D.descriptor_quaternion(), _fixed(quaternions, _QUAT)),
    ]


def frame_id(entity_path: str) -> str:
    """The name of an entity's implicit transform frame (Rerun's ``tf#/<path>``)."""
    return f"tf#/{entity_path.strip('/')}"


def _in_parent_frame(path: str) -> rr.CoordinateFrame:
    """The data of the entity at ``path`` in its parent's frame, not in the frame its own
    ``Transform3D`` places (that one places only the entities under it)."""
    return rr.CoordinateFrame(frame_id(path.rsplit("/", 1)[0]))


def _shape_matrices(axes: FloatArray) -> pa.Array:
    """(K, 2, 2) maps A of the unit circle onto ellipses as 3x3 matrices diag(A, 1),
    stored by columns as Rerun does.

    A flat ellipse (an axis of 0) would make the matrix singular, which the viewer does
    not draw: its axes are kept at least ``MIN_AXIS`` long.
    """
    k = len(axes)
    lengths = np.linalg.norm(axes, axis=1, keepdims=True)  # of the columns: the semi-axes
    unit = np.divide(axes, lengths, out=np.tile(np.eye(2), (k, 1, 1)), where=lengths > 0)
    axes = unit * np.maximum(lengths, MIN_AXIS)
    matrices = np.zeros((k, 9))
    matrices[:, [0, 1, 3, 4]] = axes.transpose(0, 2, 1).reshape(k, 4)  # by columns
    matrices[:, 8] = 1.0
    return _fixed(matrices, _MAT3)


_NO_ROWS: IntArray = np.zeros(0, dtype=np.int64)
_INFO, _WARN = str(rr.TextLogLevel.INFO), str(rr.TextLogLevel.WARN)  # as Arrow strings


@dataclass(frozen=True, slots=True)
class _Index:
    """A time column already in Arrow, as the SDK's ``TimeColumnLike``."""

    timeline: str
    times: pa.Array

    def timeline_name(self) -> str:
        return self.timeline

    def as_arrow_array(self) -> pa.Array:
        return self.times


def _times(
    steps: IntArray, events: IntArray, times: FloatArray | None = None, epoch: bool = False
) -> list[rr.TimeColumnLike]:
    """The timelines of some rows, in Arrow: ``step``, ``event`` and, when the records
    have times, ``time`` (see :func:`time_is_epoch` for its type)."""
    columns: list[rr.TimeColumnLike] = [
        _Index(style.STEP, pa.array(steps)),
        _Index(style.EVENT, pa.array(events)),
    ]
    if times is not None:
        nanos = np.rint(times * 1e9).astype(np.int64)
        kind = pa.timestamp("ns") if epoch else pa.duration("ns")
        columns.append(_Index(style.TIME, pa.array(nanos, type=kind)))
    return columns


def time_is_epoch(first_time: float) -> bool:
    """Whether the ``time`` timeline is a timestamp (Unix time, shown as a date) rather
    than a duration: decided once per recording by its first time, from 10^9 s
    (September 2001) on. Either way its value in seconds is the log's time."""
    return first_time >= EPOCH_MIN_S


class _Rows:
    """The step, event and time of each buffered record, to pick the time columns of a send."""

    def __init__(
        self,
        steps: IntArray,
        events: IntArray,
        times: FloatArray | None = None,
        epoch: bool = False,
    ) -> None:
        self.steps = steps
        self.events = events
        self.times = times
        self.epoch = epoch
        self.all = _times(steps, events, times, epoch)  # most sends have a row per record

    def __len__(self) -> int:
        return len(self.steps)

    def pick(self, rows: Sequence[int] | IntArray) -> list[rr.TimeColumnLike]:
        index = np.asarray(rows, dtype=np.int64)
        times = None if self.times is None else self.times[index]
        return _times(self.steps[index], self.events[index], times, self.epoch)


def _landmark_rows(record: EventRecord, which: str | None) -> IntArray:
    """Rows of ``record``'s landmarks: all (None), the observed or the initialised ones."""
    if which is None or record.observations is None:
        return np.arange(record.n_landmarks)
    observations = record.observations
    ids = observations.ids if which == "observed" else observations.ids[observations.initialised]
    return np.flatnonzero(np.isin(record.landmark_ids, ids))


@dataclass(frozen=True, slots=True)
class _Observed:
    """What the updates of a send did with their observations, summed per record in one
    go (a numpy call per record would cost more than the rest of its logging).

    :param rows: the records with observations
    :param seen: (count,) observations per record, 0 without
    :param z: (sum(seen), 2) their measured (bearing, range), record after record
    """

    rows: IntArray
    seen: IntArray
    z: FloatArray
    new: IntArray
    nis_sum: FloatArray
    nis_used: IntArray
    skipped: IntArray

    @staticmethod
    def of(records: list[EventRecord], corrected: IntArray) -> _Observed:
        count = len(records)
        observed = [
            (k, observations)
            for k in corrected.tolist()
            if (observations := records[k].observations) is not None
        ]
        rows = np.array([k for k, _ in observed], dtype=np.int64)
        seen = np.zeros(count, dtype=np.int64)
        seen[rows] = [len(observations) for _, observations in observed]
        owner = np.repeat(np.arange(count), seen)

        def joined(field: str, empty: npt.NDArray[Any]) -> npt.NDArray[Any]:
            return np.concatenate([empty, *(getattr(o, field) for _, o in observed)])

        nis = joined("nis", np.zeros(0))
        used = np.isfinite(nis)
        return _Observed(
            rows=rows,
            seen=seen,
            z=joined("z", np.zeros((0, 2))),
            new=np.bincount(owner[joined("initialised", np.zeros(0, bool))], minlength=count),
            nis_sum=np.bincount(owner[used], weights=nis[used], minlength=count).astype(np.float64),
            nis_used=np.bincount(owner[used], minlength=count),
            skipped=np.bincount(owner[joined("skipped", np.zeros(0, bool))], minlength=count),
        )


def _rows_of(indexes: Sequence[rr.TimeColumnLike]) -> int:
    return len(indexes[0].as_arrow_array()) if indexes else 0


@dataclass(frozen=True, slots=True)
class _FirstRow:
    """A component of one row followed by ``rows - 1`` rows without it (nulls): the
    SDK's ``ComponentColumn`` has no missing rows."""

    descriptor: rr.ComponentDescriptor
    values: pa.Array
    rows: int

    def component_descriptor(self) -> rr.ComponentDescriptor:
        return self.descriptor

    def as_arrow_array(self) -> pa.Array:
        offsets = np.full(self.rows + 1, len(self.values), dtype=np.int32)
        offsets[0] = 0
        mask = np.ones(self.rows, dtype=bool)
        mask[0] = False
        return pa.ListArray.from_arrays(pa.array(offsets), self.values, mask=pa.array(mask))


def _first_row_only(styling: rr.AsComponents, rows: int) -> list[_FirstRow]:
    """The components of ``styling`` as columns of ``rows`` rows, set in the first only."""
    return [
        _FirstRow(batch.component_descriptor(), batch.as_arrow_array(), rows)
        for batch in styling.as_component_batches()
    ]


class _Entities:
    """The recording stream with every entity path under ``prefix`` (none when empty),
    so that several runs can share one recording (``variants/<key>/world/...``)."""

    def __init__(self, rec: rr.RecordingStream, prefix: str) -> None:
        self.rec = rec
        self._prefix = prefix.strip("/") + "/" if prefix.strip("/") else ""
        self._styles: dict[str, tuple[rr.AsComponents, ...]] = {}  # path -> styling unsent
        self.sent: set[str] = set()  # the entities (without the prefix) given data so far

    def path(self, entity: str) -> str:
        return self._prefix + entity

    def style(self, entity: str, *styling: rr.AsComponents) -> None:
        """Styling of an entity that gets data over time, sent with its first row.

        A static chunk of its own would cost some 1.5 kB of schema and index for a few
        bytes of colours; in the first row of the entity's data it is a column more. It
        holds from the entity's first row on (nothing is drawn before it) and is sent
        static by :meth:`send_styles` if the entity never gets data.
        """
        self._styles[self.path(entity)] = styling

    def send_styles(self) -> None:
        """Send as static data the styling of every entity that has had no data yet."""
        for path, styling in self._styles.items():
            self.rec.log(path, *styling, static=True)
        self._styles.clear()

    def log(self, entity: str, data: Any, *, static: bool = False) -> None:
        self.sent.add(entity)
        path = self.path(entity)
        styling = self._styles.pop(path, ())
        self.rec.log(path, data, *styling, static=static)

    def send_columns(self, entity: str, indexes: Sequence[rr.TimeColumnLike], columns: Any) -> None:
        self.sent.add(entity)
        path = self.path(entity)
        styling = self._styles.pop(path, ())
        if styling:
            rows = _rows_of(indexes)
            columns = [*columns, *(c for s in styling for c in _first_row_only(s, rows))]
        self.rec.send_columns(path, indexes=indexes, columns=columns)

    def set_time(self, timeline: str, *, sequence: int) -> None:
        self.rec.set_time(timeline, sequence=sequence)

    def send_blueprint(self, blueprint: rrb.Blueprint) -> None:
        self.rec.send_blueprint(blueprint)

    def flush(self, *, timeout_sec: float) -> None:
        flush_interruptibly(self.rec, timeout_sec)


class _SeriesBuffer:
    """Scalar series gathered per entity path and sent with ``send_columns`` in chunks."""

    def __init__(self, rec: _Entities, clock: _Clock) -> None:
        self._rec = rec
        self._clock = clock
        self._series: dict[str, tuple[list[int], list[int], list[float], list[float]]] = {}

    def add(self, path: str, step: int, event: int, value: float, time: float | None) -> None:
        steps, events, values, times = self._series.setdefault(path, ([], [], [], []))
        steps.append(step)
        events.append(event)
        values.append(value)
        times.append(math.nan if time is None else time)

    def flush(self) -> None:
        for path, (steps, events, values, times) in self._series.items():
            if values:
                at = np.arange(len(values))
                if path.endswith((style.LOWER, style.UPPER)):  # constant along long runs
                    at = _run_ends(np.array(values))
                rows = self._clock.rows(np.array(steps), np.array(events), times)
                self._rec.send_columns(
                    path,
                    indexes=rows.pick(at),
                    columns=_scalars(np.array(values)[at]),
                )
        self._series.clear()


class _Clock:
    """The ``time`` timeline of a recording: its type, and times for records without one.

    A record without a time (an untimed line of an extended log, ...) takes the latest
    time before it, or the first after it in the same send; a recording without any
    time has no ``time`` timeline.
    """

    def __init__(self) -> None:
        self.epoch: bool | None = None  # decided by the first time met
        self.last: float | None = None
        self.span: tuple[float, float] | None = None

    def rows(self, steps: IntArray, events: IntArray, times: Sequence[float] | FloatArray) -> _Rows:
        filled = self.fill(np.asarray(times, dtype=np.float64))
        return _Rows(steps, events, filled, bool(self.epoch))

    def fill(self, times: FloatArray) -> FloatArray | None:
        known = np.isfinite(times)
        if not known.any():
            if self.last is None:
                return None
            return np.full(len(times), self.last)
        if self.epoch is None:
            self.epoch = time_is_epoch(float(times[known][0]))
        if not known.all():
            # carry the latest time forward; before the first, the first of this send
            index = np.where(known, np.arange(len(times)), -1)
            np.maximum.accumulate(index, out=index)
            start = self.last if self.last is not None else float(times[known][0])
            times = np.where(index >= 0, times[np.maximum(index, 0)], start)
        self.last = max(float(times[-1]), self.last if self.last is not None else -math.inf)
        low, high = float(times.min()), float(times.max())
        self.span = (low, high) if self.span is None else (
            min(low, self.span[0]), max(high, self.span[1])
        )  # fmt: skip
        return times


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
        see :func:`ekfviz.viz.association.log_reference`): the layout has its plot
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        *,
        truth: GroundTruth | None = None,
        landmark_ids: Sequence[int] | None = None,
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
    ) -> None:
        self._rec = _Entities(rec, prefix)
        self._gps_reference = gps_reference
        self._sensor = sensor if sensor is not None else RangeBearing()
        self.association: AssociationView | None = None  # made at the first scan
        # id-less scans: a new landmark's first-sighting outline (mean, covariance), held
        # until the association confirms it (drawn then) or removes it (dropped)
        self._first_sightings: dict[int, tuple[FloatArray, FloatArray]] = {}
        self._last_true_step = 0  # the step of the last true pose logged
        self._history = history
        self._correlation = CorrelationCadence()  # of the array API (a replay's records own)
        self._last_correlation: Correlation | None = None  # the last one logged
        self._detail = detail
        self._truth = truth
        self._heading_length = heading_length
        self._order: list[int] = [int(i) for i in landmark_ids] if landmark_ids else []
        self._in_order: set[int] = set(self._order)
        self._seen: set[int] = set()  # ids observed so far through the array API
        self._seen_ids: set[int] = set()  # every landmark id in the map so far (for the layout)
        # labels below the outlines, not in the small maps of a sweep (prefix) nor in a
        # large map, where they would cover it (the viewer shows a label on hover)
        self._labels_off = bool(prefix.strip("/"))
        # landmark classes (see _annotate): ids 0.._class_top and _class_extra are logged
        self._class_top = -1
        self._class_extra: set[int] = set()
        self._class_pending: set[int] = set()
        self._class_count = 0
        self._clock = _Clock()
        self._series = _SeriesBuffer(self._rec, self._clock)
        self._thinning = PredictThinning(None if detail else predict_interval_s)
        # records not sent yet, each with whether it logs the whole map's ellipses
        self._pending: list[tuple[EventRecord, bool]] = []
        self._pending_landmarks = 0
        self._map_step: int | None = None  # step of the last update that logged the whole map
        self._map_time: float | None = None  # and its time
        self._last_update: tuple[EventRecord, bool] | None = None
        # the small map as last logged: its ids and _shapes rows, and at which event
        self._map_shown: tuple[IntArray, FloatArray] | None = None
        self._map_shown_event: int | None = None
        self._final_event: int | None = None  # the last update's, at finish: shown exactly
        self._last_ids: IntArray | None = None  # landmark ids of the last update, annotated
        self._event = 0
        self._step = 0
        self._step_has_update = True  # the initialisation counts as step 0's update
        self._last_xy: FloatArray | None = None
        self._last_true_xy: FloatArray | None = None  # (1, 2) the true path's last point
        self._checked_step: int | None = None  # of the last covariance check (array API)
        self._round_off_said = False  # a round-off asymmetry of P is a warning once a run
        self._blueprint = blueprint
        self._run_documents = run_documents
        self._bounds_xy: FloatArray | None = None  # [[x_min, y_min], [x_max, y_max]] so far
        # NIS, NEES: (largest value, largest 95% upper bound) so far, to fit their axes
        self._extents: dict[str, tuple[float, float]] = {}
        if blueprint and live_layout:
            self._rec.send_blueprint(self._layout())
        if not prefix.strip("/") and not run_documents:  # a filter of the user's own
            properties = rr.AnyValues()
            properties.with_component_from_data("version", __version__)
            properties.with_component_from_data("kind", "recorder")
            rec.send_property("ekfviz", properties)
        self._log_styling()
        log_correlation_styling(self._rec)
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
        self._checked_step = None
        self.log_record(
            self._correlated(snapshot(
                x, P, event=0, step=0, kind=EventKind.INIT, line=line,
                landmark_ids=self._state_ids(x), observations=observations,
                **self._check(P, 0),
            ), P)
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
                **self._check(P, self._step + 1),
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
            self._correlated(snapshot(
                x, P, event=self._event + 1, step=step, kind=EventKind.UPDATE, line=line,
                landmark_ids=self._state_ids(x), observations=observations,
                **self._check(P, step),
            ), P)
        )  # fmt: skip

    def finish(self, evaluation: Evaluation | None = None) -> None:
        """Send the buffered data, the whole map at the last update, the evaluation document
        if given, the layout framing the whole run, and flush."""
        for record in self._thinning.drain():
            self._log_record(record)
        if self._last_update is not None:  # its map exactly, in the same send if pending
            self._final_event = self._last_update[0].event
        self._send_pending()
        if self._class_pending:
            self._log_classes()
        if self._last_update is not None and not self._last_update[1]:
            record = self._last_update[0]
            self._last_update = (record, True)
            if self._map_shown_event != record.event:  # its points too, exactly
                end = self._clock.rows(
                    np.array([record.step]),
                    np.array([record.event]),
                    [math.nan if record.time is None else record.time],
                )
                self._send_landmarks(end.all, [record])
                self._map_shown_event = record.event
            self._log_landmark_errors(record, None)
            rows = self._clock.rows(
                np.array([record.step]),
                np.array([record.event]),
                [math.nan if record.time is None else record.time],
            )
            self._send_ellipses(
                style.LANDMARK_ELLIPSES, rows, [(0, record, _landmark_rows(record, None))]
            )
        elif self._last_update is not None and self._map_shown_event != self._last_update[0].event:
            record = self._last_update[0]  # the end exactly, not within MAP_TOLERANCE
            rows = self._clock.rows(
                np.array([record.step]),
                np.array([record.event]),
                [math.nan if record.time is None else record.time],
            )
            self._send_landmarks(rows.all, [record])
            self._send_ellipses(
                style.LANDMARK_ELLIPSES, rows, [(0, record, _landmark_rows(record, None))]
            )
            self._map_shown_event = record.event
        if self._last_update is not None and self._last_update[0].n_landmarks:
            last = self._last_update[0]  # frame the final map's ellipses, not only its points
            self._grow_bounds(ellipse_extent(last.landmarks_xy, last.landmark_covs))
        self._series.flush()
        if self.association is not None:
            self.association.flush()
        if evaluation is not None:
            self._rec.log(
                style.RUN_EVALUATION,
                rr.TextDocument(evaluation.to_markdown(), media_type=rr.MediaType.MARKDOWN),
                static=True,
            )
        self._rec.send_styles()
        if self._blueprint:
            self._rec.send_blueprint(self._layout(self._bounds_xy, final=True))
        self._rec.flush(timeout_sec=FLUSH_TIMEOUT_S)

    def note(self, text: str, level: str | rr.TextLogLevel = rr.TextLogLevel.WARN) -> None:
        """A line in the text log at the latest event: a warning, or why a run stopped."""
        for record in self._thinning.drain():
            self._log_record(record)
        self._send_pending()
        self._rec.set_time(style.STEP, sequence=self._step)
        self._rec.set_time(style.EVENT, sequence=self._event)
        self._set_time(self._clock.last)
        self._rec.log(style.LOG, rr.TextLog(text, level=level))

    def _set_time(self, time: float | None) -> None:
        """Set the ``time`` timeline of the stream's next ``log`` calls, if there is one."""
        if time is None:
            return
        if self._clock.epoch is None:
            self._clock.epoch = time_is_epoch(time)
        if self._clock.epoch:
            self._rec.rec.set_time(style.TIME, timestamp=time)
        else:
            self._rec.rec.set_time(style.TIME, duration=time)

    def _layout(self, bounds_xy: FloatArray | None = None, *, final: bool = False) -> rrb.Blueprint:
        if bounds_xy is not None:
            margin = 0.05 * max(float(np.max(bounds_xy[1] - bounds_xy[0])), 1.0)
            bounds_xy = bounds_xy + np.array([[-margin], [margin]])
        return default_blueprint(
            has=self.entities_with_data if final else None,
            value_ranges={
                path: (0.0, 1.08 * max(1.15 * bound, top))
                for path, (top, bound) in self._extents.items()
            },
            landmark_ids=sorted(self._seen_ids) if self._truth is not None else (),
            has_truth=self._truth is not None,
            has_true_poses=self._truth is not None and self._truth.has_poses,
            has_run_info=self._run_documents,
            bounds_xy=bounds_xy,
            has_time=self._clock.span is not None,
            history=self._history,
        )

    # -- records -------------------------------------------------------------------------

    @property
    def entities_with_data(self) -> frozenset[str]:
        """The entity paths (without the prefix) given data so far, and the GPS
        reference's series if one is to come."""
        has = set(self._rec.sent)
        if self.association is not None:  # it logs through the stream itself
            has |= {f"{ASSOCIATION_SERIES}/matched", style.LOG}
        if self._gps_reference:
            has |= {f"{REFERENCE_SERIES}/gps_error", f"{REFERENCE_SERIES}/gps_rmse"}
        return frozenset(has)

    @property
    def time_span(self) -> tuple[float, float] | None:
        """The first and last log time (seconds) logged, or None for an untimed run."""
        return self._clock.span

    @property
    def time_is_epoch(self) -> bool:
        """Whether the ``time`` timeline is a timestamp (else a duration)."""
        return bool(self._clock.epoch)

    def log_record(self, record: EventRecord) -> None:
        """Log one record of the core: the map, the metrics and a line of text (the
        predicts of a timestamped log thinned, see :mod:`ekfviz.viz.thinning`)."""
        for admitted in self._thinning.admit(record):
            self._log_record(admitted)

    def _log_record(self, record: EventRecord) -> None:
        self._event, self._step = record.event, record.step
        self._step_has_update = record.kind is not EventKind.PREDICT
        whole_map = False
        if record.kind is not EventKind.PREDICT:
            ids = record.landmark_ids
            # the core's records share one ids array until the map grows
            if ids is not self._last_ids and (
                self._last_ids is None or not np.array_equal(ids, self._last_ids)
            ):
                self._annotate(ids)
                self._last_ids = ids
                self._seen_ids.update(ids.tolist())
            whole_map = (
                not self._sparse_map(record)
                or self._map_step is None
                or (
                    record.time - self._map_time >= MAP_EVERY_S
                    if record.time is not None and self._map_time is not None
                    else record.step - self._map_step >= MAP_EVERY_STEPS
                )
            )
            if whole_map:
                self._map_step = record.step
                self._map_time = record.time
            self._last_update = (record, whole_map)
        if record.association is not None:
            if self.association is None:  # association ids are not the truth's ids
                self.association = AssociationView(
                    self._rec.rec, self._rec.path, self._sensor, self._truth
                )
            self.association.log(record)
        if self._truth is not None:
            self._log_metrics(record, whole_map)
        if record.correlation is not None:  # a few per run: logged at once
            self._rec.set_time(style.STEP, sequence=record.step)
            self._rec.set_time(style.EVENT, sequence=record.event)
            self._set_time(record.time)
            log_correlation(self._rec, record.correlation, self._last_correlation)
            self._last_correlation = record.correlation
        self._pending.append((record, whole_map))
        self._pending_landmarks += len(record.landmark_ids)
        if len(self._pending) >= FLUSH_EVERY or self._pending_landmarks >= FLUSH_LANDMARKS:
            self._send_pending()
            self._series.flush()

    def _send_pending(self) -> None:
        """Send the buffered records: one column per entity (see the module for what)."""
        pending = self._pending
        if not pending:
            return
        self._pending = []
        self._pending_landmarks = 0
        records = [record for record, _ in pending]
        count = len(records)
        rows = self._clock.rows(
            np.fromiter((record.step for record in records), np.int64, count),
            np.fromiter((record.event for record in records), np.int64, count),
            np.fromiter(
                (math.nan if record.time is None else record.time for record in records),
                np.float64,
                count,
            ),
        )
        poses = np.stack([record.pose for record in records])
        pose_covs = np.stack([record.pose_cov for record in records])
        is_predict = np.fromiter(
            (record.kind is EventKind.PREDICT for record in records), bool, count
        )
        corrected = np.flatnonzero(~is_predict)
        observed = _Observed.of(records, corrected)

        # the robot frame: the robot's point and heading are static in it, its ellipses
        # change shape there only slowly (see _pose_ellipses)
        self._send(style.ROBOT, rows.all, [_positions(poses), *_robot_frame(poses)])
        if self._truth is not None and self._truth.has_poses:
            self._send_true_path(rows, records, corrected, self._truth)
        paths = {k: r.path_xytheta for k, r in enumerate(records) if r.path_xytheta is not None}
        self._send_trajectory(rows, poses[:, :2], corrected, paths)
        for path, history, picked in (
            (style.POSE_PREDICTED, style.POSE_PREDICTED_HISTORY, np.flatnonzero(is_predict)),
            (style.POSE_UPDATED, style.POSE_UPDATED_HISTORY, corrected),
        ):
            self._send_pose_ellipses(path, rows, picked, poses, pose_covs)
            if self._history and picked.size:  # outlines in the world, to accumulate
                outlines = ellipse_outlines(poses[picked, :2], pose_covs[picked, :2, :2])
                self._send_strips(history, rows, picked, outlines)
        self._send_rays(rows, observed)

        sigma = np.sqrt(np.diagonal(pose_covs, axis1=1, axis2=2))
        if corrected.size:  # x, y, theta: three series of one entity, a row a step
            self._send(
                style.POSE_SIGMA,
                rows.pick(corrected),
                [
                    _column(
                        rr.Scalars.descriptor_scalars(),
                        pa.array(sigma[corrected].reshape(-1)),
                        np.full(corrected.size, 3, dtype=np.int64),
                    )
                ],
            )
        with_nis = np.flatnonzero(observed.nis_used)
        if with_nis.size:  # with the chi-square bounds of 2 dof per landmark used
            used, which = np.unique(observed.nis_used[with_nis], return_inverse=True)
            bounds = np.array([chi2_bounds(2 * int(n)) for n in used])[which]
            self._send(style.NIS, rows.pick(with_nis), _scalars(observed.nis_sum[with_nis]))
            self._extent(
                style.NIS, float(observed.nis_sum[with_nis].max()), float(bounds[:, 1].max())
            )
            ends = _run_ends(bounds[:, 0])
            at = rows.pick(with_nis[ends])
            for path, values in (
                (f"{style.NIS}/{style.LOWER}", bounds[ends, 0]),
                (f"{style.NIS}/{style.UPPER}", bounds[ends, 1]),
            ):
                self._send(path, at, _scalars(values))

        if corrected.size:
            updates = [(k, records[k], pending[k][1]) for k in corrected.tolist()]
            shown = self._map_changes(updates)
            if shown:
                self._send_landmarks(
                    rows.pick([k for k, _, _ in shown]), [record for _, record, _ in shown]
                )
            self._send_ellipses(
                style.LANDMARK_ELLIPSES,
                rows,
                [(k, record, _landmark_rows(record, None)) for k, record, whole in shown if whole],
            )
            # Beyond a small map: the observed landmarks' own ellipses at the updates between
            # two of the whole map's (and an empty row, clearing them, at those).
            self._send_ellipses(
                style.LANDMARK_ELLIPSES_OBSERVED,
                rows,
                [
                    (k, record, _NO_ROWS if whole else _landmark_rows(record, "observed"))
                    for k, record, whole in updates
                    if self._sparse_map(record)
                ],
            )
            self._send_ellipses(
                style.LANDMARK_INITIAL,
                rows,
                [
                    (k, record, _landmark_rows(record, "initialised"))
                    for k, record, _ in updates
                    if observed.new[k] and record.association is None
                ],
            )
            self._send_confirmed_first_sightings(rows, updates)
        self._send_health(records, rows, pose_covs, corrected, observed)
        self._send_text(records, rows, observed)

    def _send_pose_ellipses(
        self, path: str, rows: _Rows, picked: IntArray, poses: FloatArray, pose_covs: FloatArray
    ) -> None:
        """The 3-sigma ellipses of the position at the rows ``picked``: the map of the
        static unit circle onto each, in the robot frame, A = R(theta)^T 3 V sqrt(L)
        (36 bytes an event instead of an outline's 256)."""
        if not picked.size:
            return
        world = ellipse_axes(np.zeros((len(picked), 2)), pose_covs[picked, :2, :2])[:, :4]
        cos_t, sin_t = np.cos(poses[picked, 2]), np.sin(poses[picked, 2])
        rotation_t = np.stack(
            [np.column_stack([cos_t, sin_t]), np.column_stack([-sin_t, cos_t])], axis=1
        )
        axes = rotation_t @ world.reshape(-1, 2, 2)
        self._send(
            path,
            rows.pick(picked),
            [_column(rr.Transform3D.descriptor_mat3x3(), _shape_matrices(axes))],
        )

    def _sparse_map(self, record: EventRecord) -> bool:
        """Whether an update logs the whole map's ellipses only now and then (and the
        observed landmarks' at every update): beyond ``SMALL_MAP`` landmarks, and in a
        timestamped log whose predicts are thinned (see :mod:`ekfviz.viz.thinning`)."""
        if self._detail:
            return False
        return record.n_landmarks > SMALL_MAP or (
            record.time is not None and self._thinning.interval_s is not None
        )

    def _map_changes(
        self, updates: list[tuple[int, EventRecord, bool]]
    ) -> list[tuple[int, EventRecord, bool]]:
        """The updates whose landmarks (points and whole-map ellipses) are logged.

        Only where the map grew or where some landmark's point or 3-sigma outline moved
        by more than ``MAP_TOLERANCE`` of its ellipse's semi-major axis since it was last
        logged: in between the viewer shows the latest, within that tolerance of the true
        state. A large map's points so (its ellipses have their own cadence, and the
        updates that log them log the points too); everything at every update with
        ``--detail``.
        """
        shown: list[tuple[int, EventRecord, bool]] = []
        for k, record, whole in updates:
            if self._detail:
                shown.append((k, record, whole))
                self._map_shown = None
                self._map_shown_event = record.event
                continue
            shape = _shapes(record.landmarks_xy, record.landmark_covs)
            if (
                self._map_shown is not None
                and record.event != self._final_event
                and not (whole and self._sparse_map(record))
                and np.array_equal(self._map_shown[0], record.landmark_ids)
            ):
                before = self._map_shown[1]
                # the point at angle t of an outline, m + 3 sqrt(C) [cos t, sin t], moves by
                # at most |dm| + 3 ||d sqrt(C)||_F; the semi-major axis is at least
                # 3 ||sqrt(C)||_F / sqrt(2)
                moved = np.linalg.norm(shape[:, :2] - before[:, :2], axis=1) + np.linalg.norm(
                    shape[:, 2:] - before[:, 2:], axis=1
                )
                semi_major = np.linalg.norm(shape[:, 2:], axis=1) / math.sqrt(2.0)
                if np.all(moved <= MAP_TOLERANCE * semi_major):
                    continue
            self._map_shown = (record.landmark_ids, shape)
            self._map_shown_event = record.event
            shown.append((k, record, whole))
        return shown

    def _send_true_path(
        self, rows: _Rows, records: list[EventRecord], corrected: IntArray, truth: GroundTruth
    ) -> None:
        """The true pose of each step at its update (by step, or by time on a track), as
        a robot frame and a segment of the true path from the step before."""
        known = [
            (k, pose)
            for k in corrected.tolist()
            if (pose := truth.pose_of(records[k].step, records[k].time)) is not None
        ]
        if not known:
            return
        at = np.array([k for k, _ in known])
        poses = np.array([pose for _, pose in known])
        self._send(style.TRUTH_ROBOT, rows.pick(at), [_positions(poses), *_robot_frame(poses)])
        starts = np.vstack([poses[:1, :2] if self._last_true_xy is None else self._last_true_xy,
                            poses[:-1, :2]])  # fmt: skip
        segments = np.stack([starts, poses[:, :2]], axis=1)
        # an offline filter's final record spans the run: the true path of every step
        # between, beside its whole estimated path (see _send_trajectory)
        spans = {
            i: k
            for i, k in enumerate(at.tolist())
            if records[k].path_xytheta is not None and truth.poses_xytheta is not None
        }
        plain = np.array([i not in spans for i in range(len(at))], dtype=bool)
        self._send_strips(style.TRUTH_TRAJECTORY, rows, at[plain], segments[plain])
        for i, k in spans.items():
            first = records[known[i - 1][0]].step if i else self._last_true_step
            between = truth.poses_xytheta[first : records[k].step + 1, :2]  # type: ignore[index]
            self._send_strips(
                style.TRUTH_TRAJECTORY, rows, np.array([k], dtype=np.int64), between[None]
            )
        self._last_true_xy = poses[-1:, :2].copy()
        self._last_true_step = records[at[-1]].step

    def _send_trajectory(
        self,
        rows: _Rows,
        ends_xy: FloatArray,
        corrected: IntArray,
        paths: dict[int, FloatArray] | None = None,
    ) -> None:
        """The path since the last row, through the predicted positions, at every update
        and at the last event of a send: a row per step rather than per event.

        :param paths: rows whose record holds an offline filter's whole path (a
            smoother's, after ``finish()``): drawn there instead of a straight segment
        """
        count = len(rows)
        at = (
            corrected
            if corrected.size and corrected[-1] == count - 1
            else np.append(corrected, count - 1)
        )
        shift = 0 if self._last_xy is None else 1
        points_xy = ends_xy if self._last_xy is None else np.vstack([self._last_xy, ends_xy])
        ends = at + shift
        starts = np.concatenate([[0], ends[:-1]])
        drawn = ends > starts  # the very first event alone is no line yet
        if paths:
            drawn &= ~np.isin(at, list(paths))
        at, starts, ends = at[drawn], starts[drawn], ends[drawn]
        if at.size:
            lengths = ends - starts + 1
            index = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(
                int(lengths.sum())
            )
            offsets = pa.array(np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32))
            strips = pa.ListArray.from_arrays(offsets, _xy(points_xy[index]), type=_STRIP)
            self._send(
                style.TRAJECTORY,
                rows.pick(at),
                [_column(rr.LineStrips2D.descriptor_strips(), strips)],
            )
        for k, path in sorted((paths or {}).items()):
            at_k = np.array([k], dtype=np.int64)
            self._send_strips(style.TRAJECTORY, rows, at_k, path[None, :, :2])
            self._grow_bounds(path[:, :2])
        self._last_xy = ends_xy[-1].copy()
        self._grow_bounds(ends_xy)

    def _send_rays(self, rows: _Rows, observed: _Observed) -> None:
        """Arrows from the robot to where each observation puts its landmark, in the robot
        frame: r [cos b, sin b] (the robot frame supplies the origin), at the updates with
        observations.

        The layout shows them on the step and event timelines only at the cursor's own
        step or event (``blueprint.at_cursor``): nothing at a predict, no row needed to
        clear them there. The ``time`` timeline shows the latest instead, so a log with
        times gets an empty row at every other event, which clears them.
        """
        vectors = observed.z[:, 1:2] * np.column_stack(
            [np.cos(observed.z[:, 0]), np.sin(observed.z[:, 0])]
        )
        column = _column(rr.Arrows2D.descriptor_vectors(), _xy(vectors, _VECTOR), observed.seen)
        if rows.times is not None:
            self._send(style.OBSERVATIONS, rows.all, [column])
            return
        at = np.flatnonzero(observed.seen)
        if at.size:
            counts = observed.seen[at]
            self._send(
                style.OBSERVATIONS,
                rows.pick(at),
                [_column(rr.Arrows2D.descriptor_vectors(), _xy(vectors, _VECTOR), counts)],
            )

    def _send_text(self, records: list[EventRecord], rows: _Rows, observed: _Observed) -> None:
        """A line per step: a predict's goes into the line of the update that follows it in
        the same step, both at the update; then one per warning at the same event."""
        text: list[str] = []
        level: list[str] = []
        line_of: list[int] = []
        held: tuple[str, tuple[str, ...]] | None = None  # a predict's line and warnings
        count = len(records)
        for k, (record, seen, new, nis_sum, nis_used) in enumerate(
            zip(
                records,
                observed.seen.tolist(),
                observed.new.tolist(),
                observed.nis_sum.tolist(),
                observed.nis_used.tolist(),
                strict=True,
            )
        ):
            line = self._describe(record, seen, new, nis_sum, nis_used)
            if (
                record.kind is EventKind.PREDICT
                and k + 1 < count
                and records[k + 1].kind is EventKind.UPDATE
                and records[k + 1].step == record.step
            ):
                held = (line, record.warnings)
                continue
            warnings = record.warnings
            if held is not None:
                line = f"{held[0]}; {line.split(' ', 2)[2]}"  # "step N predict ...; update ..."
                warnings = held[1] + warnings
                held = None
            text.append(line)
            level.append(_INFO)
            line_of.append(k)
            for warning in warnings:
                text.append(f"step {record.step} line {record.line}: {warning}")
                level.append(_WARN)
                line_of.append(k)
        self._send(
            style.LOG,
            rows.pick(line_of),
            [
                _column(rr.TextLog.descriptor_text(), pa.array(text, pa.utf8())),
                _column(rr.TextLog.descriptor_level(), pa.array(level, pa.utf8())),
            ],
        )

    def _send_health(
        self,
        records: list[EventRecord],
        rows: _Rows,
        pose_covs: FloatArray,
        corrected: IntArray,
        observed: _Observed,
    ) -> None:
        """The numerical health series (see ``ekfviz.core.health``)."""
        if corrected.size:  # a predict adds Q: only an update can lose definiteness
            self._send(
                style.HEALTH_POSE_MIN_EIG,
                rows.pick(corrected),
                _scalars(pose_min_eigenvalues(pose_covs[corrected])),
            )
        with_map = [k for k in corrected.tolist() if records[k].n_landmarks]
        if with_map:
            counts = np.array([records[k].n_landmarks for k in with_map])
            eigenvalues = landmark_min_eigenvalues(
                np.concatenate([records[k].landmark_covs for k in with_map])
            )
            smallest = np.minimum.reduceat(eigenvalues, np.cumsum(counts) - counts)
            self._send(style.HEALTH_LANDMARK_MIN_EIG, rows.pick(with_map), _scalars(smallest))
        if observed.rows.size:
            skipped = observed.skipped[observed.rows]
            ends = _run_ends(skipped)
            self._send(
                style.HEALTH_SKIPPED, rows.pick(observed.rows[ends]), _scalars(skipped[ends])
            )
        checked = [
            (k, check)
            for k, record in enumerate(records)
            if (check := record.covariance) is not None
        ]
        if checked:
            self._send_checks(rows, checked)

    def _send_checks(self, rows: _Rows, checked: list[tuple[int, CovarianceCheck]]) -> None:
        """The checks of the whole covariance; a condition number only where P is definite."""
        at = rows.pick([k for k, _ in checked])
        for path, values in (
            (style.HEALTH_P_MIN_EIG, [check.min_eigenvalue for _, check in checked]),
            (style.HEALTH_P_ASYMMETRY, [check.asymmetry for _, check in checked]),
        ):
            self._send(path, at, _scalars(values))
        definite = [(k, check) for k, check in checked if math.isfinite(check.condition)]
        if definite:
            self._send(
                style.HEALTH_P_LOG10_CONDITION,
                rows.pick([k for k, _ in definite]),
                _scalars([math.log10(check.condition) for _, check in definite]),
            )

    def _send(
        self,
        entity: str,
        times: Sequence[rr.TimeColumnLike],
        columns: Sequence[rr.ComponentColumn],
    ) -> None:
        """Send one column batch on both timelines (``times``: see ``_Rows``)."""
        self._rec.send_columns(entity, indexes=times, columns=columns)

    def _identify(
        self, archetype: type[rr.Points2D] | type[rr.LineStrips2D], ids: IntArray, counts: IntArray
    ) -> rr.ComponentColumn:
        """Landmark ids as class ids (labelled by the annotation context), or as labels
        "L<id>" where an id does not fit a class id."""
        if self._has_class_ids(ids):
            return _column(
                archetype.descriptor_class_ids(), pa.array(ids.astype(np.uint16)), counts
            )
        return _column(
            archetype.descriptor_labels(), pa.array([f"L{i}" for i in ids.tolist()]), counts
        )

    def _send_landmarks(
        self, times: Sequence[rr.TimeColumnLike], updates: list[EventRecord]
    ) -> None:
        """All landmark estimates at every update, one batch each, class id = landmark id."""
        ids = np.concatenate([record.landmark_ids for record in updates])
        positions = np.concatenate([record.landmarks_xy for record in updates])
        counts = np.array([record.n_landmarks for record in updates])
        if len(positions):
            self._grow_bounds(positions)
        self._send(
            style.LANDMARKS,
            times,
            [
                _column(rr.Points2D.descriptor_positions(), _xy(positions), counts),
                self._identify(rr.Points2D, ids, counts),
            ],
        )
        # the labels just below each 3-sigma outline (y - 3 sigma_y, y up), clear of it; in a
        # large map they would cover it: there the viewer shows a landmark's label on hover
        if self._labels_off or max(record.n_landmarks for record in updates) > SMALL_MAP:
            if not self._labels_off:  # empty rows from here on: the labels are gone
                self._labels_off = True
                empty = np.zeros(len(updates), dtype=np.int64)
                self._send(
                    style.LANDMARK_LABELS,
                    times,
                    [_column(rr.Points2D.descriptor_positions(), _xy(np.zeros((0, 2))), empty)],
                )
            return
        sigma_y = np.sqrt(np.concatenate([record.landmark_covs[:, 1, 1] for record in updates]))
        below = positions - np.column_stack([np.zeros(len(positions)), 3.0 * sigma_y])
        if self._bounds_xy is not None and counts[-1] > 1:
            # labels of close landmarks stacked, not overprinted: the offsets that clear the
            # batch's last map, by landmark id, for all its rows (a map moves little within
            # a batch, and one pass per update would cost seconds on a long run)
            span = max(float(np.max(self._bounds_xy[1] - self._bounds_xy[0])), 1e-9)
            last = slice(len(below) - int(counts[-1]), len(below))
            offsets = unclutter(below[last], LABEL_WIDTH * span, LABEL_HEIGHT * span) - below[last]
            if offsets.any():
                last_ids = ids[last]
                order = np.argsort(last_ids)
                at = np.clip(np.searchsorted(last_ids[order], ids), 0, len(order) - 1)
                same = last_ids[order][at] == ids
                below[same] += offsets[order][at[same]]
        self._send(
            style.LANDMARK_LABELS,
            times,
            [
                _column(rr.Points2D.descriptor_positions(), _xy(below), counts),
                self._identify(rr.Points2D, ids, counts),
            ],
        )

    def _send_strips(
        self,
        entity: str,
        rows: _Rows,
        at: IntArray,
        polylines: FloatArray,
        counts: IntArray | None = None,
        ids: IntArray | None = None,
    ) -> None:
        """Line strips at the rows ``at`` (ascending): ``counts[i]`` of the ``polylines`` at
        ``at[i]`` (one each by default), with class id = ``ids`` if given.

        Sent in chunks of at most ``SHAPES_EVERY`` events, whatever the flush: ``rerun rrd
        verify`` takes a time in rows x points per chunk of line strips.
        """
        counts = np.ones(len(at), dtype=np.int64) if counts is None else counts
        ends = np.cumsum(counts)
        cuts = np.searchsorted(at, np.arange(SHAPES_EVERY, len(rows), SHAPES_EVERY))
        for lo, hi in itertools.pairwise([0, *cuts.tolist(), len(at)]):
            if lo == hi:
                continue
            first, last = (int(ends[lo - 1]) if lo else 0), int(ends[hi - 1])
            columns = [
                _column(
                    rr.LineStrips2D.descriptor_strips(),
                    _strips(polylines[first:last]),
                    counts[lo:hi],
                )
            ]
            if ids is not None:
                columns.append(self._identify(rr.LineStrips2D, ids[first:last], counts[lo:hi]))
            self._send(entity, rows.pick(at[lo:hi]), columns)

    def _send_ellipses(
        self, entity: str, rows: _Rows, batches: list[tuple[int, EventRecord, IntArray]]
    ) -> None:
        """3-sigma outlines of some landmarks of some updates, class id = landmark id.

        :param batches: per row to send, its index in ``rows``, the update and the rows of
            the landmarks to draw
        """
        if not batches:
            return
        counts = np.array([len(picked) for _, _, picked in batches])
        # one outline size per send, from the largest batch (see ellipses.outline_points)
        n_points = min(MAP_POINTS, outline_points(int(counts.max())))
        means, covs, ids = [], [], []
        for _, record, picked in batches:
            if len(picked) == record.n_landmarks:  # all of them: no copy
                means.append(record.landmarks_xy)
                covs.append(record.landmark_covs)
                ids.append(record.landmark_ids)
            else:
                means.append(record.landmarks_xy[picked])
                covs.append(record.landmark_covs[picked])
                ids.append(record.landmark_ids[picked])
        outlines = ellipse_outlines(np.concatenate(means), np.concatenate(covs), n_points=n_points)
        at = np.array([k for k, _, _ in batches], dtype=np.int64)
        self._send_strips(entity, rows, at, outlines, counts, np.concatenate(ids))

    def _send_confirmed_first_sightings(
        self, rows: _Rows, updates: list[tuple[int, EventRecord, bool]]
    ) -> None:
        """With id-less scans, the first-sighting outline of a landmark appears when the
        association confirms it: most new landmarks of a cluttered scan are removed
        again, and their outlines would bury the map (Victoria Park: 600 of 900)."""
        at, means, covs, ids = [], [], [], []
        for k, record, _ in updates:
            association = record.association
            if association is None:
                continue
            if record.observations is not None and record.observations.initialised.any():
                rows_new = _landmark_rows(record, "initialised")
                for row in rows_new.tolist():
                    self._first_sightings[int(record.landmark_ids[row])] = (
                        record.landmarks_xy[row].copy(),
                        record.landmark_covs[row].copy(),
                    )
            for landmark_id in association.removed.tolist():
                self._first_sightings.pop(int(landmark_id), None)
            confirmed = [
                (int(i), held)
                for i in association.confirmed.tolist()
                if (held := self._first_sightings.pop(int(i), None)) is not None
            ]
            if confirmed:
                at.append(k)
                ids.append([i for i, _ in confirmed])
                means += [mean for _, (mean, _) in confirmed]
                covs += [cov for _, (_, cov) in confirmed]
        if not at:
            return
        counts = np.array([len(group) for group in ids])
        n_points = min(MAP_POINTS, outline_points(int(counts.max())))
        outlines = ellipse_outlines(np.array(means), np.array(covs), n_points=n_points)
        self._send_strips(
            style.LANDMARK_INITIAL, rows, np.array(at, dtype=np.int64), outlines, counts,
            np.array([i for group in ids for i in group], dtype=np.int64),
        )  # fmt: skip

    def _grow_bounds(self, points_xy: FloatArray) -> None:
        box = np.stack([points_xy.min(axis=0), points_xy.max(axis=0)])
        if self._bounds_xy is not None:
            box = np.stack(
                [np.minimum(box[0], self._bounds_xy[0]), np.maximum(box[1], self._bounds_xy[1])]
            )
        self._bounds_xy = box

    def _log_metrics(self, record: EventRecord, whole_map: bool) -> None:
        """The series that need the truth; the others go by columns (_send_metrics)."""
        if self._truth is None or record.kind is EventKind.PREDICT:
            return
        nees = pose_nees(record, self._truth)
        if nees is not None:
            self._add_statistic(style.NEES, record, nees, chi2_bounds(3))
        self._log_landmark_errors(record, None if whole_map else "observed")

    def _log_landmark_errors(self, record: EventRecord, which: str | None) -> None:
        """Euclidean error and Mahalanobis distance of the landmarks (see _landmark_rows)."""
        if self._truth is None or self.association is not None:
            return
        rows = _landmark_rows(record, which)
        ids = record.landmark_ids[rows]
        euclidean, mahalanobis = landmark_errors(
            record.landmarks_xy[rows], record.landmark_covs[rows], self._truth.lookup(ids)
        )
        add = self._series.add
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

    def _add_statistic(
        self, path: str, record: EventRecord, value: float, bounds: tuple[float, float]
    ) -> None:
        """A NIS or NEES value with its chi-square bounds, drawn in the same plot."""
        at = (record.step, record.event)
        self._extent(path, value, bounds[1])
        self._series.add(path, *at, value, record.time)
        self._series.add(f"{path}/{style.LOWER}", *at, bounds[0], record.time)
        self._series.add(f"{path}/{style.UPPER}", *at, bounds[1], record.time)

    def _extent(self, path: str, value: float, upper: float) -> None:
        """Grow the largest value and 95% upper bound of a NIS or NEES series so far."""
        top, bound = self._extents.get(path, (0.0, 0.0))
        if math.isfinite(value):
            top = max(top, value)
        self._extents[path] = (top, max(bound, upper))

    @staticmethod
    def _describe(record: EventRecord, seen: int, new: int, nis: float, nis_used: int) -> str:
        """The log line of a record; for an update, ``seen`` observations of which ``new``
        first sightings, and the NIS summed over the ``nis_used`` landmarks it used."""
        where = f"step {record.step} {record.kind.value}"
        if record.line:
            where += f" line {record.line}"
        if record.kind is EventKind.PREDICT:
            if record.control is None:
                return where
            d, alpha = record.control.tolist()
            return f"{where}: d {d:.3f}, alpha {alpha:.4f}"
        if record.observations is None:
            return f"{where}: {record.n_landmarks} landmarks in the map"
        text = f"{where}: {seen} landmarks"
        if new:
            text += f" ({new} new)"
        if nis_used:
            text += f", NIS {nis:.2f}"
        return text

    # -- static data -----------------------------------------------------------------------

    def _log_styling(self) -> None:
        rec = self._rec
        for path, name in ((style.NIS, "NIS"), (style.NEES, "NEES")):
            rec.style(path, rr.SeriesLines(colors=style.STATISTIC_COLOR, names=name))
            for bound, label in ((style.LOWER, "95% lower"), (style.UPPER, "95% upper")):
                rec.style(
                    f"{path}/{bound}",
                    rr.SeriesLines(colors=style.BOUND_COLOR, names=label, widths=1.0),
                )
        rec.style(  # one entity, three series: one colour each, the unit in the name
            style.POSE_SIGMA,
            rr.SeriesLines(
                colors=list(style.POSE_SIGMA_COLORS.values()),
                names=[
                    f"{axis} ({'rad' if axis == 'theta' else 'm'})"
                    for axis in style.POSE_SIGMA_COLORS
                ],
            ),
        )
        for path, name in (
            (style.HEALTH_POSE_MIN_EIG, "pose block"),
            (style.HEALTH_LANDMARK_MIN_EIG, "landmark blocks"),
            (style.HEALTH_P_MIN_EIG, "whole P"),
            (style.HEALTH_P_ASYMMETRY, "max |P - P^T|"),
            (style.HEALTH_P_LOG10_CONDITION, "log10 cond(P)"),
            (style.HEALTH_SKIPPED, "skipped observations"),
        ):
            rec.style(path, rr.SeriesLines(names=name))
        if self._truth is not None:
            for root in (style.LANDMARK_ERROR_SUMMARY, style.MAHALANOBIS_SUMMARY):
                for which, color in style.SUMMARY_COLORS.items():
                    rec.style(
                        f"{root}/{which}",
                        rr.SeriesLines(colors=color, names=f"{which} landmark", widths=2.0),
                    )
        # A 2-D view draws y down; mirroring "world" in the root frame shows the map y up
        # as in the classic plots, while every entity keeps its true world coordinates.
        rec.log(style.WORLD, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        line = _radius(style.LINE_RADIUS_UI)
        rec.style(
            style.ROBOT,
            rr.Points2D.from_fields(
                colors=style.ROBOT_COLOR,
                radii=_radius(style.ROBOT_RADIUS_UI),
                draw_order=40.0,
            ),
            _in_parent_frame(self._rec.path(style.ROBOT)),  # see _robot_frame
        )
        rec.log(
            style.HEADING,
            rr.Arrows2D(
                origins=[[0.0, 0.0]],
                vectors=[[self._heading_length, 0.0]],
                colors=style.ROBOT_COLOR,
                radii=line,
                draw_order=40.0,
            ),
            static=True,
        )
        rec.style(
            style.TRAJECTORY,
            rr.LineStrips2D.from_fields(colors=style.TRAJECTORY_COLOR, radii=line, draw_order=10.0),
        )
        for path, color in (
            (style.POSE_PREDICTED, style.PREDICTED_COLOR),
            (style.POSE_UPDATED, style.UPDATED_COLOR),
        ):
            # one unit circle, drawn through each event's transform (see _affine_columns):
            # a sixth of the bytes of an outline per event
            rec.style(
                path,
                rr.LineStrips2D(
                    [unit_circle()], colors=color, radii=line, show_labels=False, draw_order=20.0
                ),
            )
        history = (
            ((style.POSE_PREDICTED_HISTORY, style.PREDICTED_COLOR),
             (style.POSE_UPDATED_HISTORY, style.UPDATED_COLOR))
            if self._history
            else ()
        )  # fmt: skip
        thin = _radius(style.THIN_LINE_RADIUS_UI)
        for path, color, radii, order in (
            *((path, color, line, 20.0) for path, color in history),
            (style.LANDMARK_ELLIPSES, style.LANDMARK_COLOR, line, 20.0),
            (style.LANDMARK_ELLIPSES_OBSERVED, style.LANDMARK_COLOR, line, 20.0),
            # the first-sighting outlines thin and beneath the current ones: on real data
            # (MRCLAM) they are metres wide and would hide the map as it is now
            (style.LANDMARK_INITIAL, style.INITIAL_COLOR, thin, 15.0),
        ):
            rec.style(
                path,
                rr.LineStrips2D.from_fields(
                    colors=color, radii=radii, show_labels=False, draw_order=order
                ),
            )
        rec.log(  # static: shown by a range at the cursor (see _send_rays), which would
            # not reach a first row holding it
            style.OBSERVATIONS,
            rr.Arrows2D.from_fields(
                colors=style.OBSERVATION_COLOR,
                radii=_radius(style.THIN_LINE_RADIUS_UI),
                draw_order=15.0,
            ),
            static=True,
        )
        rec.style(
            style.LANDMARKS,
            rr.Points2D.from_fields(
                colors=style.LANDMARK_COLOR,
                radii=_radius(style.POINT_RADIUS_UI),
                show_labels=False,
                draw_order=30.0,
            ),
        )
        rec.style(
            style.LANDMARK_LABELS,
            rr.Points2D.from_fields(
                colors=style.LANDMARK_COLOR,
                radii=_radius(style.LABEL_ANCHOR_RADIUS_UI),
                show_labels=True,
                draw_order=31.0,
            ),
        )
        rec.style(
            style.TRUTH_LANDMARKS,
            rr.Points2D.from_fields(
                colors=style.TRUTH_COLOR,
                radii=_radius(style.TRUTH_RADIUS_UI),
                show_labels=False,
                draw_order=35.0,
            ),
        )

    def _log_truth(self, truth: GroundTruth) -> None:
        if truth.has_poses:  # the true robot (a grey point) and path
            self._rec.style(
                style.TRUTH_ROBOT,
                rr.Points2D.from_fields(
                    colors=style.TRUTH_PATH_COLOR,
                    radii=_radius(style.TRUTH_RADIUS_UI),
                    draw_order=36.0,
                ),
                _in_parent_frame(self._rec.path(style.TRUTH_ROBOT)),  # see _robot_frame
            )
            self._rec.style(
                style.TRUTH_TRAJECTORY,
                rr.LineStrips2D.from_fields(
                    colors=style.TRUTH_PATH_COLOR,
                    radii=_radius(style.THIN_LINE_RADIUS_UI),
                    draw_order=5.0,
                ),
            )
        class_ids = truth.ids if self._has_class_ids(truth.ids) else None
        self._rec.log(  # with its styling: one static chunk
            style.TRUTH_LANDMARKS, rr.Points2D(truth.landmarks_xy, class_ids=class_ids), static=True
        )

    def _annotate(self, ids: IntArray) -> None:
        """Give every landmark id a class with its label "L<id>", re-logging the (static)
        context rarely: it costs some 25 us per class.

        Ids usually number the landmarks 1..N in some order: the context then covers all
        ids from 0 to a power of two above the largest, re-logged when an id passes it
        (O(log N) times). Ids far sparser than that get their own classes, re-logged
        whenever their number has doubled and at ``finish``: while streaming a few labels
        may show late, none is missing from the recording.
        """
        new = {i for i in ids.tolist() if self._class_top < i <= MAX_CLASS_ID}
        new -= self._class_extra | self._class_pending
        if not new:
            return
        self._class_pending |= new
        self._class_count = max(self._class_count, len(ids))  # the map's size: distinct ids
        top = max(self._class_pending)
        if top <= 2 * self._class_count + 64:
            self._class_top = min(MAX_CLASS_ID, (1 << top.bit_length()) - 1 if top else 1)
            self._class_extra = {i for i in self._class_extra if i > self._class_top}
            self._class_pending.clear()
            self._log_classes()
        elif len(self._class_pending) >= max(16, len(self._class_extra)):
            self._log_classes()

    def _log_classes(self) -> None:
        self._class_extra |= self._class_pending
        self._class_pending.clear()
        classes = [*range(self._class_top + 1), *sorted(self._class_extra)]
        self._rec.log(
            style.WORLD,
            rr.AnnotationContext([(i, f"L{i}") for i in classes]),
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

    def _correlated(self, record: EventRecord, P: FloatArray) -> EventRecord:
        """The record with the correlation matrix of ``P`` where it is due."""
        if self._correlation.due(record.step, record.n_landmarks, last=False):
            return replace(record, correlation=correlation_of(P, record.landmark_ids))
        return record

    def _check(self, P: FloatArray, step: int) -> dict[str, Any]:
        """The check of a whole covariance handed in through the array API: at every call
        while it is small (``CHECK_ALL_DIM``), else as often as a replay checks its own."""
        P = np.asarray(P, dtype=np.float64)
        dim = P.shape[0]
        if (
            dim > CHECK_ALL_DIM
            and self._checked_step is not None
            and step - self._checked_step < check_interval(dim)
        ):
            return {}
        self._checked_step = step
        check = check_covariance(P)
        problems = check.problems(round_off=not self._round_off_said)
        self._round_off_said |= check.round_off_asymmetry
        return {"covariance": check, "warnings": tuple(problems)}

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
            initialised=initialised, skipped=np.zeros(m, dtype=bool),
        )  # fmt: skip
