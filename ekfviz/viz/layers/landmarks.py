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

import itertools
import math

import numpy as np
import rerun as rr

from ekfviz.core.records import EventKind, EventRecord
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.ellipses import (
    ellipse_extent,
    ellipse_outlines,
    ellipse_shape_columns,
    outline_points,
)
from ekfviz.viz.layers.arrow import column, radius, xy
from ekfviz.viz.layers.batch import Batch, Maps, landmark_rows
from ekfviz.viz.layers.canvas import Canvas, Rows
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
# the map's window search (MapLayer._changes_of_one_map): after an update logged, look this
# many updates ahead at least (twice the last gap between two logged, if more)
WINDOW_MIN = 16


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
        rows, corrected, maps = batch.rows, batch.corrected, batch.maps
        records = maps.records
        whole = batch.whole[corrected]
        sparse = self._sparse_maps(batch)
        shown = self._map_changes(batch, sparse).tolist()
        if shown:
            self._send_points(rows.pick(corrected[shown]), [records[i] for i in shown])
        # the ellipses of every update below by their rows in the batch's joined maps
        # (maps.xy, maps.covs), found for all updates at once (see _joined_rows)
        joined_ids = _JoinedIds(records)
        whole_maps = np.array([i for i in shown if whole[i]], dtype=np.int64)
        self._send_joined_ellipses(
            style.LANDMARK_ELLIPSES,
            rows,
            corrected[whole_maps],
            maps,
            _ranges(maps.starts[whole_maps], maps.starts[whole_maps + 1]),
            maps.counts[whole_maps],
            joined_ids,
        )
        # Beyond a small map: the observed landmarks' own ellipses at the updates between
        # two of the whole map's (and an empty row, clearing them, at those).
        at_sparse = np.flatnonzero(sparse)
        own = at_sparse[~whole[at_sparse]]
        tables: dict[int, _IdRows | None] = {}  # id lookups of the batch's maps
        joined_rows, own_counts = _joined_rows(maps, own, "observed", tables)
        counts = np.zeros(len(at_sparse), dtype=np.int64)
        counts[~whole[at_sparse]] = own_counts
        self._send_joined_ellipses(
            style.LANDMARK_ELLIPSES_OBSERVED,
            rows,
            corrected[at_sparse],
            maps,
            joined_rows,
            counts,
            joined_ids,
        )
        with_new = np.flatnonzero(batch.observed.new[corrected]).tolist()
        self._send_ellipses(
            style.LANDMARK_INITIAL,
            rows,
            [
                (int(corrected[i]), record, landmark_rows(record, "initialised"))
                for i in with_new
                if (record := records[i]).association is None
            ],
            INITIAL_POINTS,
        )
        self._send_confirmed_first_sightings(
            rows, corrected, maps, batch.observed.new[corrected], joined_ids, tables
        )

    def _sparse_maps(self, batch: Batch) -> BoolArray:
        """:meth:`sparse` of each of the batch's updates, in a few numpy calls."""
        maps = batch.maps
        if self._detail:
            return np.zeros(len(maps.records), dtype=bool)
        large = maps.counts > SMALL_MAP
        if self._thinned:
            large |= np.array([record.time is not None for record in maps.records], dtype=bool)
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
            self._map_shown_event = maps.records[-1].event
            return np.arange(len(corrected))
        # the shapes and tolerances of every landmark of every update at once, a row per
        # quantity (see ellipse_shape_columns)
        every = ellipse_shape_columns(maps.xy, maps.covs)
        # the point at angle t of an outline, m + 3 sqrt(C) [cos t, sin t], moves by at most
        # |dm| + 3 ||d sqrt(C)||_F; the semi-major axis is at least 3 ||sqrt(C)||_F / sqrt(2)
        tolerance = MAP_TOLERANCE * _root_norms(every[2:] * every[2:]) / math.sqrt(2.0)
        events = batch.rows.events[corrected]
        forced = batch.whole[corrected] & sparse
        if self._final_event is not None:
            forced |= events == self._final_event
        shown: list[IntArray] = []
        for start, end in itertools.pairwise([*maps.runs(), len(corrected)]):
            first, last = int(maps.starts[start]), int(maps.starts[end])
            n = int(maps.counts[start])
            shown.append(
                start
                + self._changes_of_one_map(
                    maps.records[start:end],
                    events[start:end],
                    forced[start:end].copy(),
                    every[:, first:last].reshape(6, end - start, n),
                    tolerance[first:last].reshape(end - start, n),
                )
            )
        return np.concatenate(shown)

    def _changes_of_one_map(
        self,
        records: list[EventRecord],
        events: IntArray,
        forced: BoolArray,
        every: FloatArray,
        tolerance: FloatArray,
    ) -> IntArray:
        """:meth:`_map_changes` of updates of the same landmarks, their shapes ``every``
        (6, u, n: a row per quantity) and tolerances (u, n), in a few numpy calls: from
        each update logged, the first that has moved from it, looked for in windows that
        grow while none has (``forced``: the updates logged whatever they moved)."""
        if self._map_shown is None or not np.array_equal(
            self._map_shown[0], records[0].landmark_ids
        ):
            forced[0] = True
        shown: list[int] = []
        # the first window as long as twice the last gap between two updates logged: the
        # same updates found in fewer numpy calls where the map moves at a steady pace
        k, gap = 0, 8
        window = 2 * gap
        while k < len(records):
            if not forced[k]:
                before = self._map_shown[1]  # type: ignore[index]
                ahead = every[:, k : k + window] - before[:, None, :]
                squares = np.multiply(ahead, ahead, out=ahead)
                moved = _root_norms(squares[:2]) + _root_norms(squares[2:])
                due = forced[k : k + window] | ~np.all(moved <= tolerance[k : k + window], axis=1)
                hits = np.flatnonzero(due)
                if not hits.size:
                    k, window = k + len(due), 2 * window
                    continue
                k += int(hits[0])
            if shown:
                gap = k - shown[-1]
            self._map_shown = (records[k].landmark_ids, every[:, k].copy())
            self._map_shown_event = int(events[k])
            shown.append(k)
            k, window = k + 1, max(WINDOW_MIN, 2 * gap)
        return np.array(shown, dtype=np.int64)

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

    def _send_joined_ellipses(
        self,
        entity: str,
        rows: Rows,
        at: IntArray,
        maps: Maps,
        joined_rows: IntArray,
        counts: IntArray,
        joined_ids: _JoinedIds,
    ) -> None:
        """:meth:`_send_ellipses` of landmarks given by their rows in a batch's joined
        maps: ``counts[i]`` of ``joined_rows`` at the row ``at[i]`` of ``rows``.

        :param joined_ids: the landmark id of each joined row
        """
        if not len(at):
            return
        n_points = min(MAP_POINTS, outline_points(int(counts.max())))
        outlines = ellipse_outlines(maps.xy[joined_rows], maps.covs[joined_rows], n_points=n_points)
        self._canvas.send_strips(entity, rows, at, outlines, counts, joined_ids.of(joined_rows))

    def _send_confirmed_first_sightings(
        self,
        rows: Rows,
        corrected: IntArray,
        maps: Maps,
        new_counts: IntArray,
        joined_ids: _JoinedIds,
        tables: dict[int, _IdRows | None],
    ) -> None:
        """With id-less scans, the first-sighting outline of a landmark appears when the
        association confirms it: most new landmarks of a cluttered scan are removed
        again, and their outlines would bury the map (Victoria Park: 600 of 900).

        :param new_counts: (u,) how many landmarks each update initialised
        :param joined_ids: the landmark id of each row of the joined maps
        :param tables: the id lookups of the batch's maps (see :func:`_joined_rows`)
        """
        records = maps.records
        picks = np.array(
            [i for i in np.flatnonzero(new_counts).tolist() if records[i].association is not None],
            dtype=np.int64,
        )
        landmark_ids = joined_ids.all() if len(picks) else np.zeros(0, dtype=np.int64)
        # the rows of each update's new landmarks in the joined maps, for all at once
        new_rows, new_per_update = _joined_rows(maps, picks, "initialised", tables)
        new_ends = np.cumsum(new_per_update).tolist()
        new_of = {
            i: new_rows[end - count : end].tolist()
            for i, end, count in zip(picks.tolist(), new_ends, new_per_update.tolist(), strict=True)
        }
        at: list[int] = []
        means: list[FloatArray] = []
        covs: list[FloatArray] = []
        ids: list[list[int]] = []
        for u, (k, record) in enumerate(zip(corrected.tolist(), records, strict=True)):
            association = record.association
            if association is None:
                continue
            for row in new_of.get(u, ()):
                self._first_sightings[int(landmark_ids[row])] = (
                    maps.xy[row].copy(),
                    maps.covs[row].copy(),
                )
            if len(association.removed):
                for landmark_id in association.removed.tolist():
                    self._first_sightings.pop(int(landmark_id), None)
            if not len(association.confirmed):
                continue
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


