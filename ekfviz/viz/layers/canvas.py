"""What the parts of the picture share: the stream under its prefix, the clock of the
``time`` timeline, the buffered scalar series, the map's bounds, and the batch of
records every part draws from (:class:`Batch`, the one columnar buffer)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr
import rerun.blueprint as rrb

from ekfviz.core.records import EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.axes import SeriesExtent
from ekfviz.viz.flush import flush_interruptibly
from ekfviz.viz.layers.arrow import (
    column,
    first_row_only,
    rows_of,
    run_ends,
    scalars,
    strips,
    time_is_epoch,
    times_of,
)
from ekfviz.viz.legend import FIRST_KIND_CLASS

SHAPES_EVERY = 256  # line strips in chunks of at most this many events (Canvas.send_strips)
# the largest landmark class id (Rerun's are u16; the kinds of marks take the top ones)
MAX_CLASS_ID = FIRST_KIND_CLASS - 1
NO_ROWS: IntArray = np.zeros(0, dtype=np.int64)


class Rows:
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
        self.all = times_of(steps, events, times, epoch)  # most sends have a row per record

    def __len__(self) -> int:
        return len(self.steps)

    def pick(self, rows: Sequence[int] | IntArray) -> list[rr.TimeColumnLike]:
        index = np.asarray(rows, dtype=np.int64)
        times = None if self.times is None else self.times[index]
        return times_of(self.steps[index], self.events[index], times, self.epoch)


class Clock:
    """The ``time`` timeline of a recording: its type, and times for records without one.

    A record without a time (an untimed line of an extended log, ...) takes the latest
    time before it, or the first after it in the same send; a recording without any
    time has no ``time`` timeline.
    """

    def __init__(self) -> None:
        self.epoch: bool | None = None  # decided by the first time met
        self.last: float | None = None
        self.span: tuple[float, float] | None = None

    def rows(self, steps: IntArray, events: IntArray, times: Sequence[float] | FloatArray) -> Rows:
        filled = self.fill(np.asarray(times, dtype=np.float64))
        return Rows(steps, events, filled, bool(self.epoch))

    def row(self, record: EventRecord) -> Rows:
        """The rows of one record."""
        time = math.nan if record.time is None else record.time
        return self.rows(np.array([record.step]), np.array([record.event]), [time])

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


def as_points(styling: tuple[rr.AsComponents, ...]) -> tuple[rr.AsComponents, ...]:
    """``styling`` with its series' lines as points (see :meth:`Entities.style`)."""
    return tuple(_points(s) if isinstance(s, rr.SeriesLines) else s for s in styling)


def _points(lines: rr.SeriesLines) -> rr.SeriesPoints:
    """The points of a series styled as ``lines``: its colours, names and visible series."""

    def values(batch: Any) -> Any:
        return None if batch is None else batch.as_arrow_array().to_pylist()

    colors = values(lines.colors)
    return rr.SeriesPoints(
        colors=None if colors is None else np.array(colors, dtype=np.uint32),  # packed RGBA
        names=values(lines.names),
        visible_series=values(lines.visible_series),
        marker_sizes=OFFLINE_MARKER_SIZE,
    )


OFFLINE_MARKER_SIZE = 4.0  # ui points: an offline run's two records, each a dot


