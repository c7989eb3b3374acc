"""Filter consistency: NEES against the true poses, NIS of the updates, chi-square bounds.

A consistent filter's errors match its covariance: the pose NEES e^T P^-1 e is chi-square
with 3 degrees of freedom, an update's NIS nu^T S^-1 nu chi-square with 2 per landmark
used. Averaged over N independent runs, N times the mean is chi-square with N times the
degrees of freedom. Too many values above the upper bound: the filter is over-confident;
below the lower one: too cautious.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from ekfviz.core.batch import EventBatch, ObservationTable
from ekfviz.core.records import EventRecord, Observations
from ekfviz.core.stats import chi2_quantile
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.models.angles import wrap_angle

CONFIDENCE = 0.95
INSIDE_FOR_CONSISTENT = 0.9  # share of steps inside the bounds to call a run consistent
# Below that, down to this share, a run is "borderline": a step more or less inside must
# not flip a reading from consistent to over-confident or too cautious.
INSIDE_BORDERLINE = 0.8
# A consistent map has 98.9 % of its landmarks within 3 sigma (chi-square, 2 dof); a
# share below this one is a map visibly off, whatever the NIS says.
MAP_INSIDE_FOR_CONSISTENT = 0.9


_BOUNDS: dict[tuple[float, float, int], tuple[float, float]] = {}


def chi2_bounds(dof: float, runs: int = 1, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Two-sided ``confidence`` bounds of the mean of ``runs`` chi-square(dof) values."""
    key = (dof, confidence, runs)
    bounds = _BOUNDS.get(key)
    if bounds is not None:
        return bounds
    tail = 0.5 * (1.0 - confidence)
    total = dof * runs
    bounds = _BOUNDS[key] = (
        chi2_quantile(tail, total) / runs,
        chi2_quantile(1.0 - tail, total) / runs,
    )
    return bounds


def pose_nees(record: EventRecord, truth: GroundTruth) -> float | None:
    """NEES e^T P^-1 e of the pose at the record's step, or None without a true pose or
    where the pose covariance is singular (a start known exactly, ``--init-pose-sigma 0
    0 0``: the NEES is undefined there, not infinite)."""
    true_pose = truth.pose_of(record.step, record.time)
    if true_pose is None:
        return None
    e = record.pose - true_pose
    e[2] = wrap_angle(float(e[2]))
    try:
        return float(e @ np.linalg.solve(record.pose_cov, e))
    except np.linalg.LinAlgError:
        return None


def poses_nees(
    poses: FloatArray, covs: FloatArray, true_poses: FloatArray
) -> tuple[FloatArray, BoolArray]:
    """:func:`pose_nees` of many poses (k, 3) with their covariances (k, 3, 3) against
    true poses (k, 3), to the bit: the NEES (k,), and where it is defined (a singular
    covariance's is not)."""
    e = poses - true_poses
    e[:, 2] = [wrap_angle(angle) for angle in e[:, 2].tolist()]
    defined = np.ones(len(e), dtype=bool)
    try:  # solve, per matrix as for one; the products as one pose's e @ x
        whitened = np.linalg.solve(covs, e[:, :, None])
    except np.linalg.LinAlgError:  # some covariance is singular: one at a time
        whitened = np.zeros((len(e), 3, 1))
        for k in range(len(e)):
            try:
                whitened[k, :, 0] = np.linalg.solve(covs[k], e[k])
            except np.linalg.LinAlgError:
                defined[k] = False
    nees: FloatArray = (e[:, None, :] @ whitened)[:, 0, 0]
    return nees, defined


def update_nis(record: EventRecord) -> tuple[float, int] | None:
    """The NIS of an update summed over the landmarks it used, and its degrees of freedom."""
    return None if record.observations is None else observations_nis(record.observations)


