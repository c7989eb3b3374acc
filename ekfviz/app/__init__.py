"""Orchestration: a log from its source through filters to its consumers.

The commands of :mod:`ekfviz.cli` parse options and print; what happens between reading
a log and writing a recording lives here, so that a newcomer reads the steps of a study
in one place: read and check the input, run every pipeline (in parallel), summarise,
record. Rerun is imported only when a recording is made. :mod:`.grade` checks a class's
submissions, each apart, with :func:`check`.
"""

from __future__ import annotations

import json
import shlex
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from ekfviz import signals
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent, EventKind, EventRecord, NeedsIds, with_ids
from ekfviz.core.tables import utf8
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import Consistency
from ekfviz.evaluation.errors import Evaluation, evaluate
from ekfviz.filters.plugged import FilterFactory
from ekfviz.filters.spec import FilterSpec, FilterSpecError, release
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.io.truth import checked_against, read_truth
from ekfviz.runner.replay import FilterLineError
from ekfviz.runner.run import Consumer, run
from ekfviz.sources import OwnTruth, Source, SourceArgs, open_source

if TYPE_CHECKING:  # the studies' modules: imported by the functions that run them
    from ekfviz.association.associator import Associator
    from ekfviz.check.coverage import Item as CoverageItem
    from ekfviz.check.lockstep import CheckResult
    from ekfviz.filters.ekf import EkfSlam
    from ekfviz.sandbox.host import WorkerProcess
    from ekfviz.studies.executors import Executor
    from ekfviz.studies.runs import Run, RunFailure, RunSpec, Summary
    from ekfviz.viz.run import RunInfo, RunLogger


def log_events(
    data: Path,
    truth: GroundTruth | None,
    truth_path: Path | None,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
    source_args: SourceArgs | None = None,
) -> Iterator[AnyEvent]:
    """The log's events (its source's options ``source_args``, else their defaults),
    checked against the truth's landmarks when there is one."""
    return source_events(open_source(data, source_args), truth, truth_path, progress, warn)