class _JoinedIds:
    """The landmark id of each row of a batch's joined maps, joined at the first ask."""

    def __init__(self, records: list[EventRecord]) -> None:
        self._records = records
        self._ids: IntArray | None = None

    def all(self) -> IntArray:
        if self._ids is None:
            self._ids = np.concatenate([record.landmark_ids for record in self._records])
        return self._ids

    def of(self, joined_rows: IntArray) -> IntArray:
        ids: IntArray = self.all()[joined_rows]
        return ids


def _ranges(starts: IntArray, ends: IntArray) -> IntArray:
    """The integers of the ranges [starts[i], ends[i]), range after range."""
    lengths = ends - starts
    # the k-th integer overall is k plus its range's start less where that range begins
    offsets = np.repeat(starts - (np.cumsum(lengths) - lengths), lengths)
    ranges: IntArray = np.arange(len(offsets), dtype=np.int64) + offsets
    return ranges


def _joined_rows(
    maps: Maps, picks: IntArray, which: str, tables: dict[int, _IdRows | None]
) -> tuple[IntArray, IntArray]:
    """:func:`~.batch.landmark_rows` of the updates ``picks`` for all at once: their rows
    in the joined maps (``maps.xy``, ``maps.covs``), update after update, each update's in
    ascending order, and how many each update has.

    The ids observed (or initialised) at every update looked up at once: in a table from
    id to row per run of updates of one map (:meth:`Maps.runs`), the tables of small
    non-negative ids joined into one array; a sorted search per map otherwise, and the
    definition update by update where a map's ids repeat. ``np.isin`` per update cost a
    numpy call each.

    :param picks: (p,) ascending indices into ``maps.records``
    :param which: ``"observed"`` or ``"initialised"``
    :param tables: the lookups made so far, by the run's first update (filled here)
    :return: the joined rows, and (p,) the count per update
    """
    records, starts = maps.records, maps.starts
    if not len(picks):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    runs = np.array(maps.runs(), dtype=np.int64)
    pick_list = picks.tolist()
    found: list[IntArray] = [np.zeros(0, dtype=np.int64)]
    observations = [records[i].observations for i in pick_list]
    # an update without observations: all of its landmarks
    found += [
        np.arange(starts[i], starts[i + 1])
        for i, seen in zip(pick_list, observations, strict=True)
        if seen is None
    ]
    observed = [seen for seen in observations if seen is not None]
    owners = picks[np.array([seen is not None for seen in observations], dtype=bool)]
    ids_each = [seen.ids for seen in observed]
    lengths = np.fromiter(map(len, ids_each), np.int64, len(ids_each))
    wanted = np.concatenate([np.zeros(0, dtype=np.int64), *ids_each]).astype(np.int64)
    owner = np.repeat(owners, lengths)  # the update of each id wanted
    if which != "observed":  # the initialised ones, picked all at once
        new = np.concatenate([np.zeros(0, dtype=bool), *(seen.initialised for seen in observed)])
        wanted, owner = wanted[new], owner[new]
    owner_run = np.searchsorted(runs, owner, side="right") - 1
    rows = np.full(len(wanted), -1, dtype=np.int64)
    # the dense tables of the runs asked, one after another: a run's at its offset
    dense: list[IntArray] = []
    offset = np.zeros(len(runs), dtype=np.int64)
    width = np.zeros(len(runs), dtype=np.int64)  # 0: no dense table
    cursor = 0
    for run in np.unique(owner_run).tolist():
        first_update = int(runs[run])
        if first_update not in tables:
            tables[first_update] = _IdRows.of(records[first_update].landmark_ids)
        table = tables[first_update]
        if table is not None and table.table is not None:
            dense.append(table.table)
            offset[run], width[run] = cursor, len(table.table)
            cursor += len(table.table)
            continue
        in_run = owner_run == run
        if table is not None:  # ids far apart: a sorted search
            rows[in_run] = table.rows(wanted[in_run])
            continue
        # ids not distinct: the definition, update by update
        for i in np.unique(owner[in_run]).tolist():
            found.append(starts[i] + landmark_rows(records[i], which))
    if dense:
        tables_joined = np.concatenate(dense)
        inside = (wanted >= 0) & (wanted < width[owner_run])
        rows[inside] = tables_joined[offset[owner_run[inside]] + wanted[inside]]
    hit = rows >= 0
    found.append(starts[owner[hit]] + rows[hit])
    # distinct and in order: update after update (their rows are apart), ascending within
    joined = np.unique(np.concatenate(found))
    counts = np.searchsorted(joined, starts[picks + 1]) - np.searchsorted(joined, starts[picks])
    return joined, counts.astype(np.int64)


