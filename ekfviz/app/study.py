"""What ``sweep`` and ``compare`` share: a log replayed by a list of run specifications
(:class:`~ekfviz.studies.runs.RunSpec`), summarised against the first, saved as one
recording and a report.

:func:`study` runs the specs and records them; :func:`run_study` is the use case around
it: outputs checked, the default recording named, progress told, the report written.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz import __version__, signals
from ekfviz.app.errors import in_family, stopped_study
from ekfviz.app.inputs import StudyInput, source_events, study_input
from ekfviz.app.outputs import default_output, filter_module, saved_line
from ekfviz.app.reporting import Reporter
from ekfviz.app.settings import (
    AssociationSettings,
    ExecutionSettings,
    FilterSettings,
    filter_params,
)
from ekfviz.core.errors import FilterError
from ekfviz.core.tables import TextTable
from ekfviz.core.truth import GroundTruth
from ekfviz.filters.spec import FilterSpecError, release
from ekfviz.io.files import check_outputs, write_json
from ekfviz.io.text import WarningCallback
from ekfviz.io.truth import read_truth
from ekfviz.runner.replay import FilterLineError
from ekfviz.sources import OwnTruth, SourceArgs, open_source
from ekfviz.studies.runs import RunSpec, study_markdown, study_table

if TYPE_CHECKING:
    from ekfviz.association import AssociationParams
    from ekfviz.studies.executors import Executor
    from ekfviz.studies.runs import Run, RunFailure, Summary


@dataclass(frozen=True, slots=True)
class StudyRequest:
    """What a sweep and a comparison are asked alike: the log (``source_args``: its
    format's options) and its truth, the filter's settings, where the runs execute, the
    association of id-less scans, the recording (None: ``recordings/<log>-<kind>.rrd``)
    and the report.

    :param given: the names of the options the user gave (the others yield to what the
        input states of itself)
    :param command: the command line, as the recording tells it
    """

    data: Path
    truth: Path | None = None
    source_args: SourceArgs = field(default_factory=SourceArgs)
    no_truth: bool = False
    save: Path | None = None
    report: Path | None = None
    filter: FilterSettings = field(default_factory=FilterSettings)
    execution: ExecutionSettings = field(default_factory=ExecutionSettings)
    association: AssociationSettings = field(default_factory=AssociationSettings)
    given: frozenset[str] = frozenset()
    command: str = "ekfviz"

    def was_given(self, name: str) -> bool:
        return name in self.given


@dataclass(frozen=True, slots=True)
class StudyResult:
    """A study run and recorded: its runs in order, their summaries, the input's digest."""

    runs: list[Run]
    summaries: list[Summary]
    truth: GroundTruth | None
    input_sha256: str
    # the runs whose filter failed before any event (compare), with why
    failures: list[RunFailure] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class StudyOutcome:
    """What a study shows: the notes on what was chosen for its runs (the start pose),
    its table, the runs that used their own R, those that stopped or failed (why), and
    the line saying where its recording is."""

    result: StudyResult
    notes: tuple[str, ...]
    table: TextTable
    own_noise: list[str]
    stopped: list[str]
    failed: list[str]
    saved: str


@dataclass(frozen=True, slots=True)
class StudyPlan:
    """A study made ready by ``sweep`` or ``compare``: its runs and their description.

    :param root: ``variants`` (a sweep) or ``filters`` (a comparison)
    :param parameters: what the recording says of the study
    :param report_extra: what the report says of it besides its rows
    :param keep_going: a filter that fails is a row saying why (compare)
    :param notes: what was chosen for the runs (the start pose), said before the table
    :param inputs: the files the log's source reads (a dataset directory's)
    """

    specs: list[RunSpec]
    root: str
    parameters: dict[str, object]
    report_extra: dict[str, object]
    executor: Executor
    keep_going: bool = False
    own_truth: OwnTruth | None = None
    notes: tuple[str, ...] = ()
    inputs: tuple[Path, ...] = ()

    @property
    def what(self) -> str:
        return "variant" if self.root == "variants" else "filter"


def opened_study(
    study: StudyRequest, reporter: Reporter
) -> tuple[StudyInput, AssociationParams | None]:
    """A study's input opened with its filter's parameters (the log's defaults, the
    options given), and the pairing of its id-less scans (None: the log has ids)."""
    given = filter_params(study.filter, log=study.data, given=study.was_given, note=reporter.note)
    start = study_input(given, study.data, study.source_args, study.truth, study.no_truth,
                        warn=reporter.warn)  # fmt: skip
    return start, study.association.for_study(study.data)


def run_study(request: StudyRequest, plan: StudyPlan, reporter: Reporter) -> StudyOutcome:
    """Run every spec on the log, save the recording and the report (see the module).

    :raises Interrupted: SIGINT or SIGTERM, saying how many runs were done
    :raises InputError, UsageError, OutputError, FilterError: one line each
    """
    data, specs, what = request.data, plan.specs, plan.what
    # none of them may be written over: the log (a dataset's files), the truth, the filters
    modules = [filter_module(spec.filter.text) for spec in specs]
    check_outputs(("--save", request.save), ("--report", request.report),
                  inputs=[data, request.truth, *plan.inputs, *modules])  # fmt: skip
    kind = "sweep" if plan.root == "variants" else "compare"
    target = request.save or default_output(f"{data.stem}-{kind}.rrd")
    finished: list[None] = []
    try:
        with reporter.counting(f"{len(specs)} {what}s", len(specs)) as advance, in_family():

            def done() -> None:
                finished.append(None)
                advance()

            result = study(request, plan, target, done=done, warn=reporter.warn)
    except signals.Interrupted as stop:
        stop.kept = stopped_study(len(finished), len(specs), f"{what}s",
                                  [target, request.report])  # fmt: skip
        raise
    except FilterLineError as error:
        where = f"{data}:{error.line}: {error}" if error.line else f"{data}: {error}"
        raise FilterError(where) from error
    if request.report is not None:
        write_json(request.report, _report(data, result, what, plan.report_extra))
    return _outcome(result, plan, saved_line(target))


def _outcome(result: StudyResult, plan: StudyPlan, saved: str) -> StudyOutcome:
    """The study's table, the runs that used their own R, what stopped or failed."""
    what = plan.what
    own = sorted({run.spec.label for run in result.runs if run.own_noise})
    failed = [failure.spec.label for failure in result.failures]
    table = study_table(result.summaries, result.truth is not None, what, set(own), failed)
    return StudyOutcome(
        result=result, notes=plan.notes, table=table, own_noise=own,
        stopped=[f"{run.spec.label}: {run.failure} (its events before that are recorded)"
                 for run in result.runs if run.failure],
        failed=[f"{failure.spec.label}: {failure.message}" for failure in result.failures],
        saved=saved,
    )  # fmt: skip


def _report(
    data: Path, result: StudyResult, what: str, report_extra: dict[str, object]
) -> dict[str, object]:
    """The study's JSON report: a row a run, then a row a filter that failed to start."""
    return {
        "ekfviz_version": __version__,
        "input": {"name": data.name, "sha256": result.input_sha256},
        **report_extra,
        f"{what}s": [
            {
                **asdict(summary),
                **run.evaluation.to_json(),
                "failure": run.failure,
                "own_noise": run.own_noise,
            }
            for summary, run in zip(result.summaries, result.runs, strict=True)
        ]
        + [
            {"label": f.spec.label, "filter": f.spec.filter.text, "failure": f.message}
            for f in result.failures
        ],
    }


def study(
    request: StudyRequest,
    plan: StudyPlan,
    target: Path,
    *,
    done: Callable[[], None] | None = None,
    warn: WarningCallback | None = None,
) -> StudyResult:
    """Replay the log with every spec, summarise against the first, save one recording.

    With ``keep_going`` (compare) a filter that fails is a row saying why, its events
    before the failure recorded, and the other filters go on.

    The log is read whole once before any work, so that bad input stops the study early;
    every filter is loaded once here for the same reason.

    :raises InputError, FilterLineError, FilterSpecError, SinkError: one line each
    """
    from ekfviz import viz
    from ekfviz.studies.runs import Run, RunFailure, run_specs, summarise
    from ekfviz.viz.study import record_study

    data, truth_path, specs = request.data, request.truth, plan.specs
    truth, truth_files = study_truth(truth_path, plan.own_truth)
    source = open_source(data, request.source_args)
    for _ in source_events(source, truth, truth_path, warn=warn):
        pass  # read whole once, its warnings said (the runs' readers say none)
    if not plan.keep_going:
        for spec in specs:
            release(spec.filter.load())
    results = run_specs(
        data,
        specs,
        truth,
        done=None if done is None else lambda _: done(),
        executor=plan.executor,
        keep_going=plan.keep_going,
        source_args=request.source_args,
    )
    runs = [r for r in results if isinstance(r, Run)]
    failures = [r for r in results if isinstance(r, RunFailure)]
    if not runs:
        raise FilterSpecError("; ".join(f"{f.spec.label}: {f.message}" for f in failures))
    summaries = [summarise(run, runs[0]) for run in runs]
    kind = "sweep" if plan.root == "variants" else "compare"
    info = viz.run_info(
        name=f"{data.stem}-{kind}",
        command=request.command,
        parameters=plan.parameters,
        input_path=data,
        truth=truth,
        truth_path=truth_files[0] if truth_files else None,
        input_files=source.files,  # a dataset directory's
        truth_files=truth_files,
        kind=kind,
    )
    markdown = study_markdown(summaries, plan.what) + failed_markdown(runs, failures)
    with viz.open_recording(info, viz.Sinks(save=target)) as recording:
        record_study(recording, runs, truth, markdown, root=plan.root)
    return StudyResult(runs, summaries, truth, info.input_sha256, failures)


def study_truth(
    truth_path: Path | None, own_truth: OwnTruth | None
) -> tuple[GroundTruth | None, list[Path]]:
    """The truth of a study or a check, and the files it was read from: a ``--truth``
    file, else the source's own."""
    if truth_path is not None:
        return read_truth(truth_path), [truth_path]
    if own_truth is not None:
        return own_truth.truth, list(own_truth.files)
    return None, []


def failed_markdown(runs: list[Run], failures: list[RunFailure]) -> str:
    """What failed in a study, for its recording's summary."""
    lines = [f"- **{r.spec.label}** stopped: {r.failure}" for r in runs if r.failure]
    lines += [f"- **{f.spec.label}** failed: {f.message}" for f in failures]
    return "\n## Failed\n\n" + "\n".join(lines) + "\n" if lines else ""
