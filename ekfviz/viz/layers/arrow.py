"""Rerun columns built straight from numpy through Arrow, and the timelines of a send.

The SDK's archetype ``columns`` check and convert their input in Python at every call,
which cost more than the rest of a send, a dozen sends per flush: every column here is
the Arrow array Rerun would make, built from numpy in one go.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style

MIN_AXIS = 1e-9  # metres: the shortest semi-axis a pose ellipse's transform gets
EPOCH_MIN_S = 1e9  # log times from here on are Unix time (see time_is_epoch)

# Arrow types of the components built here (see column), from the SDK's own conversion
XY = rr.components.Position2DBatch([[0.0, 0.0]]).as_arrow_array().type
VECTOR = rr.components.Vector2DBatch([[0.0, 0.0]]).as_arrow_array().type
STRIP = rr.components.LineStrip2DBatch([[[0.0, 0.0], [0.0, 0.0]]]).as_arrow_array().type
VEC3 = rr.components.Translation3DBatch([[0.0, 0.0, 0.0]]).as_arrow_array().type
MAT3 = rr.components.TransformMat3x3Batch([np.eye(3)]).as_arrow_array().type
QUAT = rr.components.RotationQuatBatch([[0.0, 0.0, 0.0, 1.0]]).as_arrow_array().type
INFO, WARN = str(rr.TextLogLevel.INFO), str(rr.TextLogLevel.WARN)  # as Arrow strings


def radius(ui_points: float) -> npt.ArrayLike:
    return rr.Radius.ui_points(ui_points)


@dataclass(frozen=True, slots=True)
class Arrow:
    """An Arrow array built here, as the SDK's ``ComponentBatchLike``."""

    array: pa.Array

    def as_arrow_array(self) -> pa.Array:
        return self.array


def column(
    descriptor: rr.ComponentDescriptor, values: pa.Array, counts: IntArray | None = None
) -> rr.ComponentColumn:
    """``values`` as a column of rows of ``counts[i]`` values each (one each by default)."""
    offsets = np.zeros(len(values) + 1 if counts is None else len(counts) + 1, dtype=np.int32)
    if counts is None:
        offsets[1:] = np.arange(1, len(values) + 1)
    else:
        np.cumsum(counts, out=offsets[1:])
    return rr.ComponentColumn(descriptor, Arrow(values), offsets=offsets)


def run_ends(values: npt.NDArray[Any]) -> IntArray:
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


def scalars(values: npt.ArrayLike) -> list[rr.ComponentColumn]:
    """One ``Scalars`` value per row."""
    array = pa.array(np.asarray(values, dtype=np.float64))
    return [column(rr.Scalars.descriptor_scalars(), array)]


def xy(points: FloatArray, vector_type: pa.DataType = XY) -> pa.Array:
    """(K, 2) points (or vectors) as Rerun's float32 pairs."""
    flat = pa.array(np.ascontiguousarray(points, dtype=np.float32).reshape(-1))
    return pa.FixedSizeListArray.from_arrays(flat, type=vector_type)


def strips(polylines: FloatArray) -> pa.Array:
    """(K, n, 2) polylines as Rerun's line strips, in its own float32.

    Built as the Arrow array Rerun would make, with offsets from numpy: the SDK's own
    conversion walks the strips in Python, which costs more than the rest of logging them.
    """
    k, n = polylines.shape[:2]
    offsets = pa.array(
        np.arange(0, (k + 1) * n, n, dtype=np.int32) if n else np.zeros(k + 1, np.int32)
    )
    return pa.ListArray.from_arrays(offsets, xy(polylines.reshape(-1, 2)), type=STRIP)


def fixed(values: npt.NDArray[Any], arrow_type: pa.DataType) -> pa.Array:
    """(K, n) values as Rerun's fixed-size lists of n float32."""
    flat = pa.array(np.ascontiguousarray(values, dtype=np.float32).reshape(-1))
    return pa.FixedSizeListArray.from_arrays(flat, type=arrow_type)


def positions(poses: FloatArray) -> rr.ComponentColumn:
    """(K, 3) poses as a ``Points2D`` column of their positions, one point a row."""
    return column(rr.Points2D.descriptor_positions(), xy(poses[:, :2]))


