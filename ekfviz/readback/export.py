"""Read an ekfviz recording back as trajectories and a map: the estimated pose of every
step, the true pose where the recording holds it, the latest landmark estimates.

The estimated pose of a step is the robot frame (``world/robot/frame``) at the step's
last event, its corrected state; the true one is ``world/truth/robot/frame``, logged by a replay
with true poses. Time stamps come from the ``time`` timeline where the recording has one
(a log with time stamps), else they are the step numbers.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.angles import wrap_angles
from ekfviz.readback.apart import NotARecordingError, read_apart
from ekfviz.readback.info import check_recording_path, recordings_of, the_recording, unreadable
from ekfviz.viz import style

TIME = "time"  # the timeline of a log's own time stamps, in seconds


@dataclass(frozen=True, slots=True)
class Trajectory:
    """One pose per step: ``steps`` (T,), ``poses_xytheta`` (T, 3), and ``seconds`` (T,)
    from the ``time`` timeline, None where the recording has none."""

    steps: IntArray
    poses_xytheta: FloatArray
    seconds: FloatArray | None

    @property
    def stamps(self) -> FloatArray:
        """Seconds where known, else the step numbers."""
        if self.seconds is not None:
            return self.seconds
        return self.steps.astype(np.float64)


@dataclass(frozen=True, slots=True)
class RecordedRun:
    """What ``ekfviz export`` writes: the estimate, the truth, the pose's standard
    deviations (T, 3) (NaN where not logged) and the last landmark estimates."""

    estimate: Trajectory
    truth: Trajectory | None
    sigmas_xytheta: FloatArray
    landmark_ids: IntArray
    landmarks_xy: FloatArray


@dataclass
class _Rows:
    """The rows of one entity: timelines and data columns, as numpy."""

    steps: list[IntArray]
    events: list[IntArray]
    seconds: list[FloatArray | None]
    columns: dict[str, list[list[Any]]]

    def add(self, batch: pa.RecordBatch) -> None:
        names = batch.schema.names
        if "step" not in names or "event" not in names:
            return  # logged by another program on an entity of ours: not a step of a replay
        self.steps.append(np.asarray(batch.column("step").to_numpy(), dtype=np.int64))
        self.events.append(np.asarray(batch.column("event").to_numpy(), dtype=np.int64))
        self.seconds.append(_seconds(batch.column(TIME)) if TIME in names else None)
        for field, column in zip(batch.schema, batch.columns, strict=True):
            if (field.metadata or {}).get(b"rerun:kind") == b"data":
                self.columns.setdefault(field.name, []).append(column.to_pylist())
        for values in self.columns.values():  # a column missing from this chunk: nulls
            if len(values) < len(self.steps):
                values.append([None] * batch.num_rows)

    def table(self) -> tuple[IntArray, IntArray, FloatArray | None, dict[str, list[Any]]]:
        """All rows by event: steps, events, seconds (None unless every row has one),
        and each data column."""
        steps = np.concatenate(self.steps)
        events = np.concatenate(self.events)
        order = np.argsort(events, kind="stable")
        seconds = None
        if all(s is not None for s in self.seconds):
            seconds = np.concatenate([s for s in self.seconds if s is not None])[order]
            if not np.isfinite(seconds).all():
                seconds = None
        columns = {
            name: [cell for part in parts for cell in part] for name, parts in self.columns.items()
        }
        return (
            steps[order],
            events[order],
            seconds,
            {name: [cells[i] for i in order.tolist()] for name, cells in columns.items()},
        )


def _seconds(column: pa.Array) -> FloatArray:
    """A time column in seconds: durations and timestamps are in nanoseconds."""
    if pa.types.is_duration(column.type) or pa.types.is_timestamp(column.type):
        nanoseconds = column.cast(pa.int64()).to_numpy(zero_copy_only=False)
        return np.asarray(nanoseconds, dtype=np.float64) / 1e9
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64)


def read_recorded_run(path: Path | str) -> RecordedRun:
    """The trajectories, pose standard deviations and map of one replay's recording,
    read in a child process (:func:`~ekfviz.readback.apart.read_apart`: a damaged file cannot
    abort this one).

    :raises NotARecordingError: when ``path`` is not a recording of a replay with
        estimated poses
    """
    return read_apart(_read_recorded_run, path)


def _read_recorded_run(path: Path) -> RecordedRun:
    """:func:`read_recorded_run` in this process."""
    check_recording_path(path)
    wanted = {  # the poses: on the robot's point; before, on the robot frame's own entity
        f"/{style.ROBOT}": "robot",
        f"/{style.TRUTH_ROBOT}": "truth",
        f"/{style.ROBOT_FRAME}": "robot_frame",
        f"/{style.TRUTH_ROBOT_FRAME}": "truth_frame",
        f"/{style.POSE_SIGMA}": "sigma",
        f"/{style.LANDMARKS}": "landmarks",
    }
    rows = {name: _Rows([], [], [], {}) for name in wanted.values()}
    try:
        # a file cut short (at a chunk's end: every chunk reads) or whose writer did not
        # close it, which ekfviz never saves (it writes beside the path and renames once
        # the footer is written)
        reader, recordings, footerless = recordings_of(path)
        if footerless:
            raise NotARecordingError(
                f"{path}: the file has no footer: cut short after {path.stat().st_size}"
                " bytes, or its writer did not close it; export reads whole recordings"
            )
        entry = the_recording(path, recordings)
        with warnings.catch_warnings():  # (Rerun's own, of what it reads: the error says more)
            warnings.simplefilter("ignore")
            for chunk in reader.stream(store=entry).filter(content=list(wanted), is_static=False):
                name = wanted.get(chunk.entity_path)
                if name is not None:
                    rows[name].add(chunk.to_record_batch())
    except (RuntimeError, ValueError, OSError) as error:
        raise NotARecordingError(unreadable(path, error)) from None
    estimate = _trajectory(rows["robot"]) or _trajectory(rows["robot_frame"])
    if estimate is None:
        raise NotARecordingError(
            f"{path}: no estimated poses ({style.ROBOT}): not a recording of an ekfviz replay"
        )
    try:
        ids, landmarks_xy = _last_landmarks(rows["landmarks"])
        run = RecordedRun(
            estimate=estimate,
            truth=_trajectory(rows["truth"]) or _trajectory(rows["truth_frame"]),
            sigmas_xytheta=_sigmas(rows["sigma"], estimate.steps),
            landmark_ids=ids,
            landmarks_xy=landmarks_xy,
        )
    except (ValueError, TypeError, KeyError, IndexError) as error:  # entities another wrote
        reason = str(error).splitlines()[0][:80] if str(error) else type(error).__name__
        raise NotARecordingError(
            f"{path}: its poses or map do not read ({reason}), expected what ekfviz writes:"
            " a damaged recording or one another program wrote"
        ) from None
    if len(run.landmark_ids) != len(run.landmarks_xy):
        raise NotARecordingError(
            f"{path}: its map has {len(run.landmarks_xy)} landmarks and"
            f" {len(run.landmark_ids)} ids, expected one id a landmark: a damaged recording"
            " or one another program wrote"
        )
    finite = [run.estimate.poses_xytheta, run.landmarks_xy]
    if run.truth is not None:
        finite.append(run.truth.poses_xytheta)
    if not all(np.isfinite(values).all() for values in finite):
        raise NotARecordingError(
            f"{path}: its poses or map hold numbers that are not finite, expected what a"
            " replay writes: a damaged recording or one another program wrote"
        )
    return run


def _last_per_step(steps: IntArray) -> IntArray:
    """Indices of the last row of each step, rows sorted by event."""
    last = np.flatnonzero(np.append(steps[1:] != steps[:-1], True))
    return last


def _trajectory(rows: _Rows) -> Trajectory | None:
    if not rows.steps:
        return None
    steps, _, seconds, columns = rows.table()
    translations = columns.get("Transform3D:translation")
    quaternions = columns.get("Transform3D:quaternion")
    if translations is None or quaternions is None:
        return None
    at = _last_per_step(steps)
    poses = np.empty((len(at), 3))
    for k, i in enumerate(at.tolist()):
        (x, y, _), (_, _, qz, qw) = translations[i][0], quaternions[i][0]
        poses[k] = x, y, 2.0 * math.atan2(qz, qw)
    poses[:, 2] = wrap_angles(poses[:, 2])
    return Trajectory(steps[at], poses, None if seconds is None else seconds[at])


def _sigmas(rows: _Rows, steps: IntArray) -> FloatArray:
    sigmas = np.full((len(steps), 3), np.nan)
    if not rows.steps:
        return sigmas
    logged_steps, _, _, columns = rows.table()
    values = columns.get("Scalars:scalars", [])
    at = _last_per_step(logged_steps)
    where = np.searchsorted(steps, logged_steps[at])
    for k, i in zip(where.tolist(), at.tolist(), strict=True):
        cell = values[i]
        if k < len(steps) and steps[k] == logged_steps[i] and cell is not None:
            sigmas[k] = np.asarray(cell, dtype=np.float64)[:3]
    return sigmas


def _last_landmarks(rows: _Rows) -> tuple[IntArray, FloatArray]:
    if not rows.steps:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    _, _, _, columns = rows.table()
    positions = np.asarray(columns["Points2D:positions"][-1], dtype=np.float64).reshape(-1, 2)
    class_ids = columns.get("Points2D:class_ids")
    if class_ids is not None and class_ids[-1] is not None:
        ids = np.asarray(class_ids[-1], dtype=np.int64)
    else:  # ids that do not fit a class id are labels "L<id>"
        labels = columns["Points2D:labels"][-1]
        ids = np.array([int(str(label)[1:]) for label in labels], dtype=np.int64)
    return ids, positions
