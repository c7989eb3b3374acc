"""The robot: its point and frame (``world/robot``), its heading, its 3-sigma position
ellipses after each predict and update, and its estimated path (``world/trajectory``)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.ellipses import ellipse_axes, unit_circle
from ekfviz.viz.layers.arrow import (
    STRIP,
    column,
    in_parent_frame,
    positions,
    radius,
    robot_frame,
    shape_matrices,
    xy,
)
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Canvas, Rows
from ekfviz.viz.legend import KIND_CLASS

HEADING_LENGTH = 1.0  # metres


class RobotLayer:
    """The estimated robot and its path.

    :param heading_length: length in metres of the robot's heading arrow
    """

    def __init__(self, canvas: Canvas, heading_length: float = HEADING_LENGTH) -> None:
        self._canvas = canvas
        self._heading_length = heading_length
        self._last_xy: FloatArray | None = None  # the path's last point so far

    def log_styling(self) -> None:
        entities = self._canvas.entities
        line = radius(style.LINE_RADIUS_UI)
        entities.style(
            style.ROBOT,
            rr.Points2D.from_fields(
                colors=style.ROBOT_COLOR,
                radii=radius(style.ROBOT_RADIUS_UI),
                draw_order=40.0,
                class_ids=KIND_CLASS[style.ROBOT],
                show_labels=False,
            ),
            in_parent_frame(entities.path(style.ROBOT)),  # see arrow.robot_frame
        )
        entities.log(
            style.HEADING,
            rr.Arrows2D(
                origins=[[0.0, 0.0]],
                vectors=[[self._heading_length, 0.0]],
                colors=style.ROBOT_COLOR,
                radii=line,
                draw_order=40.0,
                class_ids=KIND_CLASS[style.HEADING],
                show_labels=False,
            ),
            static=True,
        )
        entities.style(
            style.TRAJECTORY,
            rr.LineStrips2D.from_fields(
                colors=style.TRAJECTORY_COLOR,
                radii=line,
                draw_order=10.0,
                class_ids=KIND_CLASS[style.TRAJECTORY],
                show_labels=False,
            ),
        )
        for path, color in (
            (style.POSE_PREDICTED, style.PREDICTED_COLOR),
            (style.POSE_UPDATED, style.UPDATED_COLOR),
        ):
            # one unit circle, drawn through each event's transform (see send_pose_ellipses):
            # a sixth of the bytes of an outline per event
            entities.style(
                path,
                rr.LineStrips2D(
                    [unit_circle()],
                    colors=color,
                    radii=line,
                    show_labels=False,
                    draw_order=20.0,
                    class_ids=KIND_CLASS[path],
                ),
            )

    def send(self, batch: Batch) -> None:
        """The robot frame at every record (its point and heading are static in it, its
        ellipses change shape there only slowly) and the path of every step."""
        rows, poses = batch.rows, batch.poses
        self._canvas.send(style.ROBOT, rows.all, [positions(poses), *robot_frame(poses)])
        paths = {
            k: extra.path_xytheta
            for k, extra in batch.extras.items()
            if extra.path_xytheta is not None
        }
        self._send_trajectory(rows, poses[:, :2], batch.corrected, paths)

    def send_pose_ellipses(self, path: str, batch: Batch, picked: IntArray) -> None:
        """The 3-sigma ellipses of the position at the rows ``picked``: the map of the
        static unit circle onto each, in the robot frame, A = R(theta)^T 3 V sqrt(L)
        (36 bytes an event instead of an outline's 256)."""
        if not picked.size:
            return
        poses, pose_covs = batch.poses, batch.pose_covs
        world = ellipse_axes(np.zeros((len(picked), 2)), pose_covs[picked, :2, :2])[:, :4]
        cos_t, sin_t = np.cos(poses[picked, 2]), np.sin(poses[picked, 2])
        rotation_t = np.stack(
            [np.column_stack([cos_t, sin_t]), np.column_stack([-sin_t, cos_t])], axis=1
        )
        axes = rotation_t @ world.reshape(-1, 2, 2)
        self._canvas.send(
            path,
            batch.rows.pick(picked),
            [column(rr.Transform3D.descriptor_mat3x3(), shape_matrices(axes))],
        )

    def _send_trajectory(
        self,
        rows: Rows,
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
            strips = pa.ListArray.from_arrays(offsets, xy(points_xy[index]), type=STRIP)
            self._canvas.send(
                style.TRAJECTORY,
                rows.pick(at),
                [column(rr.LineStrips2D.descriptor_strips(), strips)],
            )
        for k, path in sorted((paths or {}).items()):
            at_k = np.array([k], dtype=np.int64)
            self._canvas.send_strips(style.TRAJECTORY, rows, at_k, path[None, :, :2])
            self._canvas.grow_bounds(path[:, :2])
        self._last_xy = ends_xy[-1].copy()
        self._canvas.grow_bounds(ends_xy)
