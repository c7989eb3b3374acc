"""The events of one send and what every part of the picture reads of them, built once
per send (see :mod:`ekfviz.viz.layers`) from the run's columns
(:class:`~ekfviz.core.batch.EventBatch`): numpy on whole columns, never a call per event.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ekfviz.core.batch import PREDICT, UPDATE, EventBatch, Extras, ranges
from ekfviz.core.records import EventRecord, ScanAssociation
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.viz.layers.canvas import Clock, Rows


def landmark_rows(record: EventRecord, which: str | None) -> IntArray:
    """Rows of ``record``'s landmarks: all (None), the observed or the initialised ones."""
    observations = record.observations
    if observations is None:
        return map_rows_of(record.landmark_ids, None, which)
    return map_rows_of(record.landmark_ids, observations.ids, which, observations.initialised)


def map_rows_of(
    landmark_ids: IntArray,
    observed_ids: IntArray | None,
    which: str | None,
    initialised: BoolArray | None = None,
) -> IntArray:
    """Rows of the map ``landmark_ids`` of an update that observed ``observed_ids`` (None:
    it has no observations): all (None), the observed or the initialised ones."""
    if which is None or observed_ids is None:
        return np.arange(len(landmark_ids))
    ids = observed_ids if which == "observed" or initialised is None else observed_ids[initialised]
    rows: IntArray = np.flatnonzero(np.isin(landmark_ids, ids))
    return rows


@dataclass(frozen=True, slots=True)
class Observed:
    """What the events of a batch did with their observations, summed per event.

    :param rows: the events with observations
    :param seen: (count,) observations per event, 0 without
    :param z: (sum(seen), 2) their measured (bearing, range), event after event
    :param new: (count,) landmarks each initialised
    :param nis_sum: (count,) the NIS of the landmarks each used, summed in order
    :param nis_used: (count,) how many those are
    :param skipped: (count,) observations each skipped
    """

    rows: IntArray
    seen: IntArray
    z: FloatArray
    new: IntArray
    nis_sum: FloatArray
    nis_used: IntArray
    skipped: IntArray

    @staticmethod
    def of(events: EventBatch) -> Observed:
        """What the events of ``events`` did with their observations."""
        table, count = events.observed, len(events)
        seen = table.counts
        owner = np.repeat(np.arange(count), seen)
        used = np.isfinite(table.nis)
        return Observed(
            rows=np.flatnonzero(table.present),
            seen=seen,
            z=table.z,
            new=np.bincount(owner[table.initialised], minlength=count),
            # bincount adds each bin's weights in order: an update's own sum, to the bit
            nis_sum=np.bincount(owner[used], weights=table.nis[used], minlength=count).astype(
                np.float64
            ),
            nis_used=np.bincount(owner[used], minlength=count),
            skipped=np.bincount(owner[table.skipped], minlength=count),
        )


