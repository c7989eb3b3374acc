"""The batch of records of one send as columns: the one buffer every part of the
picture draws from, built once per send (see :mod:`ekfviz.viz.layers`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from ekfviz.core.records import EventKind, EventRecord
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
    def of(records: list[EventRecord], corrected: IntArray) -> Observed:
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

    :param records: the records, in order
    :param whole: (count,) whether each update logs the whole map's ellipses
    :param rows: their timelines
    :param poses: (count, 3) and ``pose_covs`` (count, 3, 3)
    :param is_predict: (count,) which records are predicts; ``corrected`` the others' rows
    :param observed: what their updates did with their observations
    """

    records: list[EventRecord]
    whole: list[bool]
    rows: Rows
    poses: FloatArray
    pose_covs: FloatArray
    is_predict: npt.NDArray[np.bool_]
    corrected: IntArray
    observed: Observed

    @staticmethod
    def of(pending: list[tuple[EventRecord, bool]], clock: Clock) -> Batch:
        records = [record for record, _ in pending]
        count = len(records)
        rows = clock.rows(
            np.fromiter((record.step for record in records), np.int64, count),
            np.fromiter((record.event for record in records), np.int64, count),
            np.fromiter(
                (math.nan if record.time is None else record.time for record in records),
                np.float64,
                count,
            ),
        )
        is_predict = np.fromiter(
            (record.kind is EventKind.PREDICT for record in records), bool, count
        )
        corrected = np.flatnonzero(~is_predict)
        return Batch(
            records=records,
            whole=[whole for _, whole in pending],
            rows=rows,
            # concatenated and reshaped: np.stack costs three times as much per record
            poses=np.concatenate([record.pose for record in records]).reshape(count, 3),
            pose_covs=np.concatenate([record.pose_cov for record in records]).reshape(count, 3, 3),
            is_predict=is_predict,
            corrected=corrected,
            observed=Observed.of(records, corrected),
        )

    def updates(self) -> list[tuple[int, EventRecord, bool]]:
        """(row, record, logs the whole map) of every update and initialisation."""
        return [(k, self.records[k], self.whole[k]) for k in self.corrected.tolist()]
