"""What a filter should be told, judged on held-out time (numpy only).

What a filter should be told: real logs have errors these estimates do not see (odometry
errors correlated over many seconds, a measurement bias, heavy tails), and a filter
told only the white part is over-confident. :func:`recommend` fits on the first part of
the run, scales the sigmas (the measurement by the NIS, the motion by the pose NEES,
:func:`scale_apart`; or one factor for all), and judges every candidate, the defaults
among them, on what the fit did not see (NEES and NIS over the held-out time, the final
map against the truth), the standard consistency tests against ground truth
(Bar-Shalom et al., 2001, ch. 5.4) beside the map's error and ellipse size.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ekfviz.association.gating import gated
from ekfviz.calibrate.fit import NO_CORRECTION, WINDOW_S, Calibration, calibrate
from ekfviz.core.batch import UPDATE, BatchBuilder, EventBatch
from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Control, LogEvent
from ekfviz.core.steps import log_steps
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.evaluation.consistency import Consistency, chi2_bounds, events_nis, poses_nees
from ekfviz.evaluation.errors import Evaluation, MapSummary, evaluate
from ekfviz.filters.ekf import EkfSlam
from ekfviz.runner.run import run

FIT_SHARE = 0.6  # the first 60 % of the run are fitted, the rest judges
NEES_TARGET = 3.0  # the mean of chi-square with 3 degrees of freedom
NEES_TOLERANCE = 1.1  # a mean NEES up to 10 % above it counts as consistent
SCALE_ROUNDS = 6  # replays of a scale's search at most, before its bisection
SCALE_RESOLUTION = 1.15  # the factor is found to within this ratio
MAX_SCALE = 12.0  # no factor beyond this: the search stops there and says so
LARGE_SCALE = 5.0  # a factor over this: the model misses errors of the log
# the held-out readings (NEES and NIS together) a recommended setting may have
TRUSTED_READINGS = ("consistent", "borderline", "too cautious")
MAP_CREDIBLE = 0.8  # a held-out map with this share of landmarks inside 3 sigma is credible
WIDENINGS = (2.0, 4.0)  # where no candidate is credible, the closest one widened so
LEFT_OUT_WARNING = 0.05  # more windows left out than this: said (a Gaussian: 0.1 %)
# a sigma whose fit hit its limit (0) is replaced in the replay by this share of the
# default sigma of its component: a filter must never be told a motion is exact
LIMIT_SHARE = 0.1


@dataclass(frozen=True, slots=True)
class RunStats:
    """A replay judged against the truth: mean NEES and NIS, their counts, the map.

    :param nees: mean pose NEES (3 expected; inf: the filter failed)
    :param nis: mean NIS per degree of freedom (1 expected)
    :param nees_inside: share of NEES values inside the 95 % bounds
    :param nis_inside: share of NIS values inside the 95 % bounds
    :param verdict: NEES and NIS together (:meth:`Consistency.combined`)
    :param map: the final map's summary, None without landmarks with truth
    """

    nees: float
    nis: float
    nees_inside: float
    nis_inside: float
    verdict: str
    map: MapSummary | None

    @classmethod
    def of(
        cls,
        nees: list[float],
        nis_total: float,
        dof_total: float,
        consistency: Consistency,
        evaluation: Evaluation,
    ) -> RunStats:
        """The figures of a run from its NEES values, NIS totals, counts and evaluation."""
        both = consistency.combined()
        return cls(
            nees=float(np.mean(nees)) if nees else math.nan,
            nis=nis_total / dof_total if dof_total else math.nan,
            nees_inside=consistency.nees.fraction_inside,
            nis_inside=consistency.nis.fraction_inside,
            verdict="no update" if both is None else both[0].value,
            map=evaluation.summary,
        )

    @property
    def credible(self) -> bool:
        """A map with at least ``MAP_CREDIBLE`` of its landmarks inside 3 sigma."""
        m = self.map
        return m is not None and m.landmarks > 0 and m.inside >= MAP_CREDIBLE * m.landmarks

    @property
    def error(self) -> float:
        return math.inf if self.map is None else self.map.mean_error

    def to_json(self) -> dict[str, object]:
        def value(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "mean_nees": value(self.nees),
            "mean_nis_per_dof": value(self.nis),
            "nees_inside": value(self.nees_inside),
            "nis_inside": value(self.nis_inside),
            "verdict": self.verdict,
            "map": None if self.map is None else self.map.to_json(),
        }


FAILED = RunStats(math.inf, math.inf, 0.0, 0.0, "failed", None)


class _HeldOut:
    """A consumer of a candidate's run: NEES, NIS and the consistency counts after ``after``
    (a time, or a step where the log has none)."""

    def __init__(self, truth: GroundTruth, after: float | None) -> None:
        self.truth, self.after = truth, after
        self.consistency = Consistency(truth)
        self.nees: list[float] = []
        self.nis_total = self.dof_total = 0.0

    def add(self, events: EventBatch) -> None:
        """Count the events of a batch after the fitted part (the updates' NEES and NIS,
        and the consistency counts)."""
        if self.after is not None:
            when = np.where(np.isnan(events.times), events.steps, events.times)
            events = events.take(np.flatnonzero(when > self.after))
        self.consistency.add(events)
        updates = np.flatnonzero(events.kinds == UPDATE)
        true_poses, known = self.truth.poses_of(events.steps[updates], events.times[updates])
        at = updates[known]
        nees, defined = poses_nees(events.poses[at], events.pose_covs[at], true_poses[known])
        self.nees += nees[defined].tolist()
        rows, totals, dofs = events_nis(events.observed)
        of_updates = events.kinds[rows] == UPDATE
        for total in totals[of_updates].tolist():  # in order, as the updates come
            self.nis_total += total
        self.dof_total += int(dofs[of_updates].sum())


def run_stats(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    params: FilterParams,
    *,
    after: float | None = None,
) -> RunStats:
    """Replay ``events`` with ``params`` and judge the run against ``truth``.

    :param after: count NEES and NIS only after this time (timed) or step (untimed);
        the map is judged at the end either way
    """
    held_out = _HeldOut(truth, after)
    try:
        last = run(events, params, [held_out.add])
    except FilterError:
        return FAILED
    if last is None:
        return FAILED
    consistency = held_out.consistency
    return RunStats.of(
        held_out.nees, held_out.nis_total, held_out.dof_total, consistency,
        evaluate(last, truth, consistency),
    )  # fmt: skip


def judge(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    params: FilterParams,
    *,
    after: float | None = None,
) -> RunStats:
    """What :func:`run_stats` finds, from the built-in filter driven directly.

    The replay makes a record of every event (a predict too) and checks the whole
    covariance now and then, which a judgement needs neither of: this loop does the
    filter's work as :func:`~ekfviz.runner.replay.replay` does it (the same steps, gate
    and odometry correction) and takes the NEES, NIS and final map from the filter,
    several times faster. A test holds it to :func:`run_stats`.
    """
    ekf = EkfSlam(params)
    consistency = Consistency(truth)
    nees_values: list[float] = []
    nis_total = dof_total = 0.0
    gate, R = params.gate, params.R
    correct = params.corrects_odometry
    step = 0
    time: float | None = None
    nees_bounds = chi2_bounds(3)
    try:
        numbers = log_steps(isinstance(event, Control) for event in events)
        for k, (event, (_, step)) in enumerate(zip(events, numbers, strict=True)):
            time = event.time
            if isinstance(event, Control):
                d, alpha = (
                    params.corrected(event.d, event.alpha) if correct else (event.d, event.alpha)
                )
                ekf.predict(d, alpha, event.dt)
                continue
            sighting = event
            if gate is not None and k:
                sighting, _ = gated(ekf.x, ekf.P, ekf.landmark_ids, event, R, gate)
            observations = ekf.observe(sighting.ids, sighting.z)
            if after is not None and (time if time is not None else float(step)) <= after:
                continue
            used = observations.nis[np.isfinite(observations.nis)]
            if used.size:
                total, dof = float(used.sum()), 2 * int(used.size)
                consistency.nis.add(total, chi2_bounds(dof))
                nis_total += total
                dof_total += dof
            true_pose = truth.pose_of(step, time)
            if true_pose is not None:
                e = ekf.x[:3] - true_pose
                e[2] = math.remainder(float(e[2]), 2.0 * math.pi)
                try:
                    value = float(e @ np.linalg.solve(ekf.P[:3, :3], e))
                except np.linalg.LinAlgError:
                    continue
                consistency.nees.add(value, nees_bounds)
                nees_values.append(value)
    except FilterError:
        return FAILED
    final = BatchBuilder()
    final.add(ekf.state_parts(), event=len(events), step=step, kind=UPDATE, time=time)
    last = final.build().last
    return RunStats.of(nees_values, nis_total, dof_total, consistency, evaluate(last, truth))


def mean_nees(events: Sequence[LogEvent], truth: GroundTruth, params: FilterParams) -> float:
    """The pose NEES averaged over the updates that have a true pose (inf if the filter
    fails, NaN when none has)."""
    return run_stats(events, truth, params).nees


def scaled(params: FilterParams, motion: float, measurement: float) -> FilterParams:
    """``params`` with the motion sigmas times ``motion``, the measurement's times
    ``measurement``."""
    return replace(
        params,
        sigma_x=params.sigma_x * motion,
        sigma_y=params.sigma_y * motion,
        sigma_alpha=params.sigma_alpha * motion,
        sigma_bearing=params.sigma_bearing * measurement,
        sigma_range=params.sigma_range * measurement,
    )


@dataclass(frozen=True, slots=True)
class Scaling:
    """Separate factors on the motion and the measurement sigmas (see :func:`scale_apart`).

    :param motion: k_m >= 1 on the motion sigmas, from the pose NEES
    :param measurement: k_z >= 1 on the measurement sigmas, from the NIS
    :param before: the run with the estimates as they are
    :param after: with both factors
    :param replays: replays it took
    :param at_limit: the motion search reached ``MAX_SCALE`` without consistency
    """

    motion: float
    measurement: float
    before: RunStats
    after: RunStats
    replays: int
    at_limit: bool = False

    def to_json(self) -> dict[str, object]:
        return {
            "motion": self.motion,
            "measurement": self.measurement,
            "before": self.before.to_json(),
            "after": self.after.to_json(),
            "replays": self.replays,
            "at_limit": self.at_limit,
        }


def scale_apart(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    params: FilterParams,
    *,
    together: bool = False,
    before: RunStats | None = None,
) -> Scaling:
    """The measurement factor from the NIS, then the motion factor from the NEES.

    k_z = sqrt(mean NIS per dof) (at least 1) makes the innovations as large as the
    filter expects; then the smallest k_m >= 1 whose replay has a mean pose NEES of at
    most ``NEES_TARGET`` (within ``NEES_TOLERANCE``): k_m grows by sqrt(NEES / 3) (at
    most 3 times a round) until the filter is consistent, then is bisected on a log
    scale to ``SCALE_RESOLUTION``. With ``together``, one factor on all five sigmas
    (k_z = k_m) is searched instead, the NIS left aside.

    :param before: the run with ``params`` as they are, when it is known
    """
    replays = 0
    if before is None:
        before = judge(events, truth, params)
        replays = 1
    k_z = 1.0
    if not together and math.isfinite(before.nis) and before.nis > 1.0:
        k_z = min(math.sqrt(before.nis), MAX_SCALE)
    current = before if k_z == 1.0 else judge(events, truth, scaled(params, 1.0, k_z))
    replays += k_z != 1.0

    def ok(stats: RunStats) -> bool:
        return stats.nees <= NEES_TARGET * NEES_TOLERANCE

    def factors(k: float) -> FilterParams:
        return scaled(params, k, k if together else k_z)

    def result(k: float, stats: RunStats, at_limit: bool = False) -> Scaling:
        return Scaling(k, k if together else k_z, before, stats, replays, at_limit)

    if ok(current) or math.isnan(current.nees):
        return result(1.0, current)
    low, high = 1.0, None
    best = stats = current
    while high is None and replays < SCALE_ROUNDS and low < MAX_SCALE:
        grow = 3.0 if not math.isfinite(stats.nees) else 1.05 * math.sqrt(stats.nees / NEES_TARGET)
        k = min(low * min(grow, 3.0), MAX_SCALE)
        stats = judge(events, truth, factors(k))
        replays += 1
        if ok(stats):
            high, best = k, stats
        else:
            low = k
    if high is None:
        return result(low, stats, at_limit=low >= MAX_SCALE)
    while high / low > SCALE_RESOLUTION and replays < SCALE_ROUNDS + 3:
        k = math.sqrt(low * high)
        stats = judge(events, truth, factors(k))
        replays += 1
        if ok(stats):
            high, best = k, stats
        else:
            low = k
    return result(high, best)


@dataclass(frozen=True, slots=True)
class Candidate:
    """A setting judged on the held-out part of the run.

    :param name: what it is (``defaults``, ``estimated``, ``scaled`` ...)
    :param params: the filter's parameters (the held-out replay starts elsewhere)
    :param held_out: the replay of the held-out part
    :param factors: (motion, measurement) scales on the estimates, None for the defaults
    """

    name: str
    params: FilterParams
    held_out: RunStats
    factors: tuple[float, float] | None = None

    def to_json(self) -> dict[str, object]:
        p = self.params
        return {
            "name": self.name,
            "sigmas": {
                "sigma_x": p.sigma_x, "sigma_y": p.sigma_y, "sigma_alpha": p.sigma_alpha,
                "sigma_bearing": p.sigma_bearing, "sigma_range": p.sigma_range,
            },
            "motion_noise": p.motion_noise.value,
            "gate": p.gate,
            "odometry_scale": list(p.odometry_scale),
            "odometry_bias": p.odometry_bias,
            "factors": None if self.factors is None else list(self.factors),
            "held_out": self.held_out.to_json(),
            "credible": self.held_out.credible,
        }  # fmt: skip


@dataclass(frozen=True, slots=True)
class Split:
    """Where a run is cut: the events fitted, the events held out and how they start.

    :param fit: the first part's events
    :param rest: the held-out events, from a control on
    :param start_pose: the true pose where the rest begins (its replay starts there)
    :param truth: the truth of the rest (per-step poses shifted to its steps)
    :param at: the time (s) or the step where it is cut
    """

    fit: list[LogEvent]
    rest: list[LogEvent]
    start_pose: FloatArray | None
    truth: GroundTruth
    at: float


def split_run(events: Sequence[LogEvent], truth: GroundTruth, share: float = FIT_SHARE) -> Split:
    """Cut a run at ``share`` of its time (of its events, untimed) at a control."""
    times = [e.time for e in events if e.time is not None]
    timed = len(times) == len(events) and len(times) > 1
    if timed:
        t0 = times[0]
        first = events[0]
        if isinstance(first, Control) and first.dt is not None:
            t0 -= first.dt
        cut_time = t0 + share * (times[-1] - t0)
        k = next((i for i, e in enumerate(events) if (e.time or 0.0) > cut_time), len(events))
    else:
        k = int(share * len(events))
    while k < len(events) and not isinstance(events[k], Control):
        k += 1
    fit, rest = list(events[:k]), list(events[k:])
    if timed:
        at = times[0] if not fit else float(fit[-1].time or 0.0)
        return Split(fit, rest, truth.pose_at(at), truth, at)
    steps = _steps(fit)
    start = truth.pose_of(steps, None)
    shifted = truth
    if truth.poses_xytheta is not None:
        shifted = replace(truth, poses_xytheta=truth.poses_xytheta[steps:])
    return Split(fit, rest, start, shifted, float(steps))


def _steps(events: Sequence[LogEvent]) -> int:
    """The step the replay of ``events`` ends at (counted as
    :func:`~ekfviz.runner.replay.replay` counts)."""
    steps = (step for _, step in log_steps(isinstance(event, Control) for event in events))
    return max(steps, default=0)  # (steps never go back)


@dataclass(frozen=True, slots=True)
class Recommendation:
    """What ``ekfviz calibrate`` found and recommends.

    :param calibration: the estimates, fitted on the first part of the run
    :param scaling: the factors found on the first part, motion and measurement apart
    :param together: the one factor on all sigmas found there
    :param candidates: every setting judged on the held-out part
    :param chosen: the index of the recommended one (None: no candidate's held-out reading
        is consistent, borderline or too cautious, so none is recommended)
    :param split: where the run was cut
    :param notes: what a user must know (limits hit, windows left out, large factors)
    """

    calibration: Calibration
    scaling: Scaling
    together: Scaling
    candidates: tuple[Candidate, ...]
    chosen: int | None
    split_at: float
    fit_share: float
    notes: tuple[str, ...]

    @property
    def best(self) -> Candidate | None:
        """The recommended candidate, if any is."""
        return None if self.chosen is None else self.candidates[self.chosen]


def estimated_params(
    calibration: Calibration, base: FilterParams, *, gate: float | None
) -> tuple[FilterParams, list[str]]:
    """``base`` with the estimates: sigmas, the odometry correction, the gate; a sigma
    that hit its fit's limit replaced (``LIMIT_SHARE`` of the default's), with a note."""
    motion = calibration.motion
    assert motion is not None
    notes: list[str] = []
    defaults = FilterParams()
    sigmas = list(motion.sigmas)
    for k, (name, default) in enumerate(
        zip(("x", "y", "alpha"), (defaults.sigma_x, defaults.sigma_y, defaults.sigma_alpha),
            strict=True)
    ):  # fmt: skip
        if name in motion.at_limit:
            sigmas[k] = LIMIT_SHARE * default
            notes.append(
                f"the motion sigma {name} hit the lower limit of its fit (0): the errors"
                f" left none for it; the replay uses {sigmas[k]:.3g}, a tenth of the"
                " default, since no motion is exact"
            )
    odometry = calibration.odometry
    correction = NO_CORRECTION if odometry is None else odometry.applied
    params = replace(
        base,
        sigma_x=sigmas[0], sigma_y=sigmas[1], sigma_alpha=sigmas[2],
        sigma_bearing=calibration.bearing.sigma, sigma_range=calibration.range.sigma,
        motion_noise=motion.model, gate=gate,
        odometry_scale=(correction[0], correction[1]), odometry_bias=correction[2],
    )  # fmt: skip
    return params, notes


def recommend(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    base: FilterParams,
    defaults: FilterParams,
    *,
    window_s: float = WINDOW_S,
    fit_share: float = FIT_SHARE,
    gate: float | None = None,
    heavy_tail_gate: float | None = None,
) -> Recommendation:
    """Fit on the first part of the run, judge the candidates on the rest, recommend one.

    The estimates (noise and odometry errors) and the scale factors come from the first
    ``fit_share`` of the run only. The candidates: the defaults (``defaults``, what a
    replay without options does), the estimates as they are, scaled apart (motion by the
    NEES, measurement by the NIS, :func:`scale_apart`) and scaled together (one factor),
    and, where an odometry correction was found, the defaults with it and both scalings
    without it. Each is replayed
    over the whole run, as the user's replay will be (a replay of the rest alone would
    start from a map-less state the user never sees, and misses the frame errors of the
    first minutes that dominate the final map), and judged on what the fit did not see:
    NEES and NIS over the held-out time, and the final map against the truth. A credible
    map (``MAP_CREDIBLE`` inside 3 sigma) beats one that is not, then the lower mean
    landmark error wins. The defaults are a candidate, so the recommendation is never
    worse than them by that order.

    :param base: the replay's parameters (start pose, model) the estimates go into
    :param heavy_tail_gate: the gate for measurements with heavy tails (None: no gate)
    """
    split = split_run(events, truth, fit_share)
    calibration = calibrate(split.fit, truth, window_s=window_s)
    corrected_events, corrected_fit = _corrected_once(events, split, calibration)
    if calibration.motion is None or calibration.sightings == 0:
        raise ValueError("no sightings or no controls with a true pose in the first part")
    heavy = not (calibration.bearing.gaussian and calibration.range.gaussian)
    estimated, notes = estimated_params(
        calibration, base, gate=gate if gate is not None else heavy_tail_gate if heavy else None
    )
    as_read = replace(estimated, odometry_scale=(1.0, 1.0), odometry_bias=0.0)
    before = judge(corrected_fit, truth, as_read)
    scaling = scale_apart(corrected_fit, truth, as_read, before=before)
    one = scale_apart(corrected_fit, truth, as_read, together=True, before=before)
    settings = _settings(defaults, estimated, scaling, one)

    def judged(params: FilterParams) -> RunStats:
        """The whole run judged on the held-out part (the events corrected once)."""
        if params.corrects_odometry and params.odometry_scale == estimated.odometry_scale:
            run = replace(params, odometry_scale=(1.0, 1.0), odometry_bias=0.0)
            return judge(corrected_events, truth, run, after=split.at)
        return judge(events, truth, params, after=split.at)

    candidates = _judged_candidates(settings, judged)
    # only a setting its own held-out reading does not call over-confident (nor unread)
    trusted = [k for k, c in enumerate(candidates) if c.held_out.verdict in TRUSTED_READINGS]
    chosen = min(
        trusted,
        key=lambda k: (not candidates[k].held_out.credible, candidates[k].held_out.error, k),
        default=None,
    )
    if chosen is not None:
        notes += _notes(calibration, scaling, candidates[chosen])
    return Recommendation(
        calibration, scaling, one, tuple(candidates), chosen, split.at, fit_share, tuple(notes)
    )


def _corrected_once(
    events: Sequence[LogEvent], split: Split, calibration: Calibration
) -> tuple[list[LogEvent], list[LogEvent]]:
    """The run's events and those of its fitted part with the odometry correction found
    applied to every control, once (the replays are then told no correction, the
    candidates keep theirs); as read where none was found."""
    if calibration.odometry is None or calibration.odometry.applied == NO_CORRECTION:
        return list(events), list(split.fit)
    k_d, k_alpha, bias = calibration.odometry.applied
    corrected: list[LogEvent] = [
        Control(e.line, k_d * e.d, k_alpha * e.alpha + bias * e.d, e.time, e.dt)
        if isinstance(e, Control)
        else e
        for e in events
    ]
    return corrected, corrected[: len(split.fit)]


Setting = tuple[str, FilterParams, tuple[float, float] | None]  # name, params, factors


def _settings(
    defaults: FilterParams, estimated: FilterParams, scaling: Scaling, one: Scaling
) -> list[Setting]:
    """The candidate settings (see :func:`recommend`), by name, with their scale factors
    of the motion and measurement noise (None: the defaults, not scaled)."""
    settings: list[Setting] = [
        ("defaults", defaults, None),
        ("estimated", estimated, (1.0, 1.0)),
        (
            "scaled apart",
            scaled(estimated, scaling.motion, scaling.measurement),
            (scaling.motion, scaling.measurement),
        ),
        ("scaled together", scaled(estimated, one.motion, one.motion), (one.motion, one.motion)),
    ]
    if estimated.corrects_odometry:
        # a log's odometry errors may be shared by its measurements (a range scale): the
        # correction is judged, not assumed
        plain = replace(estimated, odometry_scale=(1.0, 1.0), odometry_bias=0.0)
        settings.append((
            "scaled apart, odometry as read",
            scaled(plain, scaling.motion, scaling.measurement),
            (scaling.motion, scaling.measurement),
        ))  # fmt: skip
        settings.append((
            "scaled together, odometry as read", scaled(plain, one.motion, one.motion),
            (one.motion, one.motion),
        ))  # fmt: skip
        settings.append((
            "defaults, odometry corrected",
            replace(defaults, odometry_scale=estimated.odometry_scale,
                    odometry_bias=estimated.odometry_bias),
            None,
        ))  # fmt: skip
    return settings


def _judged_candidates(
    settings: list[Setting], judged: Callable[[FilterParams], RunStats]
) -> list[Candidate]:
    """Every setting judged once (two of the same parameters, once); where none has a
    credible map, the most accurate widened until its map is (a map inside its ellipses
    with a known error beats a tighter one that is not)."""
    candidates: list[Candidate] = []
    for name, params, factors in settings:
        if any(c.params == params for c in candidates):
            continue  # a factor of 1: the same setting as one judged already
        candidates.append(Candidate(name, params, judged(params), factors))
    if any(c.held_out.credible for c in candidates):
        return candidates
    closest = min(candidates, key=lambda c: c.held_out.error)
    for widen in WIDENINGS:
        motion, measurement = closest.factors or (1.0, 1.0)
        params = scaled(closest.params, widen, widen)
        stats = judged(params)
        name = f"{closest.name}, {widen:g} times wider"
        candidates.append(Candidate(name, params, stats, (motion * widen, measurement * widen)))
        if stats.credible:
            break
    return candidates


def _notes(calibration: Calibration, scaling: Scaling, best: Candidate) -> list[str]:
    notes = []
    motion = calibration.motion
    assert motion is not None
    if motion.left_out_share > LEFT_OUT_WARNING:
        notes.append(
            f"{motion.left_out_share:.0%} of the motion windows lie beyond the 99.9 % bound"
            " of the fit and were left out (a Gaussian: 0.1 %): the odometry has errors the"
            " fitted noise does not describe (slips, bumps, errors correlated over longer"
            " times)"
        )
    odometry = calibration.odometry
    if odometry is not None and odometry.at_limit:
        notes.append(
            f"the odometry fit hit its limits for {', '.join(odometry.at_limit)}: those terms"
            " are not applied (a log or truth out of step?)"
        )
    if scaling.at_limit:
        notes.append(
            f"no motion factor up to {MAX_SCALE:g} made the filter consistent on the fitted part"
        )
    if best.factors is not None and max(best.factors) > LARGE_SCALE:
        notes.append(
            f"the recommendation scales sigmas by {max(best.factors):.3g} (over"
            f" {LARGE_SCALE:g}): the log has errors the noise model does not describe"
            " (odometry errors correlated over minutes, biases, heavy tails); the filter"
            " is kept honest by inflating its covariance, at the cost of a less certain map"
        )
    return notes
