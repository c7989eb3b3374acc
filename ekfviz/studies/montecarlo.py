"""Monte-Carlo consistency: many simulated runs of a scenario, NEES and NIS averaged per step.

Numpy only. Each trial simulates the scenario with its own seed, replays it through the
filter and keeps the pose NEES after every step and the NIS of every update. With
id-less scans (misses, clutter) each trial pairs them with an associator of its own, so
the verdict is that of the filter and its association together. Averaged
over N trials, N times the mean NEES is chi-square with 3N degrees of freedom if the
filter is consistent; the same holds for the NIS with the summed degrees of freedom.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ekfviz.association import AssociationParams, Associator
from ekfviz.core.batch import EventBatch
from ekfviz.core.params import FilterParams
from ekfviz.core.stats import chi2_quantile
from ekfviz.core.tables import Styled, TextTable
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.evaluation.consistency import (
    CONFIDENCE,
    BoundCount,
    Verdict,
    events_nis,
    poses_nees,
)
from ekfviz.filters.spec import BUILTIN, load_filter
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.runner.run import run as replay_run
from ekfviz.sim.scenarios import Scenario
from ekfviz.sim.simulate import Detection, Noise
from ekfviz.studies.executors import LocalExecutor


@dataclass(frozen=True, slots=True)
class Trials:
    """What every trial shares: the world, the true noise and prior, the filter."""

    scenario: Scenario
    true_noise: Noise
    init_pose_sigma: tuple[float, float, float]
    params: FilterParams
    filter: str = BUILTIN  # a --filter value (see ekfviz.filters)
    detection: Detection = field(default_factory=Detection)  # misses, clutter, id-less scans
    laps: int = 1
    # how id-less scans are paired, each trial with its own associator
    association: AssociationParams | None = None


@dataclass(frozen=True, slots=True)
class TrialResult:
    """One trial, by step (0 = the start): NEES, NIS and its degrees of freedom (NaN/0
    where a step had no update)."""

    nees: FloatArray
    nis: FloatArray
    nis_dof: IntArray


class _Trial:
    """A trial's consumer: the pose NEES and the NIS of every step that has them."""

    def __init__(self, truth: GroundTruth, steps: int) -> None:
        self.truth = truth
        self.nees = np.full(steps, np.nan)
        self.nis = np.full(steps, np.nan)
        self.nis_dof = np.zeros(steps, dtype=np.int64)

    def add(self, events: EventBatch) -> None:
        """The NEES and NIS of the events of a batch that end a step."""
        corrected = events.corrected
        steps = events.steps[corrected]
        true_poses, known = self.truth.poses_of(steps, events.times[corrected])
        at = corrected[known]
        nees, defined = poses_nees(events.poses[at], events.pose_covs[at], true_poses[known])
        self.nees[steps[known][defined]] = nees[defined]
        rows, totals, dofs = events_nis(events.observed)
        self.nis[events.steps[rows]], self.nis_dof[events.steps[rows]] = totals, dofs


def run_trial(trials: Trials, seed: int) -> TrialResult:
    """Simulate and replay one trial."""
    run = trials.scenario.run(
        trials.true_noise, seed=seed, init_pose_sigma=trials.init_pose_sigma,
        detection=trials.detection, laps=trials.laps,
    )  # fmt: skip
    truth = GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta)
    associator = None
    if trials.association is not None and run.scan_events is not None:
        associator = Associator(trials.association, RangeBearing(), trials.params.R)
    make_filter = load_filter(trials.filter)
    events = run.scan_events if run.scan_events is not None else run.events
    trial = _Trial(truth, len(run.poses_xytheta))
    replay_run(events, trials.params, [trial.add], make_filter=make_filter, name=trials.filter,
               associator=associator)  # fmt: skip
    nees, nis, nis_dof = trial.nees, trial.nis, trial.nis_dof
    return TrialResult(nees, nis, nis_dof)


