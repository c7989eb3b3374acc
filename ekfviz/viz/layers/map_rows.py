"""The rows of a batch's joined maps, and which updates log their map (the window search).

Numpy on the batch's joined maps (:class:`~ekfviz.viz.layers.batch.Maps`) for
:mod:`.landmarks`: the rows of the landmarks each update observed or initialised, found
for all updates at once, and the updates whose landmarks moved by more than
``MAP_TOLERANCE`` of their ellipses since the map was last logged.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from ekfviz.core.batch import ranges
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.viz.ellipses import ellipse_shape_columns
from ekfviz.viz.layers.batch import Maps, map_rows_of

# A small map is logged again only once some landmark's point or outline would move by
# more than this fraction of its ellipse's semi-major axis (the viewer shows the latest).
MAP_TOLERANCE = 0.02
# the window search: after an update logged, look this many updates ahead at least
# (twice the last gap between two logged, if more)
WINDOW_MIN = 16

Shown = tuple[IntArray, FloatArray]  # the map last logged: its ids and shapes (6, n)


def map_changes(
    maps: Maps, events: IntArray, forced: BoolArray, shown: Shown | None
) -> tuple[IntArray, Shown | None, int | None]:
    """The updates of ``maps`` whose landmarks are logged (see
    :meth:`.landmarks.MapLayer._map_changes`): the first update of a map of other ids than
    ``shown``'s, the ``forced`` ones, and any whose landmarks moved from the last logged.

    :param events: (u,) the updates' events; :param forced: (u,) logged whatever moved
    :param shown: the map last logged before these updates, None if none
    :return: the updates logged (indices), the map last logged and its event (None if
        none of these updates was)
    """
    # the shapes and tolerances of every landmark of every update at once, a row per
    # quantity (see ellipse_shape_columns)
    every = ellipse_shape_columns(maps.xy, maps.covs)
    # the point at angle t of an outline, m + 3 sqrt(C) [cos t, sin t], moves by at most
    # |dm| + 3 ||d sqrt(C)||_F; the semi-major axis is at least 3 ||sqrt(C)||_F / sqrt(2)
    tolerance = MAP_TOLERANCE * root_norms(every[2:] * every[2:]) / math.sqrt(2.0)
    logged: list[IntArray] = []
    shown_event: int | None = None
    for start, end in itertools.pairwise([*maps.runs(), len(maps.ids)]):
        first, last = int(maps.starts[start]), int(maps.starts[end])
        n = int(maps.counts[start])
        of_map, shown, event = _changes_of_one_map(
            maps.ids[start:end],
            events[start:end],
            forced[start:end].copy(),
            every[:, first:last].reshape(6, end - start, n),
            tolerance[first:last].reshape(end - start, n),
            shown,
        )
        logged.append(start + of_map)
        shown_event = event if event is not None else shown_event
    return np.concatenate(logged), shown, shown_event


def _changes_of_one_map(
    ids: list[IntArray],
    events: IntArray,
    forced: BoolArray,
    every: FloatArray,
    tolerance: FloatArray,
    shown: Shown | None,
) -> tuple[IntArray, Shown | None, int | None]:
    """:func:`map_changes` of updates of the same landmarks, their shapes ``every``
    (6, u, n: a row per quantity) and tolerances (u, n), in a few numpy calls: from each
    update logged, the first that has moved from it, looked for in windows that grow
    while none has (``forced``: the updates logged whatever they moved)."""
    if shown is None or not np.array_equal(shown[0], ids[0]):
        forced[0] = True
    logged: list[int] = []
    event: int | None = None
    # the first window as long as twice the last gap between two updates logged: the
    # same updates found in fewer numpy calls where the map moves at a steady pace
    k, gap = 0, 8
    window = 2 * gap
    while k < len(ids):
        if not forced[k]:
            assert shown is not None  # the first update is forced without one
            ahead = every[:, k : k + window] - shown[1][:, None, :]
            squares = np.multiply(ahead, ahead, out=ahead)
            moved = root_norms(squares[:2]) + root_norms(squares[2:])
            due = forced[k : k + window] | ~np.all(moved <= tolerance[k : k + window], axis=1)
            hits = np.flatnonzero(due)
            if not hits.size:
                k, window = k + len(due), 2 * window
                continue
            k += int(hits[0])
        if logged:
            gap = k - logged[-1]
        shown = (ids[k], every[:, k].copy())
        event = int(events[k])
        logged.append(k)
        k, window = k + 1, max(WINDOW_MIN, 2 * gap)
    return np.array(logged, dtype=np.int64), shown, event


class JoinedIds:
    """The landmark id of each row of a batch's joined maps, joined at the first ask."""

    def __init__(self, each: list[IntArray]) -> None:
        self._each = each  # the ids of each map
        self._ids: IntArray | None = None

    def all(self) -> IntArray:
        if self._ids is None:
            self._ids = np.concatenate(self._each)
        return self._ids

    def of(self, joined_rows: IntArray) -> IntArray:
        ids: IntArray = self.all()[joined_rows]
        return ids