def observations_nis(observations: Observations) -> tuple[float, int] | None:
    """:func:`update_nis` of what an update did."""
    values = observations.nis.tolist()
    total = sum(values)
    if values and math.isfinite(total):  # every value used: the sum as it would be
        return total, 2 * len(values)
    used = [value for value in values if math.isfinite(value)]
    if not used:
        return None
    return sum(used), 2 * len(used)


def events_nis(table: ObservationTable) -> tuple[IntArray, FloatArray, IntArray]:
    """:func:`update_nis` of every event of ``table`` that used landmarks, the events of
    one length at once: their rows, the sums (k,) and their degrees of freedom (k,)."""
    rows = np.flatnonzero(table.present)
    counts = table.counts[rows]
    found: list[tuple[IntArray, FloatArray, IntArray]] = []
    for m in np.unique(counts).tolist():
        if not m:
            continue
        at = rows[counts == m]
        values = table.nis[table.starts[at][:, None] + np.arange(m)]
        used = np.isfinite(values)
        # summed in order, as update_nis sums a line (the last of the running sums); an
        # observation not used adds 0, which changes no sum
        totals = np.cumsum(np.where(used, values, 0.0), axis=1)[:, -1]
        dofs = 2 * used.sum(axis=1)
        some = dofs > 0
        found.append((at[some], totals[some], dofs[some]))
    if not found:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
    joined_rows = np.concatenate([f[0] for f in found])
    order = np.argsort(joined_rows, kind="stable")
    return (
        joined_rows[order],
        np.concatenate([f[1] for f in found])[order],
        np.concatenate([f[2] for f in found]).astype(np.int64)[order],
    )


class Verdict(str, enum.Enum):
    CONSISTENT = "consistent"
    BORDERLINE = "borderline"
    OVER_CONFIDENT = "over-confident"
    TOO_CAUTIOUS = "too cautious"


@dataclass(slots=True)
class BoundCount:
    """How many values of a statistic fell below, inside and above their bounds."""

    below: int = 0
    inside: int = 0
    above: int = 0

    def add(self, value: float, bounds: tuple[float, float]) -> None:
        if value < bounds[0]:
            self.below += 1
        elif value > bounds[1]:
            self.above += 1
        else:
            self.inside += 1

    def add_many(self, values: FloatArray, bounds: tuple[float, float]) -> None:
        """:meth:`add` of every value."""
        below = int(np.count_nonzero(values < bounds[0]))
        above = int(np.count_nonzero(values > bounds[1]))
        self.below += below
        self.above += above
        self.inside += len(values) - below - above

    @property
    def total(self) -> int:
        return self.below + self.inside + self.above

    @property
    def fraction_inside(self) -> float:
        return self.inside / self.total if self.total else math.nan

    @property
    def verdict(self) -> Verdict | None:
        """Consistent with at least ``INSIDE_FOR_CONSISTENT`` of the values inside,
        borderline down to ``INSIDE_BORDERLINE``, else over-confident (more above than
        below) or too cautious."""
        if not self.total:
            return None
        if self.fraction_inside >= INSIDE_FOR_CONSISTENT:
            return Verdict.CONSISTENT
        if self.fraction_inside >= INSIDE_BORDERLINE:
            return Verdict.BORDERLINE
        return Verdict.OVER_CONFIDENT if self.above >= self.below else Verdict.TOO_CAUTIOUS

    def leaning(self) -> str:
        """Where the values outside the bounds lie, e.g. ``12% high``; empty if none."""
        if not self.total or self.inside == self.total:
            return ""
        if self.above >= self.below:
            return f"{self.above / self.total:.0%} high"
        return f"{self.below / self.total:.0%} low"

    def to_json(self) -> dict[str, object]:
        verdict = self.verdict
        return {
            "count": self.total,
            "below": self.below,
            "inside": self.inside,
            "above": self.above,
            "fraction_inside": None if not self.total else self.fraction_inside,
            "verdict": None if verdict is None else verdict.value,
        }