def robot_frame(poses: FloatArray) -> list[rr.ComponentColumn]:
    """(K, 3) poses as ``Transform3D`` columns placing the robot frame in the world:
    translation (x, y, 0) and the rotation theta about z as a quaternion (x, y, z, w).

    Logged on the robot's point (``world/robot``), whose rows they share: they place
    what is under it (``world/robot/frame/...``), while the point itself stays in the
    world's frame (its ``CoordinateFrame``, see :func:`in_parent_frame`). One row an
    event instead of two: a row costs some 20 bytes of row id and timelines.
    """
    k = len(poses)
    translations = np.zeros((k, 3))
    translations[:, :2] = poses[:, :2]
    half = 0.5 * poses[:, 2]
    quaternions = np.zeros((k, 4))
    quaternions[:, 2], quaternions[:, 3] = np.sin(half), np.cos(half)
    return [
        column(rr.Transform3D.descriptor_translation(), fixed(translations, VEC3)),
        column(rr.Transform3D.descriptor_quaternion(), fixed(quaternions, QUAT)),
    ]


def frame_id(entity_path: str) -> str:
    """The name of an entity's implicit transform frame (Rerun's ``tf#/<path>``)."""
    return f"tf#/{entity_path.strip('/')}"


def in_parent_frame(path: str) -> rr.CoordinateFrame:
    """The data of the entity at ``path`` in its parent's frame, not in the frame its own
    ``Transform3D`` places (that one places only the entities under it)."""
    return rr.CoordinateFrame(frame_id(path.rsplit("/", 1)[0]))


def shape_matrices(axes: FloatArray) -> pa.Array:
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
    return fixed(matrices, MAT3)


@dataclass(frozen=True, slots=True)
class Index:
    """A time column already in Arrow, as the SDK's ``TimeColumnLike``."""

    timeline: str
    times: pa.Array

    def timeline_name(self) -> str:
        return self.timeline

    def as_arrow_array(self) -> pa.Array:
        return self.times


def times_of(
    steps: IntArray, events: IntArray, times: FloatArray | None = None, epoch: bool = False
) -> list[rr.TimeColumnLike]:
    """The timelines of some rows, in Arrow: ``step``, ``event`` and, when the records
    have times, ``time`` (see :func:`time_is_epoch` for its type)."""
    columns: list[rr.TimeColumnLike] = [
        Index(style.STEP, pa.array(steps)),
        Index(style.EVENT, pa.array(events)),
    ]
    if times is not None:
        nanos = np.rint(times * 1e9).astype(np.int64)
        kind = pa.timestamp("ns") if epoch else pa.duration("ns")
        columns.append(Index(style.TIME, pa.array(nanos, type=kind)))
    return columns


def time_is_epoch(first_time: float) -> bool:
    """Whether the ``time`` timeline is a timestamp (Unix time, shown as a date) rather
    than a duration: decided once per recording by its first time, from 10^9 s
    (September 2001) on. Either way its value in seconds is the log's time."""
    return first_time >= EPOCH_MIN_S


def time_column(times: FloatArray) -> rr.TimeColumn:
    """The ``time`` timeline of some rows, of the type the recorder chose for the log."""
    if len(times) and time_is_epoch(float(times[0])):
        return rr.TimeColumn(style.TIME, timestamp=times)
    return rr.TimeColumn(style.TIME, duration=times)


def rounded_time_column(times: FloatArray) -> rr.TimeColumn:
    """:func:`time_column` rounded to the nanosecond as ``set_time`` rounds (the SDK's
    columns truncate: 8.543 s would become 8.542999999 s), for rows once logged one by one."""
    nanos = np.round(times * 1e9).astype(np.int64)
    if len(times) and time_is_epoch(float(times[0])):
        return rr.TimeColumn(style.TIME, timestamp=nanos.astype("datetime64[ns]"))
    return rr.TimeColumn(style.TIME, duration=nanos.astype("timedelta64[ns]"))


def rows_of(indexes: Sequence[rr.TimeColumnLike]) -> int:
    return len(indexes[0].as_arrow_array()) if indexes else 0


@dataclass(frozen=True, slots=True)
class FirstRow:
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
        # rows 1.. null through null offsets: the same array as from_arrays(mask=...), which
        # imports pyarrow.compute (30-45 ms of a short replay's start) to apply its mask
        null = np.zeros(self.rows + 1, dtype=bool)
        null[1 : self.rows] = True
        return pa.ListArray.from_arrays(pa.array(offsets, mask=null), self.values)


def first_row_only(styling: rr.AsComponents, rows: int) -> list[FirstRow]:
    """The components of ``styling`` as columns of ``rows`` rows, set in the first only."""
    return [
        FirstRow(batch.component_descriptor(), batch.as_arrow_array(), rows)
        for batch in styling.as_component_batches()
    ]