def joined_rows(
    maps: Maps, picks: IntArray, which: str, tables: dict[int, IdRows | None]
) -> tuple[IntArray, IntArray]:
    """:func:`~.batch.landmark_rows` of the updates ``picks`` for all at once: their rows
    in the joined maps (``maps.xy``, ``maps.covs``), update after update, each update's in
    ascending order, and how many each update has.

    The ids observed (or initialised) at every update looked up at once: in a table from
    id to row per run of updates of one map (:meth:`Maps.runs`), the tables of small
    non-negative ids joined into one array; a sorted search per map otherwise, and the
    definition update by update where a map's ids repeat. ``np.isin`` per update cost a
    numpy call each.

    :param picks: (p,) ascending indices into the maps (``maps.ids``)
    :param which: ``"observed"`` or ``"initialised"``
    :param tables: the lookups made so far, by the run's first update (filled here)
    :return: the joined rows, and (p,) the count per update
    """
    starts = maps.starts
    if not len(picks):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    runs = np.array(maps.runs(), dtype=np.int64)
    found: list[IntArray] = [np.zeros(0, dtype=np.int64)]
    # an update without observations: all of its landmarks
    without = picks[~maps.has_observations[picks]]
    found += [np.arange(starts[i], starts[i + 1]) for i in without.tolist()]
    owners = picks[maps.has_observations[picks]]
    first, end = maps.observed_starts[owners], maps.observed_starts[owners + 1]
    flat = ranges(first, end)
    wanted = maps.observed_ids[flat]
    owner = np.repeat(owners, end - first)  # the update of each id wanted
    if which != "observed":  # the initialised ones, picked all at once
        new = maps.observed_new[flat]
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
            tables[first_update] = IdRows.of(maps.ids[first_update])
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
            observed_ids, initialised = maps.observed_of(i)
            found.append(starts[i] + map_rows_of(maps.ids[i], observed_ids, which, initialised))
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


class IdRows:
    """The row of each landmark id in one map's ids: a table where the ids are small
    non-negative integers, a sorted search otherwise."""

    def __init__(self, ids: IntArray, table: IntArray | None, order: IntArray | None) -> None:
        self._ids = ids
        self.table = table  # by id, its row (-1: none), where the ids are small
        self._order = order

    @staticmethod
    def of(ids: IntArray) -> IdRows | None:
        """The lookup of the map ``ids``; None if they are not distinct."""
        ids = np.asarray(ids, dtype=np.int64)
        if not len(ids):
            return IdRows(ids, np.full(0, -1, dtype=np.int64), None)
        low, high = int(ids.min()), int(ids.max())
        if low >= 0 and high < 4 * len(ids) + 1024:
            table = np.full(high + 1, -1, dtype=np.int64)
            table[ids] = np.arange(len(ids))
            if int(np.count_nonzero(table >= 0)) != len(ids):
                return None
            return IdRows(ids, table, None)
        order = np.argsort(ids, kind="stable")
        if bool((ids[order][1:] == ids[order][:-1]).any()):
            return None
        return IdRows(ids, None, order)

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


def root_norms(squares: FloatArray) -> FloatArray:
    """The Euclidean norms of vectors given by their squared entries, a row per entry
    (the vectors along axis 0): ``np.linalg.norm`` of the vectors to the bit, as it
    sums them (the squares in order, left to right; see tests/test_send_columns.py),
    from contiguous rows instead of a strided last axis."""
    total = squares[0].copy()
    for row in squares[1:]:
        total += row
    norms: FloatArray = np.sqrt(total, out=total)
    return norms
