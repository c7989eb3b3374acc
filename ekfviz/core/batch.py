"""Columnar batches of a run's events: the one form a replay hands its consumers.

A replay (:func:`~ekfviz.runner.replay.replay`) emits its events in batches. A batch
holds, for a run of consecutive events, one array per quantity: the event and step
numbers, the kind, the log line and time, the pose (k, 3) and its covariance (k, 3, 3),
the control (k, 2); the maps (landmark ids, means and 2x2 marginals), stored once for
every run of events whose map is the same (a predict moves the pose alone); what the
updates did with each observation, flattened with offsets per event; and the rare extras
(warnings, the whole-covariance check, the correlation, the association's decision, a
smoother's path, the full covariance where asked for), sparse by row. The per-event
view, an :class:`~ekfviz.core.records.EventRecord`, is made only when asked for
(:meth:`EventBatch.event`).

A batch never holds the full (3+2N)^2 covariance of every event: only where a consumer
asked for it (``full_cov``), as an extra.

:class:`BatchBuilder` appends one event at a time and builds the batch; every column is
read-only once built.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple, TypeVar, overload

import numpy as np

from ekfviz.core.correlation import Correlation
from ekfviz.core.health import CovarianceCheck
from ekfviz.core.records import (
    NIS,
    TABLE_COLUMNS,
    EventKind,
    EventRecord,
    Observations,
    ScanAssociation,
    landmark_marginals,
)
from ekfviz.core.types import BoolArray, FloatArray, Int8Array, IntArray

AnyArray = np.ndarray[Any, np.dtype[Any]]
ArrayT = TypeVar("ArrayT", bound=AnyArray)

# The kinds of events as the ``kinds`` column holds them (EventKind by its code).
INIT, PREDICT, UPDATE = 0, 1, 2
KINDS = (EventKind.INIT, EventKind.PREDICT, EventKind.UPDATE)
KIND_CODES = {kind: code for code, kind in enumerate(KINDS)}


def ranges(starts: IntArray, ends: IntArray) -> IntArray:
    """The integers of the ranges [starts[i], ends[i]), range after range."""
    lengths = ends - starts
    # the k-th integer overall is k plus its range's start less where that range begins
    offsets = np.repeat(starts - (np.cumsum(lengths) - lengths), lengths)
    joined: IntArray = np.arange(len(offsets), dtype=np.int64) + offsets
    return joined


def _read_only(array: ArrayT) -> ArrayT:
    array.flags.writeable = False
    return array


@dataclass(frozen=True, slots=True)
class Extras:
    """What only some events have.

    :param warnings: what went wrong at the event without stopping the run, one
        sentence each (a skipped observation, a covariance that lost definiteness)
    :param covariance: the check of the whole covariance, where it ran
    :param correlation: the correlation matrix of the whole covariance, where taken
    :param association: what the association decided, at the update of a scan
    :param path_xytheta: (K, 3) an offline filter's estimate of every pose of the run,
        the start's first, at its event after ``finish()`` (a smoother's whole path)
    :param full_cov: (3+2N, 3+2N) the whole covariance, where the consumer asked for it
    """

    warnings: tuple[str, ...] = ()
    covariance: CovarianceCheck | None = None
    correlation: Correlation | None = None
    association: ScanAssociation | None = None
    path_xytheta: FloatArray | None = None
    full_cov: FloatArray | None = None


NO_EXTRAS = Extras()


# a map as a batch keeps it: landmark ids (N,), means (N, 2) and 2x2 marginals (N, 2, 2)
MapParts = tuple[IntArray, FloatArray, FloatArray]


class StateParts(NamedTuple):
    """A filter's state as a batch takes it: the pose (3,) and its covariance (3, 3),
    which the batch copies at once (they may be views of a filter's buffers), the map
    (landmark ids (N,), means (N, 2), 2x2 marginals (N, 2, 2)), which it keeps (never to
    be changed), and, where asked for, the whole covariance.

    The built-in filter hands the same map arrays for as long as its map is unchanged;
    a batch then stores them once.
    """

    pose: FloatArray
    pose_cov: FloatArray
    landmark_ids: IntArray
    landmarks_xy: FloatArray
    landmark_covs: FloatArray
    full_cov: FloatArray | None = None

    @staticmethod
    def of(
        x: FloatArray, P: FloatArray, landmark_ids: IntArray | None = None, full_cov: bool = False
    ) -> StateParts:
        """The parts of a state in the classic layout x = [x, y, theta, l1x, l1y, ...],
        copied (the caller may go on changing ``x`` and ``P``).

        :param x: (3+2N,) state mean
        :param P: (3+2N, 3+2N) state covariance (its diagonal blocks only are read,
            unless ``full_cov``)
        :param landmark_ids: (N,) ids in state order; default 1..N
        :raises ValueError: ``x`` and ``P`` of shapes that are not a state's
        """
        n = (x.shape[0] - 3) // 2
        if x.ndim != 1 or x.shape[0] != 3 + 2 * n or P.shape != (x.shape[0], x.shape[0]):
            raise ValueError(
                f"expected x of length 3+2N and P of shape (3+2N, 3+2N), got {x.shape} and"
                f" {P.shape}"
            )
        ids = np.arange(1, n + 1) if landmark_ids is None else landmark_ids
        mean = np.array(x, dtype=np.float64)
        return StateParts(
            mean[:3],
            np.array(P[:3, :3], dtype=np.float64),
            np.array(ids, dtype=np.int64).reshape(n),
            mean[3:].reshape(n, 2),
            landmark_marginals(np.asarray(P, dtype=np.float64), n),
            np.array(P, dtype=np.float64) if full_cov else None,
        )


@dataclass(frozen=True, slots=True)
class MapTable:
    """The maps of a batch, each stored once.

    :param id_sets: the distinct landmark id arrays of the maps (a map's ids are the
        same array for as long as they do not change)
    :param id_set: (m,) which of ``id_sets`` each map has
    :param starts: (m + 1,) where each map's landmarks start in ``xy`` and ``covs``
    :param xy: (L, 2) the landmark means, map after map
    :param covs: (L, 2, 2) their marginal covariances
    """

    id_sets: tuple[IntArray, ...]
    id_set: IntArray
    starts: IntArray
    xy: FloatArray
    covs: FloatArray

    def __len__(self) -> int:
        return len(self.id_set)

    def ids(self, i: int) -> IntArray:
        """The landmark ids of map ``i``, in state order."""
        return self.id_sets[int(self.id_set[i])]

    @property
    def counts(self) -> IntArray:
        """(m,) the landmarks of each map."""
        counts: IntArray = np.diff(self.starts)
        return counts

    def take(self, maps: IntArray) -> MapTable:
        """The maps ``maps`` (indices, ascending), in a table of their own."""
        if len(maps) == len(self) and (not len(maps) or int(maps[-1]) == len(maps) - 1):
            return self
        used_sets, id_set = np.unique(self.id_set[maps], return_inverse=True)
        first, end = self.starts[maps], self.starts[maps + 1]
        starts = np.zeros(len(maps) + 1, dtype=np.int64)
        np.cumsum(end - first, out=starts[1:])
        if len(maps) and bool((first[1:] == end[:-1]).all()):  # one stretch: views
            rows: slice | IntArray = slice(int(first[0]), int(end[-1]))
        else:
            rows = ranges(first, end)
        return MapTable(
            tuple(self.id_sets[s] for s in used_sets.tolist()),
            _read_only(id_set.astype(np.int64).reshape(len(maps))),
            _read_only(starts),
            self.xy[rows],
            self.covs[rows],
        )

    @staticmethod
    def joined(tables: Sequence[MapTable]) -> MapTable:
        """The maps of ``tables``, table after table (an id array met twice kept once)."""
        position: dict[int, int] = {}
        id_sets: list[IntArray] = []
        id_set: list[IntArray] = []
        for table in tables:
            local = []
            for ids in table.id_sets:
                if id(ids) not in position:
                    position[id(ids)] = len(id_sets)
                    id_sets.append(ids)
                local.append(position[id(ids)])
            id_set.append(np.array(local, dtype=np.int64)[table.id_set])
        counts = np.concatenate([np.zeros(0, np.int64), *(table.counts for table in tables)])
        starts = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=starts[1:])
        return MapTable(
            tuple(id_sets),
            _read_only(np.concatenate([np.zeros(0, np.int64), *id_set])),
            _read_only(starts),
            _read_only(np.concatenate([np.zeros((0, 2)), *(table.xy for table in tables)])),
            _read_only(np.concatenate([np.zeros((0, 2, 2)), *(table.covs for table in tables)])),
        )


@dataclass(frozen=True, slots=True)
class ObservationTable:
    """What the events of a batch did with their observations, flattened in event order
    (see :class:`~ekfviz.core.records.Observations` for each column).

    :param starts: (k + 1,) where each event's observations start
    :param present: (k,) whether each event has observations at all (an update or an
        initialisation from an observation line; an empty line has some, none of them)
    """

    starts: IntArray
    present: BoolArray
    ids: IntArray
    z: FloatArray
    table: FloatArray
    initialised: BoolArray
    skipped: BoolArray

    @property
    def nis(self) -> FloatArray:
        """The NIS of each observation (a view of the table's column)."""
        return self.table[:, NIS]

    @property
    def counts(self) -> IntArray:
        """(k,) the observations of each event."""
        counts: IntArray = np.diff(self.starts)
        return counts

    def of(self, row: int) -> Observations | None:
        """The observations of the event at ``row`` (views), or None where it has none."""
        if not self.present[row]:
            return None
        span = slice(int(self.starts[row]), int(self.starts[row + 1]))
        return Observations(
            self.ids[span],
            self.z[span],
            self.table[span],
            self.initialised[span],
            self.skipped[span],
        )

    def columns(self) -> tuple[AnyArray, ...]:
        """The flattened columns, in the order of :class:`Observations`' fields."""
        return self.ids, self.z, self.table, self.initialised, self.skipped

    def take(self, rows: IntArray) -> ObservationTable:
        """The observations of the events at ``rows``, in a table of their own."""
        first, end = self.starts[rows], self.starts[rows + 1]
        starts = np.zeros(len(rows) + 1, dtype=np.int64)
        np.cumsum(end - first, out=starts[1:])
        flat = ranges(first, end)
        return ObservationTable(
            _read_only(starts),
            self.present[rows],
            *(column[flat] for column in self.columns()),
        )

    @staticmethod
    def joined(tables: Sequence[ObservationTable]) -> ObservationTable:
        """The observations of ``tables``, table after table."""
        counts = np.concatenate([np.zeros(0, np.int64), *(table.counts for table in tables)])
        starts = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=starts[1:])
        columns = [
            _read_only(np.concatenate(parts))
            for parts in zip(*(table.columns() for table in tables), strict=True)
        ]
        present = np.concatenate([table.present for table in tables])
        return ObservationTable(_read_only(starts), _read_only(present), *columns)


@dataclass(frozen=True, slots=True, eq=False)
class EventBatch:
    """A run of consecutive events of a replay, in columns (see the module).

    :param events: (k,) event numbers: 0 for the initialisation, +1 for every predict
        and update
    :param steps: (k,) steps: 0 for the initialisation, then one per control and
        observation cycle (see :class:`~ekfviz.core.steps.StepCounter`)
    :param kinds: (k,) ``INIT``, ``PREDICT`` or ``UPDATE`` (``KINDS`` names them)
    :param lines: (k,) the 1-based log line of each event (0 where none)
    :param times: (k,) the log's time of each event in seconds, NaN where it has none
    :param poses: (k, 3) x, y, theta with theta in (-pi, pi]
    :param pose_covs: (k, 3, 3) pose covariances
    :param controls: (k, 2) the (d, alpha) of each predict that has one, NaN elsewhere
    :param map_of: (k,) the map of each event: an index into ``maps``
    :param maps: the maps, each stored once
    :param observed: what each event did with its observations
    :param extras: by row, what only some events have (see :class:`Extras`)
    """

    events: IntArray
    steps: IntArray
    kinds: Int8Array
    lines: IntArray
    times: FloatArray
    poses: FloatArray
    pose_covs: FloatArray
    controls: FloatArray
    map_of: IntArray
    maps: MapTable
    observed: ObservationTable
    extras: dict[int, Extras] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.events)

    @overload
    def __getitem__(self, index: int) -> EventRecord: ...

    @overload
    def __getitem__(self, index: slice) -> EventBatch: ...

    def __getitem__(self, index: int | slice) -> EventRecord | EventBatch:
        """An event's view (an int), or the events of a slice as a batch."""
        if isinstance(index, slice):
            return self.take(np.arange(len(self))[index])
        return self.event(index)

    def __iter__(self) -> Iterator[EventRecord]:
        """Every event's view, in order (made one by one: for the few events a caller
        reads one at a time)."""
        return (self.event(i) for i in range(len(self)))

    @property
    def is_predict(self) -> BoolArray:
        """(k,) which events are predicts."""
        predicts: BoolArray = self.kinds == PREDICT
        return predicts

    @property
    def corrected(self) -> IntArray:
        """The rows of the events that are not predicts (initialisation and updates)."""
        rows: IntArray = np.flatnonzero(self.kinds != PREDICT)
        return rows

    @property
    def n_landmarks(self) -> IntArray:
        """(k,) the landmarks in each event's map."""
        counts: IntArray = self.maps.counts[self.map_of]
        return counts

    def extra(self, row: int) -> Extras:
        """The extras of the event at ``row`` (none: :data:`NO_EXTRAS`)."""
        return self.extras.get(row, NO_EXTRAS)

    def event(self, row: int) -> EventRecord:
        """The view of the event at ``row`` (negative from the end) as a record."""
        if row < 0:
            row += len(self)
        if not 0 <= row < len(self):
            raise IndexError(f"event row {row} of a batch of {len(self)}")
        m = int(self.map_of[row])
        span = slice(int(self.maps.starts[m]), int(self.maps.starts[m + 1]))
        time = float(self.times[row])
        extra = self.extra(row)
        return EventRecord(
            event=int(self.events[row]),
            step=int(self.steps[row]),
            kind=KINDS[int(self.kinds[row])],
            line=int(self.lines[row]),
            pose=self.poses[row],
            pose_cov=self.pose_covs[row],
            landmark_ids=self.maps.ids(m),
            landmarks_xy=self.maps.xy[span],
            landmark_covs=self.maps.covs[span],
            control=None if math.isnan(self.controls[row, 0]) else self.controls[row],
            observations=self.observed.of(row),
            full_cov=extra.full_cov,
            time=None if math.isnan(time) else time,
            warnings=extra.warnings,
            covariance=extra.covariance,
            correlation=extra.correlation,
            association=extra.association,
            path_xytheta=extra.path_xytheta,
        )

    @property
    def last(self) -> EventRecord:
        """The view of the batch's last event."""
        return self.event(len(self) - 1)

    def take(self, rows: IntArray | Sequence[int]) -> EventBatch:
        """The events at ``rows`` (ascending), as a batch of their own."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        if len(rows) == len(self) and (not len(rows) or int(rows[-1]) == len(rows) - 1):
            return self
        used, map_of = np.unique(self.map_of[rows], return_inverse=True)
        extras = {}
        if self.extras:
            keys = np.fromiter(self.extras, np.int64, len(self.extras))
            for at in np.flatnonzero(np.isin(rows, keys)).tolist():
                extras[at] = self.extras[int(rows[at])]
        return _batch(
            [column[rows] for column in self._columns()],
            _read_only(map_of.astype(np.int64).reshape(len(rows))),
            self.maps.take(used),
            self.observed.take(rows),
            extras,
        )

    def _columns(self) -> tuple[AnyArray, ...]:
        return (
            self.events, self.steps, self.kinds, self.lines, self.times, self.poses,
            self.pose_covs, self.controls,
        )  # fmt: skip

    @staticmethod
    def joined(batches: Iterable[EventBatch]) -> EventBatch:
        """The events of ``batches``, batch after batch, as one batch."""
        batches = [batch for batch in batches if len(batch)]
        if len(batches) == 1:
            return batches[0]
        if not batches:
            return BatchBuilder().build()
        map_offsets = np.cumsum([0] + [len(batch.maps) for batch in batches[:-1]])
        row_offsets = np.cumsum([0] + [len(batch) for batch in batches[:-1]]).tolist()
        extras = {
            offset + row: extra
            for batch, offset in zip(batches, row_offsets, strict=True)
            for row, extra in batch.extras.items()
        }
        columns = [
            _read_only(np.concatenate(parts))
            for parts in zip(*(batch._columns() for batch in batches), strict=True)
        ]
        map_of = np.concatenate(
            [batch.map_of + offset for batch, offset in zip(batches, map_offsets, strict=True)]
        )
        return _batch(
            columns,
            _read_only(map_of),
            MapTable.joined([batch.maps for batch in batches]),
            ObservationTable.joined([batch.observed for batch in batches]),
            extras,
        )


def _batch(
    columns: Sequence[AnyArray],
    map_of: IntArray,
    maps: MapTable,
    observed: ObservationTable,
    extras: dict[int, Extras],
) -> EventBatch:
    """A batch of its per-event columns (in the order of :meth:`EventBatch._columns`)
    and the rest."""
    events, steps, kinds, lines, times, poses, pose_covs, controls = columns
    return EventBatch(
        events, steps, kinds, lines, times, poses, pose_covs, controls, map_of, maps, observed,
        extras,
    )  # fmt: skip


_NAN2 = (math.nan, math.nan)
_NO_IDS: IntArray = _read_only(np.zeros(0, dtype=np.int64))
_NO_OBSERVATIONS = Observations(
    _NO_IDS,
    np.zeros((0, 2)),
    np.zeros((0, TABLE_COLUMNS)),
    np.zeros(0, dtype=bool),
    np.zeros(0, dtype=bool),
)


_FIRST_ROWS = 1024  # room for poses a batch starts with (twice as much whenever full)


class BatchBuilder:
    """Appends events one at a time and builds them into an :class:`EventBatch`.

    A map handed again as the same arrays (the built-in filter's, while it does not
    change) is stored once. :meth:`build` starts a new batch and remembers the last map,
    so that a predict after it in the next batch finds it again. An event counts once it
    is wholly appended: a signal raised in :meth:`add` (Ctrl-C is an exception
    anywhere) leaves nothing half written in the batch.
    """

    def __init__(self) -> None:
        self._last_map: MapParts | None = None  # kept from one batch to the next
        # the poses and their covariances, copied event by event into buffers kept from
        # one batch to the next (a numpy copy into place costs a third of a copy kept and
        # joined at the end)
        self._poses = np.empty((_FIRST_ROWS, 3))
        self._pose_covs = np.empty((_FIRST_ROWS, 3, 3))
        self._room = _FIRST_ROWS
        self._start()

    def _start(self) -> None:
        self._count = 0
        self._events: list[int] = []
        self._steps: list[int] = []
        self._kinds: list[int] = []
        self._lines: list[int] = []
        self._times: list[float] = []
        self._d: list[float] = []
        self._alpha: list[float] = []
        self._map_of: list[int] = []
        self._maps: list[MapParts] = []
        self._map_index = -1  # of the last map in this batch (-1: none yet)
        self.landmarks = 0  # landmarks stored in the maps (what a batch's size grows with)
        self._observations: list[Observations | None] = []
        self._extras: dict[int, Extras] = {}

    def __len__(self) -> int:
        return self._count

    def add(
        self,
        parts: StateParts,
        *,
        event: int,
        step: int,
        kind: int,
        line: int = 0,
        time: float | None = None,
        control: tuple[float, float] | None = None,
        observations: Observations | None = None,
        extras: Extras | None = None,
    ) -> int:
        """Append an event in the state ``parts``; its row in the batch. The pose and its
        covariance are copied at once; the map's arrays are kept (not to be changed).

        :param kind: ``INIT``, ``PREDICT`` or ``UPDATE``
        :param control: a predict's (d, alpha)
        """
        pose, pose_cov, ids, xy, covs, full_cov = parts
        last = self._last_map
        if last is None or ids is not last[0] or xy is not last[1] or covs is not last[2]:
            last = (ids, xy, covs)
        if full_cov is not None:
            extras = replace(Extras() if extras is None else extras, full_cov=full_cov)
        return self.append(
            event, step, kind, line, time, control, pose, pose_cov, last, observations, extras
        )

    def append(
        self,
        event: int,
        step: int,
        kind: int,
        line: int,
        time: float | None,
        control: tuple[float, float] | None,
        pose: FloatArray,
        pose_cov: FloatArray,
        map_parts: MapParts,
        observations: Observations | None,
        extras: Extras | None,
    ) -> int:
        """:meth:`add`, its arguments in order and the map as one tuple (a filter hands
        the same tuple for as long as its map is unchanged): what a replay calls at
        every event."""
        row = self._count
        if len(self._map_of) != row:  # a signal cut the last call short: drop its part
            self._truncate(row)
        if map_parts is not self._last_map or self._map_index < 0:  # (-1: a new batch)
            self._new_map(map_parts)
        # (the map's index first: a call cut short before it has appended nothing else)
        self._map_of.append(self._map_index)
        self._events.append(event)
        self._steps.append(step)
        self._kinds.append(kind)
        self._lines.append(line)
        self._times.append(math.nan if time is None else time)
        if row == self._room:
            self._grow()
        self._poses[row] = pose
        self._pose_covs[row] = pose_cov
        d, alpha = _NAN2 if control is None else control
        self._d.append(d)
        self._alpha.append(alpha)
        self._observations.append(observations)
        if extras is not None:
            self._extras[row] = extras
        self._count = row + 1  # the event counts: all of it appended
        return row

    def _new_map(self, map_parts: MapParts) -> None:
        """Store a map for the events appended from now on."""
        last = self._last_map
        ids = map_parts[0]
        if last is not None and ids is not last[0] and np.array_equal(ids, last[0]):
            # the same ids: one array (consumers compare a map's ids by identity)
            map_parts = (last[0], map_parts[1], map_parts[2])
        self._last_map = map_parts
        self._maps.append(map_parts)
        self.landmarks += len(ids)
        self._map_index = len(self._maps) - 1

    def _grow(self) -> None:
        """Twice the room for poses, those so far kept."""
        self._poses = np.concatenate([self._poses, np.empty_like(self._poses)])
        self._pose_covs = np.concatenate([self._pose_covs, np.empty_like(self._pose_covs)])
        self._room = len(self._poses)

    def _truncate(self, row: int) -> None:
        """Forget what a call cut short appended beyond ``row`` events."""
        for column in self._columns():
            del column[row:]
        self._extras.pop(row, None)

    def add_state(
        self,
        x: FloatArray,
        P: FloatArray,
        *,
        landmark_ids: IntArray | Sequence[int] | None = None,
        full_cov: bool = False,
        event: int,
        step: int,
        kind: int,
        line: int = 0,
        time: float | None = None,
        control: tuple[float, float] | None = None,
        observations: Observations | None = None,
        extras: Extras | None = None,
    ) -> int:
        """:meth:`add` of a state in the classic layout, copied (see
        :meth:`StateParts.of`): for a filter that hands its x, P and landmark ids."""
        ids = None if landmark_ids is None else np.asarray(landmark_ids, dtype=np.int64)
        return self.add(
            StateParts.of(np.asarray(x, np.float64), np.asarray(P, np.float64), ids, full_cov),
            event=event, step=step, kind=kind, line=line, time=time, control=control,
            observations=observations, extras=extras,
        )  # fmt: skip

    def set_extras(self, row: int, extras: Extras) -> None:
        """Replace the extras of the event at ``row`` (work that was done after it was
        appended: the checks of a large covariance, see ``ekfviz.runner.checks``)."""
        self._extras[row] = extras

    def extras_of(self, row: int) -> Extras:
        return self._extras.get(row, NO_EXTRAS)

    def _columns(self) -> tuple[list[object], ...]:
        return (
            self._map_of, self._events, self._steps, self._kinds, self._lines,  # type: ignore[return-value]
            self._times, self._d, self._alpha,
            self._observations,
        )  # fmt: skip

    def build(self) -> EventBatch:
        """The events appended so far as a batch; the builder starts a new one."""
        k = self._count
        self._truncate(k)
        maps = self._maps
        counts = np.fromiter((len(ids) for ids, _, _ in maps), np.int64, len(maps))
        starts = np.zeros(len(maps) + 1, dtype=np.int64)
        np.cumsum(counts, out=starts[1:])
        id_sets: list[IntArray] = []
        id_set = np.zeros(len(maps), dtype=np.int64)
        for i, (ids, _, _) in enumerate(maps):
            if not id_sets or ids is not id_sets[-1]:
                id_sets.append(_read_only(ids) if ids.flags.writeable else ids)
            id_set[i] = len(id_sets) - 1
        table = MapTable(
            tuple(id_sets),
            _read_only(id_set),
            _read_only(starts),
            _read_only(np.concatenate([np.zeros((0, 2)), *(xy for _, xy, _ in maps)])),
            _read_only(np.concatenate([np.zeros((0, 2, 2)), *(c for _, _, c in maps)])),
        )
        controls = np.empty((k, 2))
        controls[:, 0], controls[:, 1] = self._d, self._alpha
        batch = EventBatch(
            events=_read_only(np.array(self._events, dtype=np.int64)),
            steps=_read_only(np.array(self._steps, dtype=np.int64)),
            kinds=_read_only(np.array(self._kinds, dtype=np.int8)),
            lines=_read_only(np.array(self._lines, dtype=np.int64)),
            times=_read_only(np.array(self._times, dtype=np.float64)),
            # concatenated and reshaped: np.stack costs twice as much per event
            poses=_read_only(self._poses[:k].copy()),
            pose_covs=_read_only(self._pose_covs[:k].copy()),
            controls=_read_only(controls),
            map_of=_read_only(np.array(self._map_of, dtype=np.int64)),
            maps=table,
            observed=_observation_table(self._observations),
            extras=self._extras,
        )
        self._start()
        return batch


def _observation_table(found: list[Observations | None]) -> ObservationTable:
    """The observations of each event (None where it has none), flattened."""
    present = np.fromiter((o is not None for o in found), bool, len(found))
    each = [o for o in found if o is not None] or [_NO_OBSERVATIONS]
    counts = np.zeros(len(found), dtype=np.int64)
    counts[present] = [len(o.ids) for o in each] if present.any() else []
    starts = np.zeros(len(found) + 1, dtype=np.int64)
    np.cumsum(counts, out=starts[1:])
    return ObservationTable(
        _read_only(starts),
        _read_only(present),
        _read_only(_joined([o.ids for o in each]).astype(np.int64, copy=False)),
        _read_only(np.concatenate([o.z for o in each])),
        _read_only(np.concatenate([o.table for o in each])),
        _read_only(_joined([o.initialised for o in each]).astype(bool, copy=False)),
        _read_only(_joined([o.skipped for o in each]).astype(bool, copy=False)),
    )


def _joined(columns: list[AnyArray]) -> AnyArray:
    """The 1-D ``columns`` one after another: one array repeated where every event
    shares it (a classic log's ids, the flags of the lines that initialised and skipped
    none), which costs a fraction of joining them one by one."""
    first = columns[0]
    if all(column is first for column in columns):
        return np.tile(first, len(columns))
    return np.concatenate(columns)