@dataclass(slots=True)
class Consistency:
    """Running count of NEES (per step, with true poses) and NIS (per update) in bounds."""

    truth: GroundTruth | None = None
    nees: BoundCount = field(default_factory=BoundCount)
    nis: BoundCount = field(default_factory=BoundCount)
    without_true_pose: int = 0  # corrected states past the truth's last pose
    singular_pose: int = 0  # corrected states whose pose covariance is singular
    last_step: int = -1  # the last step counted (a truth with poses past it: not this log's?)

    @property
    def unused_true_poses(self) -> int:
        """The true poses (one per step) past the last step counted."""
        poses = None if self.truth is None else self.truth.poses_xytheta
        if poses is None or self.last_step < 0:
            return 0
        return max(0, len(poses) - (self.last_step + 1))

    def add(self, events: EventBatch) -> None:
        """Count a batch of a run's events: the NIS of every update that used
        landmarks, and the NEES of every event that ends a step (not a predict)."""
        if not len(events):
            return
        self.last_step = max(self.last_step, int(events.steps.max()))
        self._add_nis(events.observed)
        truth = self.truth
        if truth is None:
            return
        corrected = events.corrected
        true_poses, known = truth.poses_of(events.steps[corrected], events.times[corrected])
        at = corrected[known]
        nees, defined = poses_nees(events.poses[at], events.pose_covs[at], true_poses[known])
        self.nees.add_many(nees[defined], chi2_bounds(3))
        self.singular_pose += int(np.count_nonzero(~defined))
        if truth.poses_xytheta is not None:  # (a track's times may lie outside it: no step)
            self.without_true_pose += int(np.count_nonzero(~known))

    def _add_nis(self, table: ObservationTable) -> None:
        """Count the NIS of every event of ``table`` that used landmarks."""
        _, totals, dofs = events_nis(table)
        for dof in np.unique(dofs).tolist():
            self.nis.add_many(totals[dofs == dof], chi2_bounds(dof))

    def combined(self) -> tuple[Verdict, str] | None:
        """One verdict from NEES and NIS together, and why where the two counts do not
        show it ("" where they do); None with neither.

        The NEES sees the pose error against the pose covariance only, and a covariance
        inflated until it holds the errors passes it. The NIS sees the measurements
        against what the filter expects of them: far below its bounds, the filter expects
        far more error than its measurements show. So: NEES consistent (or borderline)
        but NIS mostly below its bounds reads "too cautious"; either one over-confident
        reads "over-confident"; both consistent reads "consistent".
        """
        nees, nis = self.nees.verdict, self.nis.verdict
        if nees is None or nis is None:
            only = nees if nees is not None else nis
            return None if only is None else (only, "")
        if Verdict.OVER_CONFIDENT in (nees, nis):
            which = "NEES" if nees is Verdict.OVER_CONFIDENT else "NIS"
            return Verdict.OVER_CONFIDENT, f"its {which} lies above the bounds"
        if nis is Verdict.TOO_CAUTIOUS or nees is Verdict.TOO_CAUTIOUS:
            if nees is not Verdict.TOO_CAUTIOUS:
                return Verdict.TOO_CAUTIOUS, (
                    f"its NEES looks {nees.value} but its NIS lies {self.nis.leaning()}"
                    " (a covariance inflated until the truth falls inside it)"
                )
            return Verdict.TOO_CAUTIOUS, "its NEES lies below the bounds"
        if Verdict.BORDERLINE in (nees, nis):
            return Verdict.BORDERLINE, ""
        return Verdict.CONSISTENT, ""

    def verdict_line(self) -> str | None:
        """The verdict, said once: what it rests on, what it is, and why where the counts
        do not show it; None with neither statistic."""
        both = self.combined()
        if both is None:
            return None
        verdict, why = both
        basis = " and ".join(n for n, c in (("NEES", self.nees), ("NIS", self.nis)) if c.total)
        alone = "" if self.nees.total and self.nis.total else " alone"
        looks = (
            "consistent only just (borderline)" if verdict is Verdict.BORDERLINE else verdict.value
        )
        return f"Verdict from the {basis}{alone}: the filter looks {looks}" + (
            f": {why}" if why else ""
        )

    def summary(self) -> list[str]:
        """One sentence per statistic, then the verdict once, for the terminal and the
        evaluation document."""
        lines = []
        for name, count, what in (
            ("NEES", self.nees, "steps"),
            ("NIS", self.nis, "updates"),
        ):
            if count.verdict is None:
                continue
            lines.append(
                f"{name}: {count.inside} of {count.total} {what} ({count.fraction_inside:.1%})"
                f" inside the {CONFIDENCE:.0%} chi-square bounds, {count.above} above,"
                f" {count.below} below"
            )
            if name == "NEES" and self.without_true_pose:
                judged = count.total + self.without_true_pose
                lines.append(
                    f"NEES: only {count.total} of {judged} corrected states have a true pose:"
                    " the truth file ends before the run does; the rest are not judged"
                )
            if name == "NEES" and self.unused_true_poses:
                lines.append(
                    f"NEES: the truth file has {self.unused_true_poses} true pose(s) past the"
                    f" run's last step ({self.last_step}), not used: is it the truth of a"
                    " longer run, or of another log?"
                )
            if name == "NEES" and self.singular_pose:
                lines.append(
                    f"NEES: {self.singular_pose} corrected state(s) with a singular pose"
                    " covariance (a start known exactly) are not judged"
                )
        verdict = self.verdict_line()
        if verdict is not None:
            lines.append(verdict)
        return lines

    def to_json(self) -> dict[str, object]:
        both = self.combined()
        return {
            "nees": self.nees.to_json(),
            "nis": self.nis.to_json(),
            "verdict": None if both is None else both[0].value,
            "steps_without_true_pose": self.without_true_pose,
            "true_poses_unused": self.unused_true_poses,
            "confidence": CONFIDENCE,
        }


