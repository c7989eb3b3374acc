"""The map: every landmark's estimate (``world/landmarks``), its 3-sigma ellipse
(``world/landmarks/ellipses``, ``.../observed`` beyond a small map) and its outline at
first sighting (``world/landmarks/initial``).

When, by default: all landmark positions where the map grew or some landmark moved by
over ``MAP_TOLERANCE`` of its ellipse (the viewer shows the latest). The 3-sigma ellipses
of all landmarks likewise while the map holds at most ``SMALL_MAP`` landmarks; beyond
that, at every update only those of the landmarks observed
(``world/landmarks/ellipses/observed``) and the whole map every ``MAP_EVERY_STEPS``
steps and at the end (the viewer shows the latest of each, so every landmark keeps an
ellipse at any time). A timestamped log (high-rate odometry) logs its map like a large
one, the whole map every ``MAP_EVERY_S`` seconds of log time and wherever a map of up to
``GROWN_MAP_WHOLE`` landmarks grew. With truth, the error
series of a landmark get a value whenever its ellipse is logged; ``detail=True`` logs
every ellipse and error at every update.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from ekfviz.core.batch import EventBatch, ranges
from ekfviz.core.records import EventRecord
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.ellipses import ellipse_extent, ellipse_outlines, outline_points
from ekfviz.viz.layers.arrow import column, radius, xy
from ekfviz.viz.layers.batch import Batch, Maps, landmark_rows
from ekfviz.viz.layers.canvas import Canvas, Rows
from ekfviz.viz.layers.first_sightings import INITIAL_POINTS as INITIAL_POINTS  # the tests'
from ekfviz.viz.layers.first_sightings import FirstSightings
from ekfviz.viz.layers.labels import LabelsLayer
from ekfviz.viz.layers.map_rows import MAP_TOLERANCE as MAP_TOLERANCE  # the recorder's
from ekfviz.viz.layers.map_rows import (
    IdRows,
    JoinedIds,
    joined_rows,
    map_changes,
)

SMALL_MAP = 32  # up to this many landmarks, every ellipse at every update
MAP_EVERY_STEPS = 25  # beyond: the whole map every this many steps
MAP_POINTS = 16  # points of a landmark outline: within 2 % of its radius, as MAP_TOLERANCE
MAP_EVERY_S = 5.0  # ... and in a thinned timestamped log, every this many seconds of log time
# ... and where a map of up to this many landmarks grew (MRCLAM's 15): beyond, a log of
# hundreds of growths (Victoria Park) would log its whole map at each
GROWN_MAP_WHOLE = 128


class MapLayer:
    """The landmarks, their ellipses and first sightings.

    :param labels: the labels layer, which draws beside the points
    :param thinned: the predicts of a timestamped log are thinned (the map goes sparse)
    """

    def __init__(self, canvas: Canvas, labels: LabelsLayer, *, thinned: bool) -> None:
        self._canvas = canvas
        self._labels = labels
        self._thinned = thinned
        self._detail = canvas.detail
        self.seen_ids: set[int] = set()  # every landmark id in the map so far (for the layout)
        self._last_ids: IntArray | None = None  # landmark ids of the last update, annotated
        self._map_step: int | None = None  # step of the last update that logged the whole map
        self._map_time: float | None = None  # and its time
        self._map_count = 0  # the most landmarks a map has had: a larger one is logged whole
        self.last_update: tuple[EventRecord, bool] | None = None
        # the small map as last logged: its ids and shapes rows, and at which event
        self._map_shown: tuple[IntArray, FloatArray] | None = None
        self._map_shown_event: int | None = None
        self._final_event: int | None = None  # the last update's, at finish: shown exactly
        self._first_sightings = FirstSightings(canvas)  # of id-less scans

    def log_styling(self) -> None:
        entities = self._canvas.entities
        line, thin = radius(style.LINE_RADIUS_UI), radius(style.THIN_LINE_RADIUS_UI)
        for path, color, radii, order in (
            (style.LANDMARK_ELLIPSES, style.LANDMARK_COLOR, line, 20.0),
            (style.LANDMARK_ELLIPSES_OBSERVED, style.LANDMARK_COLOR, line, 20.0),
            # the first-sighting outlines thin and beneath the current ones: on real data
            # (MRCLAM) they are metres wide and would hide the map as it is now
            (style.LANDMARK_INITIAL, style.INITIAL_COLOR, thin, 15.0),
        ):
            entities.style(
                path,
                rr.LineStrips2D.from_fields(
                    colors=color, radii=radii, show_labels=False, draw_order=order
                ),
            )
        entities.style(
            style.LANDMARKS,
            rr.Points2D.from_fields(
                colors=style.LANDMARK_COLOR,
                radii=radius(style.POINT_RADIUS_UI),
                show_labels=False,
                draw_order=30.0,
            ),
        )

    def admit(self, events: EventBatch) -> BoolArray:
        """Take note of the maps of a batch's updates (and initialisation); whether each
        event logs the whole map's ellipses (never a predict).

        An update logs its whole map beyond ``SMALL_MAP`` landmarks, or in a timestamped
        log whose predicts are thinned (see :mod:`ekfviz.viz.thinning`), only now and then
        (its map is sparse); every update of a small map logs it.
        """
        whole = np.zeros(len(events), dtype=bool)
        corrected = events.corrected
        if not len(corrected):
            return whole
        table = events.maps
        at = events.map_of[corrected]
        sets = table.id_set[at]
        for k in np.flatnonzero(np.r_[True, sets[1:] != sets[:-1]]).tolist():
            ids = table.id_sets[int(sets[k])]
            # a map's ids are one array until the map grows
            if ids is not self._last_ids and (
                self._last_ids is None or not np.array_equal(ids, self._last_ids)
            ):
                self._labels.annotate(ids)
                self._last_ids = ids
                self.seen_ids.update(ids.tolist())
        times = events.times[corrected]
        sparse = np.zeros(len(corrected), dtype=bool)
        if not self._detail:
            sparse = table.counts[at] > SMALL_MAP
            if self._thinned:
                sparse |= ~np.isnan(times)
        steps = events.steps[corrected]
        if not sparse.any():  # every update logs its map: the last is the latest to
            whole[corrected] = True
            self._map_step = int(steps[-1])
            self._map_time = None if np.isnan(times[-1]) else float(times[-1])
        else:
            whole[corrected] = [
                self._logs_whole_map(is_sparse, step, None if time != time else time, count)
                for is_sparse, step, time, count in zip(
                    sparse.tolist(),
                    steps.tolist(),
                    times.tolist(),
                    table.counts[at].tolist(),
                    strict=True,
                )
            ]
        self.last_update = (events.event(int(corrected[-1])), bool(whole[corrected[-1]]))
        return whole

    def _logs_whole_map(self, sparse: bool, step: int, time: float | None, count: int) -> bool:
        """Whether an update at ``step`` (and ``time``) of a map of ``count`` landmarks logs
        the whole map's ellipses, noted as the last that did if so: every update of a map
        that is not ``sparse``, else the first, every one where a map of at most
        ``GROWN_MAP_WHOLE`` landmarks grew (a new landmark's ellipse would go with the
        next update's observed ones, for up to ``MAP_EVERY_S``) and then every
        ``MAP_EVERY_S`` of log time (``MAP_EVERY_STEPS`` steps without times)."""
        grew = self._map_count < count <= GROWN_MAP_WHOLE
        self._map_count = max(self._map_count, count)
        whole = (
            not sparse
            or grew
            or self._map_step is None
            or (
                time - self._map_time >= MAP_EVERY_S
                if time is not None and self._map_time is not None
                else step - self._map_step >= MAP_EVERY_STEPS
            )
        )
        if whole:
            self._map_step, self._map_time = step, time
        return whole

    def send(self, batch: Batch) -> None:
        """The points and ellipses of the batch's updates (see :meth:`_map_changes`)."""
        if not batch.corrected.size:
            return
        rows, corrected, maps = batch.rows, batch.corrected, batch.maps
        whole = batch.whole[corrected]
        sparse = self._sparse_maps(batch)
        shown = self._map_changes(batch, sparse).tolist()
        if shown:
            picked = np.array(shown, dtype=np.int64)
            joined = ranges(maps.starts[picked], maps.starts[picked + 1])
            self._send_points(
                rows.pick(corrected[picked]),
                np.concatenate([maps.ids[i] for i in shown]),
                maps.xy[joined],
                maps.counts[picked],
            )
        # the ellipses of every update below by their rows in the batch's joined maps
        # (maps.xy, maps.covs), found for all updates at once (see joined_rows)
        joined_ids = JoinedIds(maps.ids)
        whole_maps = np.array([i for i in shown if whole[i]], dtype=np.int64)
        self._send_joined_ellipses(
            style.LANDMARK_ELLIPSES,
            rows,
            corrected[whole_maps],
            maps,
            ranges(maps.starts[whole_maps], maps.starts[whole_maps + 1]),
            maps.counts[whole_maps],
            joined_ids,
        )
        # Beyond a small map: the observed landmarks' own ellipses at the updates between
        # two of the whole map's (and an empty row, clearing them, at those).
        at_sparse = np.flatnonzero(sparse)
        own = at_sparse[~whole[at_sparse]]
        tables: dict[int, IdRows | None] = {}  # id lookups of the batch's maps
        observed_rows, own_counts = joined_rows(maps, own, "observed", tables)
        counts = np.zeros(len(at_sparse), dtype=np.int64)
        counts[~whole[at_sparse]] = own_counts
        self._send_joined_ellipses(
            style.LANDMARK_ELLIPSES_OBSERVED,
            rows,
            corrected[at_sparse],
            maps,
            observed_rows,
            counts,
            joined_ids,
        )
        # the first sightings of a log with ids, at once (a scan's: see FirstSightings)
        with_new = np.array(
            [i for i in np.flatnonzero(batch.observed.new[corrected]).tolist()
             if maps.association(i) is None],
            dtype=np.int64,
        )  # fmt: skip
        new_rows, new_counts = joined_rows(maps, with_new, "initialised", tables)
        self._send_joined_ellipses(
            style.LANDMARK_INITIAL, rows, corrected[with_new], maps, new_rows, new_counts,
            joined_ids, INITIAL_POINTS,
        )  # fmt: skip
        self._first_sightings.send(
            rows, corrected, maps, batch.observed.new[corrected], joined_ids, tables
        )

    def _sparse_maps(self, batch: Batch) -> BoolArray:
        """Whether each of the batch's updates logs its whole map only now and then (see
        :meth:`admit`)."""
        maps = batch.maps
        if self._detail:
            return np.zeros(len(maps.ids), dtype=bool)
        large: BoolArray = maps.counts > SMALL_MAP
        if self._thinned:
            large |= ~np.isnan(maps.times)
        return large

    def mark_final(self) -> None:
        """The run ends: its last update's map is to be shown exactly."""
        if self.last_update is not None:
            self._final_event = self.last_update[0].event

    def finish(self) -> EventRecord | None:
        """The whole map at the last update, exactly, once the batches are sent; the
        last update if its whole map's errors are still to be logged."""
        if self.last_update is None:
            return None
        record, whole = self.last_update
        errors_due = None
        if not whole or self._map_shown_event != record.event:
            rows = self._canvas.clock.row(record)
            if self._map_shown_event != record.event:  # its points too, exactly
                self._send_points(
                    rows.all,
                    record.landmark_ids,
                    record.landmarks_xy,
                    np.array([record.n_landmarks]),
                )
                self._map_shown_event = record.event
            if not whole:
                self.last_update = (record, True)
                errors_due = record
            self._send_ellipses(
                style.LANDMARK_ELLIPSES, rows, [(0, record, landmark_rows(record, None))]
            )
        if record.n_landmarks:  # frame the final map's ellipses, not only its points
            self._canvas.grow_bounds(ellipse_extent(record.landmarks_xy, record.landmark_covs))
        return errors_due

    def _map_changes(self, batch: Batch, sparse: BoolArray) -> IntArray:
        """The batch's updates (indices into its ``corrected`` rows) whose landmarks
        (points and whole-map ellipses) are logged.

        Only where the map grew or where some landmark's point or 3-sigma outline moved
        by more than ``MAP_TOLERANCE`` of its ellipse's semi-major axis since it was last
        logged: in between the viewer shows the latest, within that tolerance of the true
        state. A large map's points so (its ellipses have their own cadence, and the
        updates that log them log the points too); everything at every update with
        ``--detail``.
        """
        maps, corrected = batch.maps, batch.corrected
        if self._canvas.detail:
            self._map_shown = None
            self._map_shown_event = int(batch.rows.events[corrected[-1]])
            return np.arange(len(corrected))
        events = batch.rows.events[corrected]
        forced = batch.whole[corrected] & sparse
        if self._final_event is not None:
            forced |= events == self._final_event
        shown, self._map_shown, event = map_changes(maps, events, forced, self._map_shown)
        if event is not None:
            self._map_shown_event = event
        return shown

    def _send_points(
        self,
        times: list[rr.TimeColumnLike],
        ids: IntArray,
        positions: FloatArray,
        counts: IntArray,
    ) -> None:
        """All landmark estimates of some updates, one row each (``counts[i]`` of the
        joined ``ids`` and ``positions``), class id = landmark id; their labels beside
        (see :mod:`.labels`), hanging from each."""
        if len(positions):
            self._canvas.grow_bounds(positions)
        self._canvas.send(
            style.LANDMARKS,
            times,
            [
                column(rr.Points2D.descriptor_positions(), xy(positions), counts),
                self._canvas.identify(rr.Points2D, ids, counts),
            ],
        )
        self._labels.send(times, ids, positions, counts)

    def _send_ellipses(
        self,
        entity: str,
        rows: Rows,
        batches: list[tuple[int, EventRecord, IntArray]],
        points: int = MAP_POINTS,
    ) -> None:
        """3-sigma outlines of some landmarks of some updates, class id = landmark id.

        :param batches: per row to send, its index in ``rows``, the update and the rows of
            the landmarks to draw
        :param points: the most points of an outline
        """
        if not batches:
            return
        counts = np.array([len(picked) for _, _, picked in batches])
        # one outline size per send, from the largest batch (see ellipses.outline_points)
        n_points = min(points, outline_points(int(counts.max())))
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
        self._canvas.send_strips(entity, rows, at, outlines, counts, np.concatenate(ids))

    def _send_joined_ellipses(
        self,
        entity: str,
        rows: Rows,
        at: IntArray,
        maps: Maps,
        joined_rows: IntArray,
        counts: IntArray,
        joined_ids: JoinedIds,
        points: int = MAP_POINTS,
    ) -> None:
        """:meth:`_send_ellipses` of landmarks given by their rows in a batch's joined
        maps: ``counts[i]`` of ``joined_rows`` at the row ``at[i]`` of ``rows``.

        :param joined_ids: the landmark id of each joined row
        """
        if not len(at):
            return
        n_points = min(points, outline_points(int(counts.max())))
        outlines = ellipse_outlines(maps.xy[joined_rows], maps.covs[joined_rows], n_points=n_points)
        self._canvas.send_strips(entity, rows, at, outlines, counts, joined_ids.of(joined_rows))
