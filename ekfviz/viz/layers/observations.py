"""The observations of an update: a ray from the robot to where each one puts its
landmark (``world/robot/frame/observations``)."""

from __future__ import annotations

import numpy as np
import rerun as rr

from ekfviz.viz import style
from ekfviz.viz.layers.arrow import VECTOR, column, radius, xy
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Canvas
from ekfviz.viz.legend import KIND_CLASS


class ObservationsLayer:
    """The rays of the updates with observations."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas

    def log_styling(self) -> None:
        self._canvas.entities.log(  # static: shown by a range at the cursor (see send),
            # which would not reach a first row holding it
            style.OBSERVATIONS,
            rr.Arrows2D.from_fields(
                colors=style.OBSERVATION_COLOR,
                radii=radius(style.THIN_LINE_RADIUS_UI),
                draw_order=15.0,
                class_ids=KIND_CLASS[style.OBSERVATIONS],
                show_labels=False,
            ),
            static=True,
        )

    def send(self, batch: Batch) -> None:
        """Arrows r [cos b, sin b] in the robot frame (which supplies the origin).

        The layout shows them on the step and event timelines only at the cursor's own
        step or event (``blueprint.at_cursor``): nothing at a predict, no row needed to
        clear them there. The ``time`` timeline shows the latest instead, so a log with
        times gets an empty row at every other event, which clears them.
        """
        rows, observed = batch.rows, batch.observed
        vectors = observed.z[:, 1:2] * np.column_stack(
            [np.cos(observed.z[:, 0]), np.sin(observed.z[:, 0])]
        )
        if rows.times is not None:
            every = column(rr.Arrows2D.descriptor_vectors(), xy(vectors, VECTOR), observed.seen)
            self._canvas.send(style.OBSERVATIONS, rows.all, [every])
            return
        at = np.flatnonzero(observed.seen)
        if at.size:
            counts = observed.seen[at]
            self._canvas.send(
                style.OBSERVATIONS,
                rows.pick(at),
                [column(rr.Arrows2D.descriptor_vectors(), xy(vectors, VECTOR), counts)],
            )
