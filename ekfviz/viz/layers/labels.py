"""The landmarks' labels: "L<id>" hanging from each landmark's point in a small map
(``world/landmarks/labels``), and the classes of ``world`` that name every landmark id
and every kind of mark."""

from __future__ import annotations

import numpy as np
import rerun as rr

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.annotations import annotation_context
from ekfviz.viz.layers.arrow import column, radius, xy
from ekfviz.viz.layers.canvas import MAX_CLASS_ID, Canvas
from ekfviz.viz.legend import kind_classes

# A landmark label's box as a fraction of the map's span, at the zoom that frames the map
# (about "L12" at 14 px on a 700 px map): closer labels are stacked (see unclutter)
LABEL_WIDTH = 0.05
LABEL_HEIGHT = 0.03
LABEL_DROP = 0.8  # a label's anchor below its landmark, in label heights: the dot stays clear


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
                    below = placed[j, 1] - 1.001 * height  # clear of it despite round-off
                    # y only falls, past each label at most once; where the height is
                    # below y's float spacing (an anchor 1e17 m out) it cannot: left there
                    if below < y:
                        y, moved = below, True
        placed[i, 1] = y
        done.append(i)
    return placed


class LabelsLayer:
    """The labels of a small map and the landmark classes.

    :param labels_off: no labels at all (the small maps of a sweep, under a prefix)
    :param small_map: beyond this many landmarks the labels go (the viewer shows a
        landmark's label on hover)
    """

    def __init__(self, canvas: Canvas, *, labels_off: bool, small_map: int) -> None:
        self._canvas = canvas
        self._labels_off = labels_off
        self._small_map = small_map
        # landmark classes (see annotate): ids 0.._class_top and _class_extra are logged
        self._class_top = -1
        self._class_extra: set[int] = set()
        self._class_pending: set[int] = set()
        self._class_count = 0
        self._classes_logged = False

    def log_styling(self) -> None:
        self._canvas.entities.style(
            style.LANDMARK_LABELS,
            rr.Points2D.from_fields(
                colors=style.LANDMARK_COLOR,
                radii=radius(style.LABEL_ANCHOR_RADIUS_UI),
                show_labels=True,
                draw_order=31.0,
            ),
        )

    def send(
        self,
        times: list[rr.TimeColumnLike],
        ids: IntArray,
        positions: FloatArray,
        counts: IntArray,
    ) -> None:
        """The labels of some maps (their ``ids`` and ``positions`` joined, ``counts`` a
        map), each hanging from its landmark (close ones stacked, see :func:`unclutter`),
        or empty rows from the first map too large for them."""
        send = self._canvas.send
        if self._labels_off or int(counts.max()) > self._small_map:
            if not self._labels_off:  # empty rows from here on: the labels are gone
                self._labels_off = True
                empty = np.zeros(len(counts), dtype=np.int64)
                send(
                    style.LANDMARK_LABELS,
                    times,
                    [column(rr.Points2D.descriptor_positions(), xy(np.zeros((0, 2))), empty)],
                )
            return
        # a label hangs just below its landmark's own point (the viewer centres it on its
        # anchor): hung below the 3-sigma outline it floated metres off on real data,
        # beside another landmark's ellipse
        below = positions.copy()
        bounds_xy = self._canvas.bounds_xy
        span = 0.0 if bounds_xy is None else max(float(np.max(bounds_xy[1] - bounds_xy[0])), 1e-9)
        below[:, 1] -= LABEL_DROP * LABEL_HEIGHT * span
        if bounds_xy is not None and counts[-1] > 1:
            # labels of close landmarks stacked, not overprinted: the offsets that clear the
            # batch's last map, by landmark id, for all its rows (a map moves little within
            # a batch, and one pass per update would cost seconds on a long run)
            last = slice(len(below) - int(counts[-1]), len(below))
            offsets = unclutter(below[last], LABEL_WIDTH * span, LABEL_HEIGHT * span) - below[last]
            if offsets.any():
                last_ids = ids[last]
                order = np.argsort(last_ids)
                at = np.clip(np.searchsorted(last_ids[order], ids), 0, len(order) - 1)
                same = last_ids[order][at] == ids
                below[same] += offsets[order][at[same]]
            # the frame takes in the last map's labels whole: none is cut at its edge
            box = np.array([[0.5 * LABEL_WIDTH * span, 0.5 * LABEL_HEIGHT * span]])
            self._canvas.grow_bounds(np.concatenate([below[last] - box, below[last] + box]))
        send(
            style.LANDMARK_LABELS,
            times,
            [
                column(rr.Points2D.descriptor_positions(), xy(below), counts),
                self._canvas.identify(rr.Points2D, ids, counts),
            ],
        )

    def annotate(self, ids: IntArray) -> None:
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

    def finish(self) -> None:
        """Log the classes still pending, and those of the kinds of marks if no landmark
        ever came."""
        if self._class_pending or not self._classes_logged:
            self._log_classes()

    def _log_classes(self) -> None:
        """The context of ``world``: the landmarks' classes and the kinds of marks'."""
        self._class_extra |= self._class_pending
        self._class_pending.clear()
        classes = [*range(self._class_top + 1), *sorted(self._class_extra)]
        kind_ids, kind_names = kind_classes(self._canvas.entities.run_name)
        self._canvas.entities.log(
            style.WORLD,
            annotation_context([*classes, *kind_ids], [*(f"L{i}" for i in classes), *kind_names]),
            static=True,
        )
        self._classes_logged = True
