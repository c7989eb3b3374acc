"""The batch of records of one send as columns: the one buffer every part of the
picture draws from, built once per send (see :mod:`ekfviz.viz.layers`)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from ekfviz.core.records import EventKind, EventRecord, PredictRows
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz.layers.canvas import Clock, Rows


def landmark_rows(record: EventRecord, which: str | None) -> IntArray:
    """Rows of ``record``'s landmarks: all (None), the observed or the initialised ones."""
    if which is None or record.observations is None:
        return np.arange(record.n_landmarks)
    observations = record.observations
    ids = observations.ids if which == "observed" else observations.ids[observations.initialised]
    return np.flatnonzero(np.isin(record.landmark_ids, ids))


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
    def of(records: list[EventRecord | None], corrected: IntArray) -> Observed:
        count = len(records)
        observed = [
            (k, observations)
            for k in corrected.tolist()
            if (observations := records[k].observations) is not None
        ]
        rows = np.array([k for k, _ in observed], dtype=np.int64)
        seen = np.zeros(count, dtype=np.int64)
        seen[rows] = [len(observations) for _, observations in observed]
        owner = np.repeat(np.arange(count), seen)

        def joined(field: str, empty: npt.NDArray[Any]) -> npt.NDArray[Any]:
            return np.concatenate([empty, *(getattr(o, field) for _, o in observed)])

        nis = joined("nis", np.zeros(0))
        used = np.isfinite(nis)
        return Observed(
            rows=rows,
            seen=seen,
            z=joined("z", np.zeros((0, 2))),
            new=np.bincount(owner[joined("initialised", np.zeros(0, bool))], minlength=count),
            nis_sum=np.bincount(owner[used], weights=nis[used], minlength=count).astype(np.float64),
            nis_used=np.bincount(owner[used], minlength=count),
            skipped=np.bincount(owner[joined("skipped", np.zeros(0, bool))], minlength=count),
        )


@dataclass(frozen=True, slots=True)
class Batch:
    """The records of one send as columns, built once and read by every part.

    :param records: the records, in order; None at a predict of a segment (see
        :class:`PredictSegment`), whose line and control are in ``lines`` and ``controls``
    :param whole: (count,) whether each update logs the whole map's ellipses
    :param rows: their timelines
    :param poses: (count, 3) and ``pose_covs`` (count, 3, 3)
    :param is_predict: (count,) which records are predicts; ``corrected`` the others' rows
    :param observed: what their updates did with their observations
    :param lines: the log line of each predict of a segment (0 elsewhere)
    :param controls: the (d, alpha) of each predict of a segment (None elsewhere)
    """

    records: list[EventRecord | None]
    whole: list[bool]
    rows: Rows
    poses: FloatArray
    pose_covs: FloatArray
    is_predict: npt.NDArray[np.bool_]
    corrected: IntArray
    observed: Observed
    lines: list[int]
    controls: list[tuple[float, float] | None]

    @staticmethod
    def of(
        pending: list[tuple[EventRecord, bool]],
        clock: Clock,
        rows: PredictRows | None = None,
        held: int = 0,
    ) -> Batch:
        """The batch of the records ``pending`` (each with whether it logs the whole map)
        and of the first ``held`` predict ``rows``, merged in event order."""
        records: list[EventRecord | None] = [record for record, _ in pending]
        whole = [is_whole for _, is_whole in pending]
        count = len(records)
        steps = np.fromiter((record.step for record in pending_records(pending)), np.int64, count)
        events = np.fromiter((record.event for record in pending_records(pending)), np.int64, count)
        times = np.fromiter(
            (math.nan if r.time is None else r.time for r in pending_records(pending)),
            np.float64,
            count,
        )
        # concatenated and reshaped: np.stack costs three times as much per record
        poses, covs = np.zeros((0, 3)), np.zeros((0, 3, 3))
        if count:
            poses = np.concatenate([record.pose for record, _ in pending]).reshape(count, 3)
            covs = np.concatenate([r.pose_cov for r, _ in pending]).reshape(count, 3, 3)
        lines: list[int] = [0] * count
        controls: list[tuple[float, float] | None] = [None] * count
        if rows is not None and held:
            # the rows' events interleave the records': each column in event order
            row_events = np.array(rows.events[:held], dtype=np.int64)
            order = np.argsort(np.concatenate([events, row_events]), kind="stable")
            at = np.empty(count + held, dtype=np.int64)
            at[order] = np.arange(count + held)  # where each record, then each row, goes
            mine, theirs = at[:count], at[count:]
            count += held
            merged: list[EventRecord | None] = [None] * count
            for k, record in zip(mine.tolist(), records, strict=True):
                merged[k] = record
            records = merged
            whole_all = [False] * count
            for k, is_whole in zip(mine.tolist(), whole, strict=True):
                whole_all[k] = is_whole
            whole = whole_all
            lines, controls = [0] * count, [None] * count
            for k, line, control in zip(
                theirs.tolist(), rows.lines[:held], rows.controls[:held], strict=True
            ):
                lines[k], controls[k] = line, control
            steps = _merged(steps, np.array(rows.steps[:held], dtype=np.int64), mine, theirs)
            events = _merged(events, row_events, mine, theirs)
            row_times = np.array(
                [math.nan if time is None else time for time in rows.times[:held]], np.float64
            )
            times = _merged(times, row_times, mine, theirs)
            poses = _merged(poses, rows.poses[:held], mine, theirs)
            covs = _merged(covs, rows.pose_covs[:held], mine, theirs)
        is_predict = np.fromiter(
            (record is None or record.kind is EventKind.PREDICT for record in records),
            bool,
            count,
        )
        corrected = np.flatnonzero(~is_predict)
        return Batch(
            records=records,
            whole=whole,
            rows=clock.rows(steps, events, times),
            poses=poses,
            pose_covs=covs,
            is_predict=is_predict,
            corrected=corrected,
            observed=Observed.of(records, corrected),
            lines=lines,
            controls=controls,
        )

    def updates(self) -> list[tuple[int, EventRecord, bool]]:
        """(row, record, logs the whole map) of every update and initialisation."""
        return [(k, self.records[k], self.whole[k]) for k in self.corrected.tolist()]


def pending_records(pending: list[tuple[EventRecord, bool]]) -> Iterator[EventRecord]:
    return (record for record, _ in pending)


ArrayT = TypeVar("ArrayT", bound=np.ndarray)


def _merged(first: ArrayT, second: ArrayT, at_first: IntArray, at_second: IntArray) -> ArrayT:
    """The rows of ``first`` and ``second`` at the rows ``at_first`` and ``at_second``."""
    out = np.empty((len(first) + len(second), *first.shape[1:]), dtype=first.dtype)
    out[at_first] = first
    out[at_second] = second
    return out  # type: ignore[return-value]