def reading(consistency: Consistency | None, inside: int | None, landmarks: int) -> str:
    """A one-line reading of a run: by its NEES where there are true poses, else by its
    NIS; never "consistent" while its map is visibly off (fewer than
    ``MAP_INSIDE_FOR_CONSISTENT`` of the landmarks inside their 3-sigma ellipses).

    :param inside: landmarks with truth inside their 3-sigma ellipse (None: no truth)
    :param landmarks: landmarks with truth
    """
    counts = []
    if consistency is not None:
        counts = [
            (n, c) for n, c in (("NEES", consistency.nees), ("NIS", consistency.nis)) if c.total
        ]
    map_off = (
        inside is not None and landmarks > 0 and inside < MAP_INSIDE_FOR_CONSISTENT * landmarks
    )
    if not counts and not map_off:
        if inside is not None and landmarks > 0:  # an offline filter: its map alone
            return f"no NEES or NIS; map: {inside}/{landmarks} landmarks in 3σ"
        return "no update to judge"
    verdict = counts[0][1].verdict if counts else None
    both = None if consistency is None else consistency.combined()
    if (
        both is not None
        and both[0] is Verdict.TOO_CAUTIOUS
        and verdict
        in (
            Verdict.CONSISTENT,
            Verdict.BORDERLINE,
        )
    ):  # a NEES that passes only because the covariance is inflated: the NIS shows it
        verdict = Verdict.TOO_CAUTIOUS
    if map_off and verdict in (
        None,
        Verdict.CONSISTENT,
        Verdict.BORDERLINE,
        Verdict.OVER_CONFIDENT,
    ):
        verdict = Verdict.OVER_CONFIDENT
    assert verdict is not None
    details = [
        f"{name} {count.leaning()}"
        for name, count in counts
        if count.verdict is not Verdict.CONSISTENT and count.leaning()
    ]
    if map_off:
        details.append(f"{inside}/{landmarks} landmarks in 3σ")
    return verdict.value + (": " + ", ".join(details) if details else "")