class Entities:
    """The recording stream with every entity path under ``prefix`` (none when empty),
    so that several runs can share one recording (``variants/<key>/world/...``)."""

    def __init__(self, rec: rr.RecordingStream, prefix: str, *, points: bool = False) -> None:
        self.rec = rec
        self._prefix = prefix.strip("/") + "/" if prefix.strip("/") else ""
        self._styles: dict[str, tuple[rr.AsComponents, ...]] = {}  # path -> styling unsent
        self.points = points  # series drawn as points (see style())
        self.sent: set[str] = set()  # the entities (without the prefix) given data so far

    def path(self, entity: str) -> str:
        return self._prefix + entity

    @property
    def run_name(self) -> str:
        """The last part of the prefix (a compared filter's or a variant's name), or ""."""
        return self._prefix.rstrip("/").rpartition("/")[2]

    def style(self, entity: str, *styling: rr.AsComponents) -> None:
        """Styling of an entity that gets data over time, sent with its first row.

        A static chunk of its own would cost some 1.5 kB of schema and index for a few
        bytes of colours; in the first row of the entity's data it is a column more. It
        holds from the entity's first row on (nothing is drawn before it) and is sent
        static by :meth:`send_styles` if the entity never gets data.

        With ``points`` (an offline filter's run, whose records are its start and its
        optimum at the end), a series' lines are drawn as points of the same colours and
        names: a line between two records would look like a value at every step.
        """
        self._styles[self.path(entity)] = as_points(styling) if self.points else styling

    def series_as_points(self) -> None:
        """From now on, and for every styling not sent yet, series as points (see
        :meth:`style`): a replay learns that its filter is offline at its last record,
        the optimum after ``finish()`` (an update without observations), before anything
        of the run was sent."""
        if self.points:
            return
        self.points = True
        for path, styling in self._styles.items():
            self._styles[path] = as_points(styling)

    def send_styles(self) -> None:
        """Send as static data the styling of every entity that has had no data yet."""
        for path, styling in self._styles.items():
            self.rec.log(path, *styling, static=True)
        self._styles.clear()

    def log(self, entity: str, data: Any, *more: Any, static: bool = False) -> None:
        """Log ``data`` (and ``more`` components, in the same row) with the entity's
        styling if not sent yet."""
        self.sent.add(entity)
        path = self.path(entity)
        styling = self._styles.pop(path, ())
        self.rec.log(path, data, *more, *styling, static=static)

    def send_columns(self, entity: str, indexes: Sequence[rr.TimeColumnLike], columns: Any) -> None:
        self.sent.add(entity)
        path = self.path(entity)
        styling = self._styles.pop(path, ())
        if styling:
            rows = rows_of(indexes)
            columns = [*columns, *(c for s in styling for c in first_row_only(s, rows))]
        self.rec.send_columns(path, indexes=indexes, columns=columns)

    def set_time(self, timeline: str, *, sequence: int) -> None:
        self.rec.set_time(timeline, sequence=sequence)

    def send_blueprint(self, blueprint: rrb.Blueprint) -> None:
        self.rec.send_blueprint(blueprint)

    def flush(self, *, timeout_sec: float) -> None:
        flush_interruptibly(self.rec, timeout_sec)


class SeriesBuffer:
    """Scalar series gathered per entity path and sent with ``send_columns`` in chunks."""

    def __init__(self, rec: Entities, clock: Clock) -> None:
        self._rec = rec
        self._clock = clock
        self._series: dict[str, tuple[list[int], list[int], list[float], list[float]]] = {}

    def add(self, path: str, step: int, event: int, value: float, time: float | None) -> None:
        steps, events, values, times = self._series.setdefault(path, ([], [], [], []))
        steps.append(step)
        events.append(event)
        values.append(value)
        times.append(math.nan if time is None else time)

    def extend(
        self, path: str, steps: list[int], events: list[int], values: list[float],
        times: list[float],
    ) -> None:  # fmt: skip
        """:meth:`add` of several values in order (``times`` NaN where there is none)."""
        series = self._series.setdefault(path, ([], [], [], []))
        for kept, more in zip(series, (steps, events, values, times), strict=True):
            kept.extend(more)  # type: ignore[attr-defined]

    def flush(self) -> None:
        for path, (steps, events, values, times) in self._series.items():
            if values:
                at = np.arange(len(values))
                if path.endswith((style.LOWER, style.UPPER)):  # constant along long runs
                    at = run_ends(np.array(values))
                rows = self._clock.rows(np.array(steps), np.array(events), times)
                self._rec.send_columns(
                    path,
                    indexes=rows.pick(at),
                    columns=scalars(np.array(values)[at]),
                )
        self._series.clear()


def has_class_ids(ids: IntArray) -> bool:
    return ids.size == 0 or bool(ids.min() >= 0 and ids.max() <= MAX_CLASS_ID)