def source_events(
    source: Source,
    truth: GroundTruth | None,
    truth_path: Path | None,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[AnyEvent]:
    """:func:`log_events` of a source already open (its files are asked of it too)."""
    events = source.events(progress, warn)
    if truth is not None and truth_path is not None:
        every_id = source.names_every_landmark
        events = checked_against(events, truth, truth_path, every_id=every_id)
    return events


class ScanHooks(Protocol):
    """What a replay adds to the filter (see :mod:`ekfviz.cli.scans`): the built-in
    filter with the models its source implies, the associator of id-less scans, a look
    at every record (the source's reference) and the truth under the association's
    pairing."""

    @property
    def slam(self) -> EkfSlam | None: ...

    @property
    def associator(self) -> Associator | None: ...

    @property
    def reads_predicts(self) -> bool: ...

    def add(self, record: EventRecord) -> None: ...

    def truth_of(self, last: EventRecord) -> GroundTruth | None: ...

    def finish(self, logger: RunLogger) -> object:
        """After the last record, before the recording's layout is made: what the run
        adds to the recording (the source's reference, which the map then frames)."""
        ...


class RunStopped(Exception):
    """A replay cut short; ``kept`` says whether its recording was kept."""

    def __init__(self, reason: str, cause: BaseException, kept: bool) -> None:
        super().__init__(reason)
        self.reason = reason
        self.kept = kept
        if isinstance(cause, KeyboardInterrupt):
            self.exit_code = 130  # 128 + SIGINT, as a shell reports it
        elif isinstance(cause, signals.Terminated):
            self.exit_code = 143  # 128 + SIGTERM
        else:
            self.exit_code = 2


def stop_reason(
    cause: BaseException,
    data: Path,
    last: EventRecord | None,
    file_of: Callable[[bool], Path | None] | None = None,
) -> str:
    """One line saying why and where a replay stopped.

    :param file_of: the file of a motion's line number or an update's, where the input
        is a dataset directory of several (:meth:`~ekfviz.sources.Source.file_of`)
    """

    def where(motion: bool | None) -> Path:
        found = None if file_of is None or motion is None else file_of(motion)
        return data if found is None else found

    after = "at the start"
    if last is not None and last.line:
        path = where(last.kind is EventKind.PREDICT)
        after = f"after input line {last.line}" if path == data else (
            f"after line {last.line} of {path}")  # fmt: skip
    if isinstance(cause, KeyboardInterrupt):
        return f"{data}: interrupted (SIGINT) {after}"
    if isinstance(cause, signals.Terminated):
        return f"{data}: terminated (SIGTERM) {after}"
    if isinstance(cause, FilterLineError):
        return f"{where(cause.motion)}:{cause.line}: {cause}" if cause.line else f"{data}: {cause}"
    return str(cause)


def replay_log(
    events: Iterable[AnyEvent],
    params: FilterParams,
    *,
    make_filter: FilterFactory | None,
    name: str,
    data: Path,
    truth: GroundTruth | None,
    logger: RunLogger,
    on_record: Callable[[EventRecord], None] | None = None,
    scans: ScanHooks | None = None,
    file_of: Callable[[bool], Path | None] | None = None,
) -> Evaluation:
    """One replay: the events through the filter into the logger, judged at the end.

    Every record goes to the logger (Rerun), the consistency count and ``on_record``;
    the plain predicts and updates (by ids, no warning, no check) go to the logger as
    columns, their NIS and NEES to the consistency count, and not to ``on_record`` (see
    :class:`~ekfviz.core.records.EventRows`).
    Bad input, a filter that cannot go on, Ctrl-C or SIGTERM stop the replay with the
    recording of everything before it kept and its last log line saying why.

    :param scans: the built-in filter with its source's models and the associator of
        id-less scans; the evaluation then sees the truth under the association's pairing
    :raises RunStopped: the replay was cut short (why, where, and whether it was kept)
    """
    consistency = Consistency(truth)
    last = _Last()
    consumers: list[Consumer] = [logger.log, consistency.add]
    if on_record is not None:
        consumers.append(on_record)
    consumers.append(last.add)
    if scans is not None:
        consumers.append(scans.add)
    slam = None if scans is None else scans.slam
    associator = None if scans is None else scans.associator
    # the plain predicts go to the recorder as columns (no other consumer reads a
    # predict's record) unless the hooks read them (a source's reference)
    rows = logger.event_rows() if scans is None or not scans.reads_predicts else None
    if rows is not None:
        # its plain updates too: only the recorder and the consistency count read them.
        # An update that the association decided (a scan) stays a record, for the
        # association's tally and view; an update by ids beside an associator (an
        # extended log that could have scans but has none here) is as plain as any
        rows.takes_updates = True
        rows.watch = consistency.add_rows
    try:
        run(events, params, consumers, make_filter=make_filter, name=name, slam=slam,
            associator=associator, event_rows=rows)  # fmt: skip
    except (InputError, FilterLineError, KeyboardInterrupt, signals.Terminated) as cause:
        if rows is not None:  # where it stopped: maybe an event written as a row
            last.record = rows.latest(last.record)
            rows.settle()
        if scans is not None and last.record is not None:
            truth = scans.truth_of(last.record)
        final = None if last.record is None else evaluate(last.record, truth, consistency)
        reason = stop_reason(cause, data, last.record, file_of)
        kept = logger.stop(reason, final)
        raise RunStopped(reason, cause, kept) from cause
    assert last.record is not None  # replay always yields the initialisation
    # a signal while the recording is finished is acted on once it is (and so kept)
    with signals.held():
        if scans is not None:
            truth = scans.truth_of(last.record)
            scans.finish(logger)  # before the layout: the map frames what it draws
        if rows is not None:  # the NIS and NEES of the rows not sent yet
            rows.settle()
        evaluation = evaluate(last.record, truth, consistency)
        logger.finish(evaluation)
    return evaluation


class _Last:
    """The last record so far; a signal that came during start-up stops the run at the
    initialisation, with its recording."""

    def __init__(self) -> None:
        self.record: EventRecord | None = None

    def add(self, record: EventRecord) -> None:
        self.record = record
        if record.event == 0:
            signals.raise_pending()


@dataclass(frozen=True, slots=True)
class StudyResult:
    """A study run and recorded: its runs in order, their summaries, the input's digest."""

    runs: list[Run]
    summaries: list[Summary]
    truth: GroundTruth | None
    input_sha256: str
    # the runs whose filter failed before any event (compare), with why
    failures: list[RunFailure] = field(default_factory=list)


def study(
    data: Path,
    truth_path: Path | None,
    specs: list[RunSpec],
    *,
    target: Path,
    workers: int | None,
    root: str,
    parameters: dict[str, object],
    markdown: Callable[[list[Summary]], str],
    done: Callable[[], None] | None = None,
    executor: Executor | None = None,
    keep_going: bool = False,
    source_args: SourceArgs | None = None,
    warn: WarningCallback | None = None,
    own_truth: OwnTruth | None = None,
) -> StudyResult:
    """Replay ``data`` with every spec, summarise against the first, save one recording.

    With ``keep_going`` (compare) a filter that fails is a row saying why, its events
    before the failure recorded, and the other filters go on.

    The log is read whole once before any work, so that bad input stops the study early;
    every filter is loaded once here for the same reason.

    :param root: ``variants`` (a sweep) or ``filters`` (a comparison)
    :param markdown: the summary table as markdown, for the recording
    :param own_truth: the source's own truth (a dataset's), where ``truth_path`` is None
    :raises InputError, FilterLineError, FilterSpecError, SinkError: one line each
    """
    from ekfviz import viz
    from ekfviz.studies.runs import Run, RunFailure, run_specs, summarise
    from ekfviz.viz.study import record_study

    truth, truth_files = study_truth(truth_path, own_truth)
    source = open_source(data, source_args)
    for _ in source_events(source, truth, truth_path, warn=warn):
        pass  # read whole once, its warnings said (the runs' readers say none)
    if not keep_going:
        for spec in specs:
            release(spec.filter.load())
    results = run_specs(
        data,
        specs,
        truth,
        workers,
        done=None if done is None else lambda _: done(),
        executor=executor,
        keep_going=keep_going,
        source_args=source_args,
    )
    runs = [r for r in results if isinstance(r, Run)]
    failures = [r for r in results if isinstance(r, RunFailure)]
    if not runs:
        raise FilterSpecError("; ".join(f"{f.spec.label}: {f.message}" for f in failures))
    summaries = [summarise(run, runs[0]) for run in runs]
    info = viz.run_info(
        name=f"{data.stem}-{'sweep' if root == 'variants' else 'compare'}",
        command=shlex.join(["ekfviz", *sys.argv[1:]]),
        parameters=parameters,
        input_path=data,
        truth=truth,
        truth_path=truth_files[0] if truth_files else None,
        input_files=source.files,  # a dataset directory's
        truth_files=truth_files,
        kind="sweep" if root == "variants" else "compare",
    )
    with viz.open_recording(info, viz.Sinks(save=target)) as recording:
        record_study(recording, runs, truth, markdown(summaries) + failed_markdown(runs, failures),
                     root=root)  # fmt: skip
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


def check(
    data: Path,
    truth_path: Path | None,
    spec: FilterSpec,
    params: FilterParams,
    *,
    tolerance: float,
    save: Path | None,
    every: bool = False,
    source_args: SourceArgs | None = None,
    warn: WarningCallback | None = None,
    own_truth: OwnTruth | None = None,
    process: WorkerProcess | None = None,
) -> tuple[CheckResult, list[CoverageItem]]:
    """Check a protocol filter against the reference in lockstep over ``data``; with
    ``save``, one recording of both side by side, the divergences marked. Also what the
    log exercised (:func:`ekfviz.check.coverage.coverage`).

    :param every: look for the cause of every divergent event (``check --all``)
    :param own_truth: the source's own truth (a dataset's), where ``truth_path`` is None
    :param process: a worker already started for a user's filter (see
        :func:`ekfviz.filters.spec.load_filter`)
    :raises InputError, FilterLineError, FilterSpecError, SinkError: one line each
    """
    from ekfviz.check.coverage import coverage
    from ekfviz.check.lockstep import lockstep

    make_filter = spec.load(process)
    truth, truth_files = study_truth(truth_path, own_truth)
    source = open_source(data, source_args)
    try:
        events = list(with_ids(source_events(source, truth, truth_path, warn=warn)))
        result = lockstep(
            events, params, make_filter, name=spec.text, tolerance=tolerance, every=every
        )
    except NeedsIds as error:
        raise InputError(
            data, error.line, f"found {error.what}: check compares updates by landmark id"
            " (replay a log of scans with --filter and --association instead)",
        ) from None  # fmt: skip
    finally:
        release(make_filter)
    exercised = coverage(events, result.reference, params)
    if save is not None and result.records:
        _record_check(data, truth, truth_files, spec, params, result, save, source.files)
    return result, exercised


def _record_check(
    data: Path,
    truth: GroundTruth | None,
    truth_files: list[Path],
    spec: FilterSpec,
    params: FilterParams,
    result: CheckResult,
    save: Path,
    input_files: Sequence[Path],
) -> None:
    """The recording of a check (``input_files``: what a dataset directory is read from;
    ``truth_files``: what its truth is)."""
    from ekfviz import viz
    from ekfviz.viz.check import record_check

    shown = check_recording(data, truth, truth_files, spec, params, result, input_files)
    with viz.open_recording(shown.info, viz.Sinks(save=save)) as recording:
        record_check(recording, shown.result, shown.runs, truth, shown.summary)


@dataclass(frozen=True, slots=True)
class CheckRecording:
    """What the recording of a check shows: the result as recorded (to its first
    divergence unless every event was checked), both runs, the run information and the
    verdict as markdown."""

    result: CheckResult
    runs: list[Run]
    info: RunInfo
    summary: str


def check_recording(
    data: Path,
    truth: GroundTruth | None,
    truth_files: list[Path],
    spec: FilterSpec,
    params: FilterParams,
    result: CheckResult,
    input_files: Sequence[Path],
) -> CheckRecording:
    """What the recording of a check of ``spec`` on ``data`` shows (see
    :func:`_record_check`); the input is read for its digest.

    :raises InputError: the input or truth file cannot be read
    """
    from dataclasses import replace

    from ekfviz import viz

    first = result.first_divergence
    if first is not None and not result.every:
        # without --all the recording ends at the first divergence, where it then opens
        kept = sum(1 for record in result.records if record.event <= first.event)
        result = replace(
            result,
            records=result.records[:kept],
            reference=result.reference[:kept],
            differences=result.differences[:kept],
            divergences=(first,),
        )
    from ekfviz.studies.runs import Run, RunSpec

    runs = []
    for label, key, records in (
        ("reference (ekf)", "reference", result.reference),
        (spec.label, spec.key if spec.key != "reference" else "checked", result.records),
    ):
        if not records:
            continue
        consistency = Consistency(truth)
        for record in records:
            consistency.add(record)
        evaluation = evaluate(records[-1], truth, consistency)
        runs.append(Run(RunSpec(label, key, params), records, evaluation, 0.0))
    info = viz.run_info(
        name=f"{data.stem}-check",
        kind="check",
        command=shlex.join(["ekfviz", *sys.argv[1:]]),
        parameters={"filter": spec.text, "tolerance": result.tolerance, **params.as_dict()},
        input_path=data,
        truth=truth,
        truth_path=truth_files[0] if truth_files else None,
        input_files=input_files,
        truth_files=truth_files,
    )
    verdict = json.dumps(result.to_json(), indent=2)
    summary = f"# Check of {utf8(spec.text)} against the reference\n\n```json\n{verdict}\n```\n"
    return CheckRecording(result, runs, info, summary)
