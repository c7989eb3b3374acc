"""The batch of records of one send as columns: the one buffer every part of the
picture draws from, built once per send (see :mod:`ekfviz.viz.layers`).

Built in a few passes over the records, one attribute each (a list comprehension reads an
attribute of a slotted record in some 15 ns, a getter of several costs ten times that),
and numpy on the columns: a numpy call per record would cost more than the rest of its
logging.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from ekfviz.core.records import (
    EventKind,
    EventRecord,
    EventRows,
    Observations,
    ScanAssociation,
    UpdateParts,
)
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.viz.layers.canvas import Clock, Rows

_PREDICT, _UPDATE = EventKind.PREDICT, EventKind.UPDATE


def landmark_rows(record: EventRecord, which: str | None) -> IntArray:
    """Rows of ``record``'s landmarks: all (None), the observed or the initialised ones."""
    return map_rows_of(record.landmark_ids, record.observations, which)


def map_rows_of(
    landmark_ids: IntArray, observations: Observations | None, which: str | None
) -> IntArray:
    """Rows of the map ``landmark_ids`` of an update that did ``observations``: all
    (None), the observed or the initialised ones."""
    if which is None or observations is None:
        return np.arange(len(landmark_ids))
    ids = observations.ids if which == "observed" else observations.ids[observations.initialised]
    return np.flatnonzero(np.isin(landmark_ids, ids))


# an update's parts, as an update row holds them (UpdateParts): what it did (None where
# it has no observations), its landmark ids, means (N, 2) and marginals (N, 2, 2)
MapParts = tuple[Observations | None, IntArray, FloatArray, FloatArray]


def update_parts(record: EventRecord) -> MapParts:
    """An update record's parts as an update row holds them."""
    return record.observations, record.landmark_ids, record.landmarks_xy, record.landmark_covs


@dataclass(frozen=True, slots=True)
class Observed:
    """What the updates of a batch did with their observations, summed per record in one
    go (a numpy call per record would cost more than the rest of its logging).

    :param rows: the records with observations
    :param seen: (count,) observations per record, 0 without
    :param z: (sum(seen), 2) their measured (bearing, range), record after record
    """

    rows: IntArray
    seen: IntArray
    z: FloatArray
    new: IntArray
    nis_sum: FloatArray
    nis_used: IntArray
    skipped: IntArray

    @staticmethod
    def of(count: int, corrected: IntArray, found: list[Observations | None]) -> Observed:
        """What the updates at the rows ``corrected`` of a batch of ``count`` did
        (``found``, None where an update has no observations)."""
        has = [observations is not None for observations in found]
        rows = corrected if all(has) else corrected[np.array(has, dtype=bool)]
        observed = [observations for observations in found if observations is not None]
        nis_each = [observations.nis for observations in observed]
        per_row = np.fromiter(map(len, nis_each), np.int64, len(nis_each))
        seen = np.zeros(count, dtype=np.int64)
        seen[rows] = per_row
        owner = np.repeat(rows, per_row)
        # joined after an empty array of the type they had always been summed in
        nis = np.concatenate([np.zeros(0), *nis_each])
        used = np.isfinite(nis)
        z = np.concatenate([np.zeros((0, 2)), *(observations.z for observations in observed)])
        new = np.concatenate(
            [np.zeros(0, bool), *(observations.initialised for observations in observed)]
        )
        skipped = np.concatenate(
            [np.zeros(0, bool), *(observations.skipped for observations in observed)]
        )
        return Observed(
            rows=rows,
            seen=seen,
            z=z,
            new=np.bincount(owner[new], minlength=count),
            nis_sum=np.bincount(owner[used], weights=nis[used], minlength=count).astype(np.float64),
            nis_used=np.bincount(owner[used], minlength=count),
            skipped=np.bincount(owner[skipped], minlength=count),
        )


