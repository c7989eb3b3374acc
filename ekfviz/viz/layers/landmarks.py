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
one, the whole map every ``MAP_EVERY_S`` seconds of log time. With truth, the error
series of a landmark get a value whenever its ellipse is logged; ``detail=True`` logs
every ellipse and error at every update.
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from ekfviz.core.records import EventKind, EventRecord
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.ellipses import ellipse_extent, ellipse_outlines, outline_points
from ekfviz.viz.layers.arrow import column, radius, xy
from ekfviz.viz.layers.batch import Batch, landmark_rows
from ekfviz.viz.layers.canvas import NO_ROWS, Canvas, Rows
from ekfviz.viz.layers.labels import LabelsLayer

SMALL_MAP = 32  # up to this many landmarks, every ellipse at every update
MAP_EVERY_STEPS = 25  # beyond: the whole map every this many steps
# A small map is logged again only once some landmark's point or outline would move by
# more than this fraction of its ellipse's semi-major axis (the viewer shows the latest).
MAP_TOLERANCE = 0.02
MAP_POINTS = 16  # points of a landmark outline: within 2 % of its radius, as MAP_TOLERANCE
# a first-sighting outline is logged once, and on real data it is metres wide: 16 points
# showed corners there, 32 do not (within 0.5 % of its radius)
INITIAL_POINTS = 32
MAP_EVERY_S = 5.0  # ... and in a thinned timestamped log, every this many seconds of log time

Update = tuple[int, EventRecord, bool]  # a batch's row, the update, whether whole map


