"""Studies: one log replayed by several pipelines at once, side by side.

A sweep (one filter, parameters varied) and a comparison (several filters, the same
parameters) are the same thing here: a list of :class:`RunSpec`, each replayed in a
process of its own (each reads the log itself), summarised against the first. The
command line prints them and :mod:`ekfviz.viz.study` records them in one recording.
No rerun, no typer.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ekfviz.association import AssociationParams, Associator
from ekfviz.association.evaluation import AssociationTally
from ekfviz.core.batch import EventBatch
from ekfviz.core.params import FilterParams
from ekfviz.core.tables import TextTable
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import Consistency, reading
from ekfviz.evaluation.errors import Evaluation, evaluate
from ekfviz.filters.plugged import FilterFactory, PluginError
from ekfviz.filters.protocol import SlamFilter
from ekfviz.filters.spec import BUILTIN, FilterSpec, FilterSpecError, release
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.runner.replay import FilterLineError
from ekfviz.runner.run import Consumer, run
from ekfviz.sources import SourceArgs, open_source
from ekfviz.studies.executors import Executor, LocalExecutor

VARIABLE = ("sigma_x", "sigma_y", "sigma_alpha", "sigma_bearing", "sigma_range")


@dataclass(frozen=True, slots=True)
class RunSpec:
    """One pipeline of a study: a filter, its parameters, how the study names it.

    :param key: safe in an entity path (``variants/<key>`` or ``filters/<key>``)
    :param changes: how the parameters differ from the baseline's (sweeps)
    """

    label: str
    key: str
    params: FilterParams
    filter: FilterSpec = field(default_factory=lambda: FilterSpec(BUILTIN))
    changes: tuple[object, ...] = ()
    # how id-less scans are paired (None: --association known, ids only)
    association: AssociationParams | None = None


@dataclass(frozen=True, slots=True)
class Run:
    """One pipeline replayed: every event, the final evaluation with consistency, and
    the wall time of the filter and evaluation (reading the log included)."""

    spec: RunSpec
    events: EventBatch
    evaluation: Evaluation
    seconds: float
    # why the run stopped before the end of the log (a filter that failed), if it did
    failure: str | None = None
    # whether its NIS was derived with the filter's own R (it exposes measurement_noise)
    own_noise: bool = False

    @property
    def steps(self) -> int:
        return int(self.events.steps[-1]) if len(self.events) else 0


@dataclass(frozen=True, slots=True)
class RunFailure:
    """A run that could not record a single event: its filter failed to load or start."""

    spec: RunSpec
    message: str


class _Timed:
    """A filter factory that remembers what it made and how long making it took."""

    def __init__(self, make: FilterFactory) -> None:
        self.make = make
        self.seconds = 0.0
        self.made: object = None

    def __call__(self, params: FilterParams) -> SlamFilter:
        started = time.perf_counter()
        self.made = self.make(params)
        self.seconds += time.perf_counter() - started
        return self.made


def run_spec(
    path: Path,
    spec: RunSpec,
    truth: GroundTruth | None,
    keep_going: bool = False,
    source_args: SourceArgs | None = None,
) -> Run | RunFailure:
    """Replay the log at ``path`` (its source's options ``source_args``: ``--robot``...)
    with one pipeline's filter and parameters.

    The run's seconds exclude loading and constructing the filter (its imports, a
    worker's start).

    :param keep_going: a filter that fails is a result (a :class:`RunFailure`, or a
        :class:`Run` of the events before it with its ``failure``), not an error
    :raises FilterSpecError: the filter cannot be loaded
    :raises FilterLineError: the filter cannot go on at a line of the log
    """
    try:
        loaded = spec.filter.load()
    except FilterSpecError as error:
        if keep_going:
            return RunFailure(spec, str(error))
        raise
    make_filter = loaded if spec.filter.in_process else _Timed(loaded)
    started = time.perf_counter()
    consistency = Consistency(truth)
    batches: list[EventBatch] = []
    consumers: list[Consumer] = [consistency.add, batches.append]
    associator, tally = None, None
    if spec.association is not None:  # a run of its own: its own tentative landmarks
        sensor = RangeBearing()
        scan_truth = None if truth is None else truth.scan_ids
        associator = Associator(spec.association, sensor, spec.params.R, scan_truth=scan_truth)
        tally = AssociationTally(truth, sensor)
        consumers.append(tally.add_batch)
    failure = None
    try:
        events = open_source(path, source_args).events()
        run(events, spec.params, consumers, make_filter=make_filter, name=spec.filter.text,
            associator=associator)  # fmt: skip
    except FilterLineError as error:
        if not keep_going or not isinstance(error.__cause__, PluginError):
            raise  # not the filter's own failure: the input's, for every filter alike
        failure = f"{path}:{error.line}: {error}" if error.line else f"{path}: {error}"
        if not batches:
            return RunFailure(spec, failure)
    finally:
        release(loaded)
    seconds = time.perf_counter() - started
    own_noise = False
    if isinstance(make_filter, _Timed):
        seconds -= make_filter.seconds
        own_noise = getattr(make_filter.made, "measurement_noise", None) is not None
    joined = EventBatch.joined(batches)
    last = joined.last
    if tally is not None and truth is not None and tally.scans:
        # the map's ids are the association's: the truth under its pairing
        truth = tally.relabelled_truth(last.landmark_ids)
    evaluation = evaluate(last, truth, consistency)
    return Run(spec, joined, evaluation, seconds, failure, own_noise)


def run_specs(
    path: Path,
    specs: Sequence[RunSpec],
    truth: GroundTruth | None,
    workers: int | None = None,
    done: Callable[[Run | RunFailure], None] | None = None,
    executor: Executor | None = None,
    keep_going: bool = False,
    source_args: SourceArgs | None = None,
) -> list[Run | RunFailure]:
    """Replay every pipeline on ``executor`` (default: ``workers`` local processes);
    results in the specs' order.

    The result does not depend on the executor or the number of workers: each run is
    the same replay.
    """
    executor = LocalExecutor(workers) if executor is None else executor
    run = functools.partial(
        run_spec, path, truth=truth, keep_going=keep_going, source_args=source_args
    )
    return executor.map(run, specs, done=done)


@dataclass(frozen=True, slots=True)
class Summary:
    """What the study table says of one run."""

    label: str
    parameters: dict[str, float]
    mean_error: float | None
    max_error: float | None
    mean_mahalanobis: float | None
    inside: int | None
    landmarks: int
    final_pose: list[float]
    from_baseline: float
    mean_nis: float | None
    nis_inside: float | None
    reading: str
    filter: str
    seconds: float
    ms_per_step: float | None
    # the map beside its errors: a map inside 3 sigma because its ellipses are huge shows
    # here; and the errors after the best rigid alignment to the truth (the map's shape)
    mean_semi_major: float | None = None
    aligned_mean_error: float | None = None
    aligned_max_error: float | None = None


def summarise(run: Run, baseline: Run) -> Summary:
    """The row of one run, compared with the first (baseline) run's final pose."""
    evaluation = run.evaluation
    errors = [r.euclidean for r in evaluation.landmarks if r.euclidean is not None]
    distances = [r.mahalanobis for r in evaluation.landmarks if r.mahalanobis is not None]
    nis = updates_nis(run.events)
    consistency = evaluation.consistency
    count = consistency.nis if consistency is not None else None
    inside = sum(bool(r.inside_3sigma) for r in evaluation.landmarks) if distances else None
    summary = evaluation.summary
    read = reading(consistency, inside, len(distances))
    return Summary(
        label=run.spec.label,
        parameters={name: getattr(run.spec.params, name) for name in VARIABLE},
        mean_error=float(np.mean(errors)) if errors else None,
        max_error=float(np.max(errors)) if errors else None,
        mean_mahalanobis=float(np.mean(distances)) if distances else None,
        inside=inside,
        landmarks=len(evaluation.landmarks),
        final_pose=[float(v) for v in evaluation.pose],
        from_baseline=float(np.hypot(*(evaluation.pose[:2] - baseline.evaluation.pose[:2]))),
        mean_nis=float(np.mean(nis)) if nis else None,
        nis_inside=count.fraction_inside if count is not None and count.total else None,
        reading=read if not run.failure else f"stopped after step {run.steps}; till then: {read}",
        filter=run.spec.filter.text,
        seconds=run.seconds,
        ms_per_step=1000.0 * run.seconds / run.steps if run.steps else None,
        mean_semi_major=None if summary is None else summary.mean_semi_major,
        aligned_mean_error=None if summary is None else summary.aligned_mean_error,
        aligned_max_error=None if summary is None else summary.aligned_worst_error,
    )


def updates_nis(events: EventBatch) -> list[float]:
    """The NIS of every update that used landmarks, summed over them in order."""
    table = events.observed
    owner = np.repeat(np.arange(len(events)), table.counts)
    used = np.isfinite(table.nis)
    rows = np.unique(owner[used])
    sums = np.bincount(owner[used], weights=table.nis[used], minlength=len(events))
    found: list[float] = sums[rows].tolist()
    return found


def study_table(
    summaries: list[Summary],
    has_truth: bool,
    what: str,
    own_noise: set[str] | None = None,
    failed: Sequence[str] = (),
) -> TextTable:
    """The study's table for the terminal (the report has every column); ``failed``: the
    labels of the runs that failed before any event, a row each saying so."""
    columns = [what]
    if has_truth:
        columns += ["mean err", "worst", "aligned", "3σ axis", "Mahal.", "in 3σ"]
    columns += ["Δ base", "NIS in", "ms/step", "reading"]
    rows = []
    for s in summaries:
        cells = [s.label + ("*" if own_noise and s.label in own_noise else "")]
        if has_truth:
            inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
            cells += [
                _num(s.mean_error, 3), _num(s.max_error, 3), _num(s.aligned_mean_error, 3),
                _num(s.mean_semi_major, 3), _num(s.mean_mahalanobis, 2), inside,
            ]  # fmt: skip
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        cells += [f"{s.from_baseline:.3f}", nis_inside, _num(s.ms_per_step, 3), s.reading]
        rows.append(tuple(cells))
    for label in failed:  # (why: the line under the table)
        rows.append((label, *(["-"] * (len(columns) - 2)), "failed before its first event"))
    left = frozenset({what, "reading"})
    return TextTable(f"{what.capitalize()}s", tuple(columns), tuple(rows), left=left, lines=False)


def study_markdown(summaries: list[Summary], what: str) -> str:
    """The study's table as markdown, for the recording."""
    columns = [what, "mean error", "max error", "aligned mean error", "mean 3σ semi-major",
               "mean Mahalanobis", "in 3σ", "final pose",
               "Δ baseline", "mean NIS", "NIS in 95%", "ms per step", "reading"]  # fmt: skip
    rows = [
        "# Sweep" if what == "variant" else "# Comparison",
        "",
        "| " + " | ".join(columns) + " |",
        "|" + "---|" * len(columns),
    ]
    for s in summaries:
        pose = ", ".join(f"{v:.3f}" for v in s.final_pose)
        inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        rows.append(
            f"| {s.label} | {_num(s.mean_error, 3)} | {_num(s.max_error, 3)} |"
            f" {_num(s.aligned_mean_error, 3)} | {_num(s.mean_semi_major, 3)} |"
            f" {_num(s.mean_mahalanobis, 2)} | {inside} | {pose} | {s.from_baseline:.3f} |"
            f" {_num(s.mean_nis, 2)} | {nis_inside} | {_num(s.ms_per_step, 3)} | {s.reading} |"
        )
    return "\n".join(rows) + "\n"


def _num(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