@dataclass(frozen=True, slots=True)
class Maps:
    """The maps of a batch's updates (its ``corrected`` rows), joined once for every part
    that reads them all (the map's changes, the health series).

    :param records: the updates' records, in order; None at an update given as a row
        (see :class:`~ekfviz.core.records.EventRows`: no association, no time)
    :param ids: (u,) each one's landmark ids (the same array while its map is the same)
    :param observations: what each did, None where it has no observations
    :param counts: (u,) landmarks of each
    :param starts: (u + 1,) where each one's landmarks start in ``xy`` and ``covs``
    :param xy: (sum(counts), 2) landmark means, update after update
    :param covs: (sum(counts), 2, 2) their marginal covariances
    """

    records: list[EventRecord | None]
    ids: list[IntArray]
    observations: list[Observations | None]
    counts: IntArray
    starts: IntArray
    xy: FloatArray
    covs: FloatArray

    @staticmethod
    def of(records: list[EventRecord | None], parts: list[MapParts]) -> Maps:
        """The maps of updates, in order: their records (None for a row) and their parts
        (observations, landmark ids, means, marginals; see :func:`update_parts`)."""
        observations = [part[0] for part in parts]
        ids = [part[1] for part in parts]
        counts = np.fromiter(map(len, ids), np.int64, len(ids))
        starts = np.zeros(len(ids) + 1, dtype=np.int64)
        np.cumsum(counts, out=starts[1:])
        if not ids:
            return Maps(records, ids, observations, counts, starts, np.zeros((0, 2)),
                        np.zeros((0, 2, 2)))  # fmt: skip
        return Maps(
            records=records,
            ids=ids,
            observations=observations,
            counts=counts,
            starts=starts,
            xy=np.concatenate([part[2] for part in parts]),
            covs=np.concatenate([part[3] for part in parts]),
        )

    @staticmethod
    def of_records(records: list[EventRecord]) -> Maps:
        """The maps of some updates' records, in order."""
        return Maps.of(list(records), [update_parts(record) for record in records])

    def association(self, i: int) -> ScanAssociation | None:
        """What the association decided at the ``i``-th update, if it decided anything."""
        record = self.records[i]
        return None if record is None else record.association

    def runs(self) -> list[int]:
        """Where each run of updates of one map (the same landmark ids) starts: the core's
        records share one ids array until the map grows."""
        ids = self.ids
        return [0] + [
            k
            for k, (before, now) in enumerate(itertools.pairwise(ids), start=1)
            if now is not before and not np.array_equal(now, before)
        ]