class _IdRows:
    """The row of each landmark id in one map's ids: a table where the ids are small
    non-negative integers, a sorted search otherwise."""

    def __init__(self, ids: IntArray, table: IntArray | None, order: IntArray | None) -> None:
        self._ids = ids
        self.table = table  # by id, its row (-1: none), where the ids are small
        self._order = order

    @staticmethod
    def of(ids: IntArray) -> _IdRows | None:
        """The lookup of the map ``ids``; None if they are not distinct."""
        ids = np.asarray(ids, dtype=np.int64)
        if not len(ids):
            return _IdRows(ids, np.full(0, -1, dtype=np.int64), None)
        low, high = int(ids.min()), int(ids.max())
        if low >= 0 and high < 4 * len(ids) + 1024:
            table = np.full(high + 1, -1, dtype=np.int64)
            table[ids] = np.arange(len(ids))
            if int(np.count_nonzero(table >= 0)) != len(ids):
                return None
            return _IdRows(ids, table, None)
        order = np.argsort(ids, kind="stable")
        if bool((ids[order][1:] == ids[order][:-1]).any()):
            return None
        return _IdRows(ids, None, order)

    def rows(self, wanted: IntArray) -> IntArray:
        """The row of each of ``wanted``, -1 where it is not in the map."""
        wanted = np.asarray(wanted, dtype=np.int64)
        rows: IntArray = np.full(len(wanted), -1, dtype=np.int64)
        if self.table is not None:
            inside = (wanted >= 0) & (wanted < len(self.table))
            rows[inside] = self.table[wanted[inside]]
            return rows
        assert self._order is not None
        ordered = self._ids[self._order]
        at = np.minimum(np.searchsorted(ordered, wanted), len(ordered) - 1)
        hit = ordered[at] == wanted
        rows[hit] = self._order[at[hit]]
        return rows


def _root_norms(squares: FloatArray) -> FloatArray:
    """The Euclidean norms of vectors given by their squared entries, a row per entry
    (the vectors along axis 0): ``np.linalg.norm`` of the vectors to the bit, as it
    sums them (the squares in order, left to right; see tests/test_send_columns.py),
    from contiguous rows instead of a strided last axis."""
    total = squares[0].copy()
    for row in squares[1:]:
        total += row
    norms: FloatArray = np.sqrt(total, out=total)
    return norms