def shapes(means_xy: FloatArray, covs: FloatArray) -> FloatArray:
    """(K, 6) rows [mx, my, 3 sqrt(C) flattened]: a 3-sigma ellipse by its mean and the
    symmetric square root of its covariance (unique, unlike the eigenvectors' signs),
    sqrt(C) = (C + sqrt(det C) I) / sqrt(tr C + 2 sqrt(det C)) for 2x2."""
    root_det = np.sqrt(np.clip(np.linalg.det(covs), 0.0, None))
    scale = np.sqrt(np.clip(np.trace(covs, axis1=1, axis2=2) + 2.0 * root_det, 0.0, None))
    roots = (covs + root_det[:, None, None] * np.eye(2)) / np.where(scale > 0, scale, 1.0)[
        :, None, None
    ]
    return np.column_stack([means_xy, 3.0 * roots.reshape(-1, 4)])


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
        self.last_update: tuple[EventRecord, bool] | None = None
        # the small map as last logged: its ids and shapes rows, and at which event
        self._map_shown: tuple[IntArray, FloatArray] | None = None
        self._map_shown_event: int | None = None
        self._final_event: int | None = None  # the last update's, at finish: shown exactly
        # id-less scans: a new landmark's first-sighting outline (mean, covariance), held
        # until the association confirms it (drawn then) or removes it (dropped)
        self._first_sightings: dict[int, tuple[FloatArray, FloatArray]] = {}

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

    def sparse(self, record: EventRecord) -> bool:
        """Whether an update logs the whole map's ellipses only now and then (and the
        observed landmarks' at every update): beyond ``SMALL_MAP`` landmarks, and in a
        timestamped log whose predicts are thinned (see :mod:`ekfviz.viz.thinning`)."""
        return not self._detail and (
            len(record.landmark_ids) > SMALL_MAP or (self._thinned and record.time is not None)
        )

    def admit(self, record: EventRecord) -> bool:
        """Take note of a record's map; whether it logs the whole map's ellipses."""
        if record.kind is EventKind.PREDICT:
            return False
        ids = record.landmark_ids
        # the core's records share one ids array until the map grows
        if ids is not self._last_ids and (
            self._last_ids is None or not np.array_equal(ids, self._last_ids)
        ):
            self._labels.annotate(ids)
            self._last_ids = ids
            self.seen_ids.update(ids.tolist())
        whole_map = (
            not self.sparse(record)
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
        self.last_update = (record, whole_map)
        return whole_map

    def send(self, batch: Batch) -> None:
        """The points and ellipses of the batch's updates (see :meth:`_map_changes`)."""
        if not batch.corrected.size:
            return
        rows = batch.rows
        updates = batch.updates()
        shown = self._map_changes(updates)
        if shown:
            self._send_points(rows.pick([k for k, _, _ in shown]), [r for _, r, _ in shown])
        self._send_ellipses(
            style.LANDMARK_ELLIPSES,
            rows,
            [(k, record, landmark_rows(record, None)) for k, record, whole in shown if whole],
        )
        # Beyond a small map: the observed landmarks' own ellipses at the updates between
        # two of the whole map's (and an empty row, clearing them, at those).
        self._send_ellipses(
            style.LANDMARK_ELLIPSES_OBSERVED,
            rows,
            [
                (k, record, NO_ROWS if whole else landmark_rows(record, "observed"))
                for k, record, whole in updates
                if self.sparse(record)
            ],
        )
        new = batch.observed.new
        self._send_ellipses(
            style.LANDMARK_INITIAL,
            rows,
            [
                (k, record, landmark_rows(record, "initialised"))
                for k, record, _ in updates
                if new[k] and record.association is None
            ],
            INITIAL_POINTS,
        )
        self._send_confirmed_first_sightings(rows, updates)

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
                self._send_points(rows.all, [record])
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

    def _map_changes(self, updates: list[Update]) -> list[Update]:
        """The updates whose landmarks (points and whole-map ellipses) are logged.

        Only where the map grew or where some landmark's point or 3-sigma outline moved
        by more than ``MAP_TOLERANCE`` of its ellipse's semi-major axis since it was last
        logged: in between the viewer shows the latest, within that tolerance of the true
        state. A large map's points so (its ellipses have their own cadence, and the
        updates that log them log the points too); everything at every update with
        ``--detail``.
        """
        shown: list[Update] = []
        if self._canvas.detail:
            for k, record, whole in updates:
                shown.append((k, record, whole))
                self._map_shown = None
                self._map_shown_event = record.event
            return shown
        start = 0
        while start < len(updates):  # runs of updates of one map (the same landmark ids)
            ids = updates[start][1].landmark_ids
            end = start + 1
            while end < len(updates) and (
                (other := updates[end][1].landmark_ids) is ids or np.array_equal(other, ids)
            ):
                end += 1
            shown += self._changes_of_one_map(updates[start:end])
            start = end
        return shown

    def _changes_of_one_map(self, updates: list[Update]) -> list[Update]:
        """:meth:`_map_changes` of updates of the same landmarks, in a few numpy calls: the
        shapes of all at once, then from each update logged, the first that has moved
        from it, looked for in windows that grow while none has."""
        records = [record for _, record, _ in updates]
        n = records[0].n_landmarks
        every = shapes(
            np.concatenate([record.landmarks_xy for record in records]),
            np.concatenate([record.landmark_covs for record in records]),
        ).reshape(len(records), n, 6)
        # the point at angle t of an outline, m + 3 sqrt(C) [cos t, sin t], moves by at most
        # |dm| + 3 ||d sqrt(C)||_F; the semi-major axis is at least 3 ||sqrt(C)||_F / sqrt(2)
        tolerance = MAP_TOLERANCE * np.linalg.norm(every[:, :, 2:], axis=2) / math.sqrt(2.0)
        forced = np.array(
            [
                record.event == self._final_event or (whole and self.sparse(record))
                for _, record, whole in updates
            ]
        )
        if self._map_shown is None or not np.array_equal(
            self._map_shown[0], records[0].landmark_ids
        ):
            forced[0] = True
        shown: list[Update] = []
        k, window = 0, 16
        while k < len(records):
            if not forced[k]:
                before = self._map_shown[1]  # type: ignore[index]
                ahead = every[k : k + window]
                moved = np.linalg.norm(ahead[:, :, :2] - before[:, :2], axis=2) + np.linalg.norm(
                    ahead[:, :, 2:] - before[:, 2:], axis=2
                )
                due = forced[k : k + window] | ~np.all(moved <= tolerance[k : k + window], axis=1)
                hits = np.flatnonzero(due)
                if not hits.size:
                    k, window = k + len(ahead), 2 * window
                    continue
                k += int(hits[0])
            self._map_shown = (records[k].landmark_ids, every[k])
            self._map_shown_event = records[k].event
            shown.append(updates[k])
            k, window = k + 1, 16
        return shown

    def _send_points(self, times: list[rr.TimeColumnLike], updates: list[EventRecord]) -> None:
        """All landmark estimates of some updates, one row each, class id = landmark id;
        their labels beside (see :mod:`.labels`)."""
        ids = np.concatenate([record.landmark_ids for record in updates])
        positions = np.concatenate([record.landmarks_xy for record in updates])
        counts = np.array([record.n_landmarks for record in updates])
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
        self._labels.send(times, updates, ids, positions, counts)

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

    def _send_confirmed_first_sightings(self, rows: Rows, updates: list[Update]) -> None:
        """With id-less scans, the first-sighting outline of a landmark appears when the
        association confirms it: most new landmarks of a cluttered scan are removed
        again, and their outlines would bury the map (Victoria Park: 600 of 900)."""
        at, means, covs, ids = [], [], [], []
        for k, record, _ in updates:
            association = record.association
            if association is None:
                continue
            if record.observations is not None and record.observations.initialised.any():
                rows_new = landmark_rows(record, "initialised")
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
        n_points = min(INITIAL_POINTS, outline_points(int(counts.max())))
        outlines = ellipse_outlines(np.array(means), np.array(covs), n_points=n_points)
        self._canvas.send_strips(
            style.LANDMARK_INITIAL, rows, np.array(at, dtype=np.int64), outlines, counts,
            np.array([i for group in ids for i in group], dtype=np.int64),
        )  # fmt: skip