@dataclass(frozen=True, slots=True)
class Batch:
    """The records of one send as columns, built once and read by every part.

    :param records: the records, in order; None at an event given as a row (see
        :class:`~ekfviz.core.records.EventRows`): a predict's line and control are in
        ``lines`` and ``controls``, an update's map and observations in ``maps``
    :param whole: (count,) whether each update logs the whole map's ellipses
    :param rows: their timelines
    :param poses: (count, 3) and ``pose_covs`` (count, 3, 3)
    :param is_predict: (count,) which records are predicts; ``corrected`` the others' rows
    :param updating: (count,) which are updates (not an initialisation)
    :param observed: what their updates did with their observations
    :param maps: the maps of the ``corrected`` rows
    :param times: (count,) the log's time of each event, NaN where it has none (``rows``
        holds them filled in)
    :param lines: (count,) the log line of each event (0 where none)
    :param controls: (count, 2) the (d, alpha) of each predict that has one (see
        ``has_control``; NaN elsewhere)
    """

    records: list[EventRecord | None]
    whole: BoolArray
    rows: Rows
    poses: FloatArray
    pose_covs: FloatArray
    is_predict: BoolArray
    updating: BoolArray
    corrected: IntArray
    observed: Observed
    maps: Maps
    times: FloatArray
    lines: IntArray
    controls: FloatArray
    has_control: BoolArray

    @staticmethod
    def of(
        pending: list[tuple[EventRecord, bool]],
        clock: Clock,
        rows: EventRows | None = None,
        held: int = 0,
        rows_whole: list[bool] | None = None,
    ) -> Batch:
        """The batch of the records ``pending`` (each with whether it logs the whole map)
        and of the first ``held`` ``rows`` (``rows_whole``: whether each logs the whole
        map), merged in event order; a row has no record (an update row's map and
        observations go into ``maps`` from its parts)."""
        own = [record for record, _ in pending]
        count = len(own)
        whole = np.array([is_whole for _, is_whole in pending], dtype=bool)
        steps = np.array([record.step for record in own], dtype=np.int64)
        events = np.array([record.event for record in own], dtype=np.int64)
        times = _times([record.time for record in own])
        kinds = [record.kind for record in own]
        is_predict = np.array([kind is _PREDICT for kind in kinds], dtype=bool)
        updating = np.array([kind is _UPDATE for kind in kinds], dtype=bool)
        lines = np.array([record.line for record in own], dtype=np.int64)
        controls = np.full((count, 2), math.nan)
        has_control = np.zeros(count, dtype=bool)
        for k in np.flatnonzero(is_predict).tolist():
            control = own[k].control
            if control is not None:
                controls[k], has_control[k] = control, True
        # concatenated and reshaped: np.stack costs three times as much per record
        poses, covs = np.zeros((0, 3)), np.zeros((0, 3, 3))
        if count:
            poses = np.concatenate([record.pose for record in own]).reshape(count, 3)
            covs = np.concatenate([record.pose_cov for record in own]).reshape(count, 3, 3)
        records: list[EventRecord | None] = list(own)
        update_of: dict[int, UpdateParts] = {}  # the update rows' parts, by their row
        if rows is not None and held:
            # the rows' events interleave the records': each column in event order
            row_events = np.array(rows.events[:held], dtype=np.int64)
            order = np.argsort(np.concatenate([events, row_events]), kind="stable")
            at = np.empty(count + held, dtype=np.int64)
            at[order] = np.arange(count + held)  # where each record, then each row, goes
            mine, theirs = at[:count], at[count:]
            records = [None] * (count + held)
            for k, record in zip(mine.tolist(), own, strict=True):
                records[k] = record
            count += held
            row_updates = [k for k, update in enumerate(rows.updates[:held]) if update is not None]
            row_is_update = np.zeros(held, dtype=bool)
            row_is_update[row_updates] = True
            at_theirs = theirs.tolist()
            for k in row_updates:
                update_of[at_theirs[k]] = rows.updates[k]  # type: ignore[assignment]
            row_controls = np.array(
                [(math.nan, math.nan) if c is None else c for c in rows.controls[:held]],
                dtype=np.float64,
            ).reshape(held, 2)
            row_whole = np.zeros(held, dtype=bool) if rows_whole is None else rows_whole[:held]
            whole = _merged(whole, np.array(row_whole, dtype=bool), mine, theirs)
            steps = _merged(steps, np.array(rows.steps[:held], dtype=np.int64), mine, theirs)
            events = _merged(events, row_events, mine, theirs)
            times = _merged(times, _times(rows.times[:held]), mine, theirs)
            poses = _merged(poses, rows.poses[:held], mine, theirs)
            covs = _merged(covs, rows.pose_covs[:held], mine, theirs)
            is_predict = _merged(is_predict, ~row_is_update, mine, theirs)
            updating = _merged(updating, row_is_update, mine, theirs)
            lines = _merged(lines, np.array(rows.lines[:held], dtype=np.int64), mine, theirs)
            controls = _merged(controls, row_controls, mine, theirs)
            has_control = _merged(has_control, ~row_is_update, mine, theirs)
        corrected = np.flatnonzero(~is_predict)
        updated = [records[k] for k in corrected.tolist()]  # None at an update row
        maps = Maps.of(
            updated,
            [
                update_parts(record) if record is not None else update_of[k]
                for k, record in zip(corrected.tolist(), updated, strict=True)
            ],
        )
        return Batch(
            records=records,
            whole=whole,
            rows=clock.rows(steps, events, times),
            poses=poses,
            pose_covs=covs,
            is_predict=is_predict,
            updating=updating,
            corrected=corrected,
            observed=Observed.of(count, corrected, maps.observations),
            maps=maps,
            times=times,
            lines=lines,
            controls=controls,
            has_control=has_control,
        )


def _times(times: list[float | None]) -> FloatArray:
    """Times as floats, NaN where a record has none."""
    missing = times.count(None)
    if missing == len(times):  # an untimed log
        return np.full(len(times), math.nan)
    if not missing:
        return np.array(times, dtype=np.float64).reshape(len(times))
    return np.array([math.nan if time is None else time for time in times], dtype=np.float64)


ArrayT = TypeVar("ArrayT", bound=np.ndarray)


def _merged(first: ArrayT, second: ArrayT, at_first: IntArray, at_second: IntArray) -> ArrayT:
    """The rows of ``first`` and ``second`` at the rows ``at_first`` and ``at_second``."""
    out = np.empty((len(first) + len(second), *first.shape[1:]), dtype=first.dtype)
    out[at_first] = first
    out[at_second] = second
    return out  # type: ignore[return-value]