class Canvas:
    """The stream and the state the parts of the picture share.

    :param truth: the run's truth, if any
    :param detail: every ellipse and error at every update (see the recorder)
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        prefix: str,
        truth: GroundTruth | None,
        detail: bool,
        *,
        points: bool = False,
    ) -> None:
        self.entities = Entities(rec, prefix, points=points)
        self.clock = Clock()
        self.series = SeriesBuffer(self.entities, self.clock)
        self.truth = truth
        self.detail = detail
        self.bounds_xy: FloatArray | None = None  # [[x_min, y_min], [x_max, y_max]] so far
        # NIS, NEES: their values and 95% bounds so far, to fit their axes (see axes)
        self.extents: dict[str, SeriesExtent] = {}

    def send(
        self,
        entity: str,
        times: Sequence[rr.TimeColumnLike],
        columns: Sequence[rr.ComponentColumn],
    ) -> None:
        """Send one column batch on both timelines (``times``: see :class:`Rows`)."""
        self.entities.send_columns(entity, indexes=times, columns=columns)

    def set_time(self, time: float | None) -> None:
        """Set the ``time`` timeline of the stream's next ``log`` calls, if there is one."""
        if time is None:
            return
        if self.clock.epoch is None:
            self.clock.epoch = time_is_epoch(time)
        if self.clock.epoch:
            self.entities.rec.set_time(style.TIME, timestamp=time)
        else:
            self.entities.rec.set_time(style.TIME, duration=time)

    def set_times(self, step: int, event: int, time: float | None) -> None:
        """Set all timelines of the stream's next ``log`` calls."""
        self.entities.set_time(style.STEP, sequence=step)
        self.entities.set_time(style.EVENT, sequence=event)
        self.set_time(time)

    def frame(self, points_xy: FloatArray, label_room: float = 0.0) -> None:
        """Grow the map's frame to take in ``points_xy`` that are not the run's.

        :param points_xy: (K, 2) world points
        :param label_room: the share of the frame's width a label beside a point needs
            on either side of it (a label is drawn centred on its point)
        """
        if not len(points_xy):
            return
        self.grow_bounds(points_xy)
        box = self.bounds_xy
        if label_room > 0.0 and box is not None:
            room = np.array([[label_room * float(box[1, 0] - box[0, 0]), 0.0]])
            self.grow_bounds(points_xy + room)
            self.grow_bounds(points_xy - room)

    def grow_bounds(self, points_xy: FloatArray) -> None:
        box = np.stack([points_xy.min(axis=0), points_xy.max(axis=0)])
        if self.bounds_xy is not None:
            box = np.stack(
                [np.minimum(box[0], self.bounds_xy[0]), np.maximum(box[1], self.bounds_xy[1])]
            )
        self.bounds_xy = box

    def extent(
        self, path: str, values: FloatArray, lower: FloatArray | float, upper: FloatArray | float
    ) -> None:
        """Take note of values of a NIS or NEES series and their 95% bounds."""
        self.extents.setdefault(path, SeriesExtent()).add(values, lower, upper)

    def identify(
        self, archetype: type[rr.Points2D] | type[rr.LineStrips2D], ids: IntArray, counts: IntArray
    ) -> rr.ComponentColumn:
        """Landmark ids as class ids (labelled by the annotation context), or as labels
        "L<id>" where an id does not fit a class id."""
        if has_class_ids(ids):
            return column(archetype.descriptor_class_ids(), pa.array(ids.astype(np.uint16)), counts)
        return column(
            archetype.descriptor_labels(), pa.array([f"L{i}" for i in ids.tolist()]), counts
        )

    def send_strips(
        self,
        entity: str,
        rows: Rows,
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
                column(
                    rr.LineStrips2D.descriptor_strips(),
                    strips(polylines[first:last]),
                    counts[lo:hi],
                )
            ]
            if ids is not None:
                columns.append(self.identify(rr.LineStrips2D, ids[first:last], counts[lo:hi]))
            self.send(entity, rows.pick(at[lo:hi]), columns)
