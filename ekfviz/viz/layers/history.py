"""The history of the robot's ellipses (``--history``): every predicted and updated
3-sigma outline in the world, accumulated by the layout up to the time cursor (the
classic figure)."""

from __future__ import annotations

import rerun as rr

from ekfviz.core.types import IntArray
from ekfviz.viz import style
from ekfviz.viz.ellipses import ellipse_outlines
from ekfviz.viz.layers.arrow import radius
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Canvas
from ekfviz.viz.legend import KIND_CLASS

PATHS = {
    style.POSE_PREDICTED: (style.POSE_PREDICTED_HISTORY, style.PREDICTED_COLOR),
    style.POSE_UPDATED: (style.POSE_UPDATED_HISTORY, style.UPDATED_COLOR),
}


class HistoryLayer:
    """The outlines of the robot's ellipses, when the layout accumulates them."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas

    def log_styling(self) -> None:
        line = radius(style.LINE_RADIUS_UI)
        for path, color in PATHS.values():
            self._canvas.entities.style(
                path,
                rr.LineStrips2D.from_fields(
                    colors=color,
                    radii=line,
                    show_labels=False,
                    draw_order=20.0,
                    class_ids=KIND_CLASS[path],
                ),
            )

    def send(self, ellipse: str, batch: Batch, picked: IntArray) -> None:
        """The outlines of the ellipses at the rows ``picked`` of ``ellipse``'s history."""
        if picked.size:  # outlines in the world, to accumulate
            outlines = ellipse_outlines(batch.poses[picked, :2], batch.pose_covs[picked, :2, :2])
            self._canvas.send_strips(PATHS[ellipse][0], batch.rows, picked, outlines)