@dataclass(frozen=True, slots=True)
class Maps:
    """The maps of a batch's initialisation and updates (its ``corrected`` rows), joined
    once for every part that reads them all (the map's changes, the health series).

    :param ids: (u,) each one's landmark ids (the same array while its map is the same)
    :param counts: (u,) landmarks of each
    :param starts: (u + 1,) where each one's landmarks start in ``xy`` and ``covs``
    :param xy: (sum(counts), 2) landmark means, update after update
    :param covs: (sum(counts), 2, 2) their marginal covariances
    :param times: (u,) the log's time of each, NaN where it has none
    :param observed_starts: (u + 1,) where each one's observations start in
        ``observed_ids`` and ``observed_new``
    :param has_observations: (u,) which have observations (else: none at all)
    :param observed_ids: the ids each observed, update after update
    :param observed_new: (len(observed_ids),) which of those it initialised
    :param associations: by update, what the association decided where it did
    """

    ids: list[IntArray]
    counts: IntArray
    starts: IntArray
    xy: FloatArray
    covs: FloatArray
    times: FloatArray
    observed_starts: IntArray
    has_observations: BoolArray
    observed_ids: IntArray
    observed_new: BoolArray
    associations: dict[int, ScanAssociation]

    @staticmethod
    def of(events: EventBatch, corrected: IntArray) -> Maps:
        """The maps of the events at the rows ``corrected`` of ``events``."""
        table = events.maps
        at = events.map_of[corrected]
        first, end = table.starts[at], table.starts[at + 1]
        counts = end - first
        starts = np.zeros(len(at) + 1, dtype=np.int64)
        np.cumsum(counts, out=starts[1:])
        if len(at) and bool((first[1:] == end[:-1]).all()):  # one stretch: views
            rows: slice | IntArray = slice(int(first[0]), int(end[-1]))
        else:
            rows = ranges(first, end)
        observed = events.observed
        u = {row: i for i, row in enumerate(corrected.tolist())} if events.extras else {}
        return Maps(
            ids=[table.id_sets[s] for s in table.id_set[at].tolist()],
            counts=counts,
            starts=starts,
            xy=table.xy[rows],
            covs=table.covs[rows],
            times=events.times[corrected],
            # (a predict observes nothing: an update's observations end where the next
            # update's start)
            observed_starts=np.append(observed.starts[corrected], observed.starts[-1]),
            has_observations=observed.present[corrected],
            observed_ids=observed.ids,
            observed_new=observed.initialised,
            associations={
                u[row]: extra.association
                for row, extra in events.extras.items()
                if extra.association is not None and row in u
            },
        )

    def association(self, i: int) -> ScanAssociation | None:
        """What the association decided at the ``i``-th update, if it decided anything."""
        return self.associations.get(i)

    def observed_of(self, i: int) -> tuple[IntArray | None, BoolArray | None]:
        """The ids the ``i``-th update observed and which it initialised (None, None: it
        has no observations)."""
        if not self.has_observations[i]:
            return None, None
        span = slice(int(self.observed_starts[i]), int(self.observed_starts[i + 1]))
        return self.observed_ids[span], self.observed_new[span]

    def runs(self) -> list[int]:
        """Where each run of updates of one map (the same landmark ids) starts: a batch's
        maps share one ids array until the map grows."""
        ids = self.ids
        return [0] + [
            k
            for k, (before, now) in enumerate(itertools.pairwise(ids), start=1)
            if now is not before and not np.array_equal(now, before)
        ]


@dataclass(frozen=True, slots=True)
class Batch:
    """The events of one send, with what the parts read of them.

    :param events: the events, in columns
    :param whole: (count,) whether each update logs the whole map's ellipses
    :param rows: their timelines
    :param corrected: the rows of the initialisation and the updates (not predicts)
    :param updating: (count,) which events are updates (not an initialisation)
    :param observed: what their updates did with their observations
    :param maps: the maps of the ``corrected`` rows
    :param has_control: (count,) which events are predicts with a control
    """

    events: EventBatch
    whole: BoolArray
    rows: Rows
    corrected: IntArray
    updating: BoolArray
    observed: Observed
    maps: Maps
    has_control: BoolArray

    @staticmethod
    def of(events: EventBatch, whole: BoolArray, clock: Clock) -> Batch:
        """The batch of a send of ``events`` (``whole``: whether each logs the whole map)."""
        corrected = events.corrected
        return Batch(
            events=events,
            whole=whole,
            rows=clock.rows(events.steps, events.events, events.times),
            corrected=corrected,
            updating=events.kinds == UPDATE,
            observed=Observed.of(events),
            maps=Maps.of(events, corrected),
            has_control=(events.kinds == PREDICT) & ~np.isnan(events.controls[:, 0]),
        )

    @property
    def poses(self) -> FloatArray:
        """(count, 3) the poses."""
        return self.events.poses

    @property
    def pose_covs(self) -> FloatArray:
        """(count, 3, 3) their covariances."""
        return self.events.pose_covs

    @property
    def is_predict(self) -> BoolArray:
        """(count,) which events are predicts."""
        return self.events.is_predict

    @property
    def times(self) -> FloatArray:
        """(count,) the log's time of each event, NaN where it has none (``rows`` holds
        them filled in)."""
        return self.events.times

    @property
    def lines(self) -> IntArray:
        """(count,) the log line of each event (0 where none)."""
        return self.events.lines

    @property
    def controls(self) -> FloatArray:
        """(count, 2) the (d, alpha) of each predict that has one (NaN elsewhere)."""
        return self.events.controls

    @property
    def extras(self) -> dict[int, Extras]:
        """By row, what only some events have (warnings, checks, correlations, ...)."""
        return self.events.extras
