"""How good the association was, against the truth: per scan and over the run.

Each estimated landmark is paired with the true landmark most of its measurements
belonged to (its *identity*). A measurement's true landmark is the truth's ``scan_ids``
when given; with true landmarks only, it is the true landmark nearest to where the
measurement puts it (within ``NEAREST_TRUE_M``), from the estimated pose.

Per scan: a *correct* association pairs a measurement with the landmark whose identity
is its true landmark; a *wrong* one with any other (clutter paired with a landmark
included); a *missed* one is a measurement of a true landmark already in the map that
was not paired (started a new landmark, or was rejected).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ekfviz.core.batch import EventBatch
from ekfviz.core.records import Fate, ScanAssociation
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.range_bearing import RangeBearing

NEAREST_TRUE_M = 2.0  # without scan_ids: a measurement farther from every true landmark is clutter


@dataclass(frozen=True, slots=True)
class ScanScore:
    correct: int
    wrong: int
    missed: int


@dataclass(slots=True)
class AssociationTally:
    """Scores the association scan by scan (feed it every batch of a run's events)."""

    truth: GroundTruth | None
    sensor: RangeBearing = field(default_factory=RangeBearing)
    correct: int = 0
    wrong: int = 0
    missed: int = 0
    matched: int = 0
    new: int = 0
    rejected: int = 0
    confirmed: int = 0
    removed: int = 0
    scans: int = 0
    hypotheses: int = 0
    exhausted: int = 0
    fallback_nn: int = 0  # scans the search gave up on before any complete pairing
    _votes: dict[int, Counter[int]] = field(default_factory=dict)

    def identity(self, landmark_id: int) -> int | None:
        votes = self._votes.get(landmark_id)
        if not votes:
            return None
        return votes.most_common(1)[0][0]

    def true_ids(self, association: ScanAssociation, pose: FloatArray) -> IntArray | None:
        """The true landmark of each measurement of a scan (made from ``pose``), -1 for
        clutter."""
        if association.truth is not None:
            return association.truth
        if self.truth is None or not len(self.truth.ids):
            return None
        z = association.z
        points = np.array([self.sensor.inverse(pose, row) for row in z]).reshape(-1, 2)
        distance = np.hypot(
            points[:, None, 0] - self.truth.landmarks_xy[None, :, 0],
            points[:, None, 1] - self.truth.landmarks_xy[None, :, 1],
        )
        nearest = distance.argmin(axis=1) if len(points) else np.zeros(0, dtype=np.int64)
        close = (
            distance[np.arange(len(points)), nearest] <= NEAREST_TRUE_M if len(points) else nearest
        )
        return np.where(close, self.truth.ids[nearest], -1).astype(np.int64)

    def add_batch(self, events: EventBatch) -> None:
        """Score every scan of a batch of a run's events, in order."""
        for row in sorted(events.extras):
            association = events.extras[row].association
            if association is not None:
                self.add(association, events.poses[row])

    def add(self, association: ScanAssociation, pose: FloatArray) -> ScanScore | None:
        """Score one scan (made from ``pose``); None where there is no truth to judge by."""
        self.scans += 1
        # the three fates counted in one pass (Fate's values are 0, 1, 2)
        matched, new, rejected = np.bincount(association.fate, minlength=3)[:3].tolist()
        self.matched += matched
        self.new += new
        self.rejected += rejected
        self.confirmed += len(association.confirmed)
        self.removed += len(association.removed)
        self.hypotheses += association.hypotheses
        self.exhausted += int(association.exhausted)
        self.fallback_nn += int(association.fallback == "nearest neighbour")
        true_ids = self.true_ids(association, pose)
        if true_ids is None:
            return None
        mapped = {self.identity(i) for i in self._votes}
        for removed in association.removed.tolist():
            self._votes.pop(removed, None)
        correct = wrong = missed = 0
        for fate, landmark, true_id in zip(
            association.fate.tolist(), association.landmark.tolist(), true_ids.tolist(), strict=True
        ):
            if fate == Fate.REJECTED:
                missed += int(true_id >= 0 and true_id in mapped)
                continue
            if true_id >= 0:
                self._votes.setdefault(landmark, Counter())[true_id] += 1
            if fate == Fate.MATCHED:
                if true_id >= 0 and self.identity(landmark) == true_id:
                    correct += 1
                else:
                    wrong += 1
            elif true_id >= 0 and true_id in mapped:
                missed += 1
        self.correct += correct
        self.wrong += wrong
        self.missed += missed
        return ScanScore(correct, wrong, missed)

    def identities(self, landmark_ids: IntArray) -> dict[int, int]:
        """Estimated landmark id -> the true landmark it stands for, where one is known."""
        pairs = {int(i): self.identity(int(i)) for i in landmark_ids.tolist()}
        return {i: t for i, t in pairs.items() if t is not None}

    def relabelled_truth(self, landmark_ids: IntArray) -> GroundTruth | None:
        """The truth under the estimated landmarks' ids, for the usual evaluation."""
        if self.truth is None:
            return None
        identities = self.identities(landmark_ids)
        ids = np.array(sorted(identities), dtype=np.int64)
        xy = self.truth.lookup(np.array([identities[i] for i in ids.tolist()], dtype=np.int64))
        keep = np.isfinite(xy).all(axis=1)
        return GroundTruth(
            ids=ids[keep],
            landmarks_xy=xy[keep].reshape(-1, 2),
            poses_xytheta=self.truth.poses_xytheta,
            simulated_with=self.truth.simulated_with,
        )

    def report(self, landmark_ids: IntArray) -> dict[str, object]:
        """The ``association`` section of the report."""
        document: dict[str, object] = {
            "scans": self.scans,
            "matched": self.matched,
            "new": self.new,
            "rejected": self.rejected,
            "confirmed": self.confirmed,
            "removed": self.removed,
            "jcbb_hypotheses": self.hypotheses,
            "jcbb_budget_exhausted_scans": self.exhausted,
            "jcbb_fallback_nearest_neighbour_scans": self.fallback_nn,
            "landmarks": len(landmark_ids),
        }
        if self.truth is not None:
            identities = self.identities(landmark_ids)
            stands_for = Counter(identities.values())
            precision = (
                self.correct / (self.correct + self.wrong)
                if self.correct + self.wrong
                else math.nan
            )
            recall = (
                self.correct / (self.correct + self.missed)
                if self.correct + self.missed
                else math.nan
            )
            document.update(
                {
                    "correct": self.correct,
                    "wrong": self.wrong,
                    "missed": self.missed,
                    "precision": precision,
                    "recall": recall,
                    "spurious_landmarks": len(landmark_ids) - len(identities),
                    "duplicate_landmarks": sum(count - 1 for count in stands_for.values()),
                    "true_landmarks_mapped": len(stands_for),
                }
            )
        return document