@dataclass(frozen=True, slots=True)
class MonteCarlo:
    """NEES and NIS averaged over the trials, per step, with the bounds of such a mean.

    :param mean_nees: (T+1,) mean NEES per step
    :param nees_bounds: (T+1, 2) bounds of the mean NEES (NaN where no trial had a value)
    :param mean_nis: (T+1,) mean NIS per step (NaN at steps without updates)
    :param nis_bounds: (T+1, 2) bounds of the mean NIS
    """

    runs: int
    mean_nees: FloatArray
    nees_bounds: FloatArray
    mean_nis: FloatArray
    nis_bounds: FloatArray
    nees: BoundCount
    nis: BoundCount

    def table(self, title: str) -> TextTable:
        """The NEES and NIS counts against their bounds, with a verdict each."""
        colours = {Verdict.CONSISTENT: "green", Verdict.BORDERLINE: "yellow"}
        rows = []
        for name, count in (("mean NEES per step", self.nees), ("mean NIS per step", self.nis)):
            verdict = count.verdict
            colour = colours.get(verdict or Verdict.CONSISTENT, "bold red")
            inside = (
                f"{count.inside}/{count.total} ({count.fraction_inside:.1%})"
                if count.total
                else "-"
            )
            rows.append((
                name, inside, str(count.above), str(count.below),
                "-" if verdict is None else Styled(verdict.value, colour),
            ))  # fmt: skip
        columns = ("statistic", "inside 95%", "above", "below", "verdict")
        return TextTable(title, columns, tuple(rows), left=frozenset({"statistic", "verdict"}))

    def to_json(self) -> dict[str, object]:
        def listed(values: FloatArray) -> list[float | None]:
            return [None if not np.isfinite(v) else float(v) for v in values]

        constant = np.unique(self.nees_bounds[np.isfinite(self.nees_bounds[:, 0])], axis=0)
        return {
            "runs": self.runs,
            "confidence": CONFIDENCE,
            "mean_nees": listed(self.mean_nees),
            "nees_bounds": constant[0].tolist() if len(constant) == 1 else None,
            "nees_bounds_per_step": [listed(b) for b in self.nees_bounds],
            "fraction_inside": self.nees.fraction_inside if self.nees.total else None,
            "verdict": None if self.nees.verdict is None else self.nees.verdict.value,
            "nees": self.nees.to_json(),
            "mean_nis": listed(self.mean_nis),
            "nis_bounds_per_step": [listed(b) for b in self.nis_bounds],
            "nis": self.nis.to_json(),
        }


def monte_carlo(trials: Trials, runs: int, seed: int = 0, workers: int | None = None) -> MonteCarlo:
    """Run ``runs`` trials with seeds ``seed``, ``seed + 1``, ... over the machine's cores."""
    seeds = [seed + k for k in range(runs)]
    # the local executor stops its workers at once on Ctrl-C (see ekfviz.studies.executors)
    results = LocalExecutor(workers).map(functools.partial(run_trial, trials), seeds)
    return average(results)


def average(results: list[TrialResult]) -> MonteCarlo:
    """Per-step means over trials and the two-sided bounds of those means."""
    nees = np.array([r.nees for r in results])
    nis = np.array([r.nis for r in results])
    dof = np.array([r.nis_dof for r in results])
    have_nees = np.isfinite(nees).sum(axis=0)
    mean_nees = np.where(have_nees > 0, np.nansum(nees, axis=0) / np.maximum(have_nees, 1), np.nan)
    have_nis = np.isfinite(nis).sum(axis=0)
    mean_nis = np.where(have_nis > 0, np.nansum(nis, axis=0) / np.maximum(have_nis, 1), np.nan)
    nees_bounds = _mean_bounds(3 * have_nees, have_nees)
    nis_bounds = _mean_bounds(dof.sum(axis=0), have_nis)
    return MonteCarlo(
        runs=len(results),
        mean_nees=mean_nees,
        nees_bounds=nees_bounds,
        mean_nis=mean_nis,
        nis_bounds=nis_bounds,
        nees=_count(mean_nees, nees_bounds),
        nis=_count(mean_nis, nis_bounds),
    )


def _mean_bounds(total_dof: IntArray, count: IntArray) -> FloatArray:
    """Bounds of a mean of ``count`` chi-square values whose degrees of freedom sum to
    ``total_dof``: the quantiles of chi-square(total_dof), divided by ``count``."""
    tail = 0.5 * (1.0 - CONFIDENCE)
    bounds = np.full((len(count), 2), np.nan)
    cache: dict[tuple[int, int], tuple[float, float]] = {}
    for step, (k, n) in enumerate(zip(total_dof.tolist(), count.tolist(), strict=True)):
        if n == 0 or k == 0:
            continue
        if (k, n) not in cache:
            cache[k, n] = (chi2_quantile(tail, k) / n, chi2_quantile(1.0 - tail, k) / n)
        bounds[step] = cache[k, n]
    return bounds


def _count(means: FloatArray, bounds: FloatArray) -> BoundCount:
    count = BoundCount()
    for value, (lo, hi) in zip(means.tolist(), bounds.tolist(), strict=True):
        if np.isfinite(value) and np.isfinite(lo):
            count.add(value, (lo, hi))
    return count
