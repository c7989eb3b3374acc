"""``check``: a filter in lockstep with the reference, every divergence and its cause.

:func:`check_log` checks a filter on one log (and records both side by side);
:func:`check` is the use case: the log asked for, or the bundled battery (the classic
sample and the edge log), each with its source's defaults and truth, the report
written. ``grade`` checks every submission of a class with :func:`check_log`.
"""

from __future__ import annotations

import json
import shlex
import sys
import tempfile
from collections.abc import Sequence
from contextlib import suppress
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ekfviz import __version__
from ekfviz.app.errors import in_family
from ekfviz.app.inputs import StudyInput, source_events, study_input
from ekfviz.app.outputs import filter_module, saved_line
from ekfviz.app.reporting import Reporter
from ekfviz.app.settings import FilterSettings, Triple, WorkerOptions, filter_params
from ekfviz.app.study import study_truth
from ekfviz.check.lockstep import DEFAULT_TOLERANCE
from ekfviz.core.errors import FilterError, InputError, UsageError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import LogEvent, NeedsIds, with_ids
from ekfviz.core.tables import utf8
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import Consistency
from ekfviz.evaluation.errors import evaluate
from ekfviz.filters.spec import FilterSpec, release
from ekfviz.io.files import check_outputs, refuse_output_over_input, write_json
from ekfviz.io.text import WarningCallback
from ekfviz.runner.replay import FilterLineError
from ekfviz.sources import OwnTruth, SourceArgs, open_source

if TYPE_CHECKING:
    from ekfviz.check.coverage import Item as CoverageItem
    from ekfviz.check.lockstep import CheckResult
    from ekfviz.core.batch import EventBatch
    from ekfviz.sandbox.remote import StartedWorker
    from ekfviz.studies.runs import Run
    from ekfviz.viz import RunInfo, Sinks

__all__ = [
    "DEFAULT_TOLERANCE",
    "CheckRequest",
    "CheckResult",
    "CoverageItem",
    "check",
    "check_log",
]


@dataclass(frozen=True, slots=True)
class CheckRequest:
    """A check as asked: the filter, the log (None: the battery) and its truth, the
    filter's settings, the tolerance, the report and the recording (with the battery,
    one per log: ``NAME-classic.rrd``, ``NAME-edge.rrd``).

    :param every: go on after a divergence and find the cause of every divergent event
    :param given: the names of the options the user gave (the others yield to what the
        input states of itself)
    :param command: the command line, as the recording tells it
    """

    filter_text: str
    data: Path | None = None
    truth: Path | None = None
    source_args: SourceArgs = field(default_factory=SourceArgs)
    no_truth: bool = False
    every: bool = False
    tolerance: float = DEFAULT_TOLERANCE
    report: Path | None = None
    save: Path | None = None
    worker: WorkerOptions | None = None
    init_pose: Triple | None = None
    filter: FilterSettings = field(default_factory=FilterSettings)
    given: frozenset[str] = frozenset()
    command: str = "ekfviz check"

    def was_given(self, name: str) -> bool:
        return name in self.given


@dataclass(frozen=True, slots=True)
class CheckedLog:
    """One log's check: its name as shown (the path given, or the battery log's stem),
    the result, what the log did not exercise, the notes on what was chosen (the start
    pose), and the line saying where its recording is."""

    log: Path
    name: str
    result: CheckResult
    coverage: list[CoverageItem]
    notes: tuple[str, ...] = ()
    saved: str | None = None

    @property
    def missing(self) -> list[CoverageItem]:
        """What the log did not exercise."""
        return [item for item in self.coverage if not item.exercised]


@dataclass(frozen=True, slots=True)
class CheckOutcome:
    """Every log's check, in order, and the report (written where asked)."""

    logs: list[CheckedLog]
    battery: bool
    report: dict[str, Any]

    @property
    def diverged(self) -> bool:
        return any(log.result.first_divergence is not None for log in self.logs)

    @property
    def failed(self) -> bool:
        """Whether the filter failed on a log (an exception, a time or memory limit)."""
        return any(log.result.error is not None for log in self.logs)


def check(request: CheckRequest, reporter: Reporter) -> CheckOutcome:
    """Check the filter on the log (or the battery) and write the report.

    :raises InputError, UsageError, OutputError, FilterError: one line each
    """
    if not request.filter_text:
        raise UsageError("give the filter to check: --filter PATH.py (or PATH.py:ClassName)")
    data, save = request.data, request.save
    check_outputs(
        ("--report", request.report), ("--save", save),
        inputs=[data, request.truth, filter_module(request.filter_text)],
    )  # fmt: skip
    spec = FilterSpec.parse(request.filter_text, worker=request.worker)
    checked: list[CheckedLog] = []
    results: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as folder:
        logs = battery_logs(request, Path(folder))
        for log, log_truth, start in logs:
            one, params = _check_one(request, spec, log, log_truth, start, reporter)
            checked.append(one)
            results.append(log_entry(one.name, one.result, one.coverage))
    document = report_document(spec, params, results, battery=data is None)
    if request.report is not None:
        write_json(request.report, document)
    return CheckOutcome(checked, data is None, document)


def log_entry(name: str, result: CheckResult, exercised: list[CoverageItem]) -> dict[str, Any]:
    """The report's entry of one log: its name, the verdict and what the log exercised."""
    return {"log": name, **result.to_json(),
            "coverage": [item.to_json() for item in exercised]}  # fmt: skip


def report_document(
    spec: FilterSpec, params: FilterParams, entries: list[dict[str, Any]], *, battery: bool
) -> dict[str, Any]:
    """The report of a check: the filter and its parameters, the log's entry (or the
    battery's: each log's, and all of them together)."""
    document: dict[str, Any] = {"ekfviz_version": __version__, "filter": spec.text,
                                "parameters": params.as_dict()}  # fmt: skip
    document.update(_battery_report(entries) if battery else entries[0])
    return document


def battery_logs(
    request: CheckRequest, folder: Path
) -> Sequence[tuple[Path, Path | None, Triple | None]]:
    """The logs to check, each with its truth and start pose: the one asked for, else
    the battery written into ``folder``.

    :raises UsageError: ``--truth`` without a log
    """
    if request.data is not None:
        return [(request.data, request.truth, request.init_pose)]
    from ekfviz.samples import write_battery

    battery = write_battery(folder)
    if request.truth is not None:
        raise UsageError("--truth needs a log (DATA); the battery brings its own truth")
    return battery


def _check_one(
    request: CheckRequest,
    spec: FilterSpec,
    log: Path,
    truth: Path | None,
    start: Triple | None,
    reporter: Reporter,
) -> tuple[CheckedLog, FilterParams]:
    """Check the filter on one log, with that log's defaults; its parameters too."""
    battery = request.data is None
    opened = prepared_input(request, log, truth, start, reporter)
    save = request.save
    target = save if not battery or save is None else per_log_path(save, log)
    try:
        with in_family():
            result, exercised = check_log(
                log, truth, spec, opened.params, tolerance=request.tolerance, save=target,
                every=request.every, source_args=request.source_args, warn=reporter.warn,
                own_truth=opened.own_truth, command=request.command, skip_unreadable=battery,
            )  # fmt: skip
    except FilterLineError as error:
        where = f"{log}:{error.line}: {error}" if error.line else f"{log}: {error}"
        raise FilterError(where) from error
    return CheckedLog(
        log=log, name=log.stem if battery else str(log), result=result,
        coverage=exercised, notes=opened.notes,
        saved=None if target is None or result.skipped else saved_line(target),
    ), opened.params  # fmt: skip


def prepared_input(
    request: CheckRequest,
    log: Path,
    truth: Path | None,
    start: Triple | None,
    reporter: Reporter,
) -> StudyInput:
    """The filter's parameters for ``log`` (the noise its header states, the start pose)
    with its source's own truth; the outputs refused where they are one of its files.

    :param start: the start pose a battery log brings, or ``--init-pose``
    :raises InputError, OutputError: one line each
    """
    params = filter_params(request.filter, log=log, given=request.was_given, note=reporter.note)
    if start is not None:
        params = replace(params, init_pose=start)
    # a dataset's own truth, and the start at its true pose (per-step noise kept: a
    # course filter's predict takes no time span)
    opened = study_input(params, log, request.source_args, truth, request.no_truth,
                         motion_noise=False, init_pose=start, pose_option=True,
                         warn=reporter.warn)  # fmt: skip
    refuse_output_over_input(
        ("--report", request.report), ("--save", request.save), inputs=opened.files
    )
    return opened


def per_log_path(save: Path, log: Path) -> Path:
    """Where the recording of the battery's ``log`` goes, for ``--save NAME.rrd``:
    ``NAME-classic.rrd`` beside it."""
    return save.with_name(f"{save.stem}-{log.stem}{save.suffix or '.rrd'}")


def _battery_report(results: list[dict[str, Any]]) -> dict[str, Any]:
    causes: dict[str, None] = {}
    divergences = []
    for entry in results:
        for cause in entry["causes"]:
            causes.setdefault(cause, None)
        divergences += [{"log": entry["log"], **group} for group in entry["divergences"]]
    coverage: dict[str, bool] = {}
    for entry in results:
        for item in entry["coverage"]:
            coverage[item["id"]] = coverage.get(item["id"], False) or bool(item["exercised"])
    return {
        "match": all(entry["match"] for entry in results),
        "logs": results,
        "divergences": divergences,
        "causes": list(causes),
        "coverage": [{"id": k, "exercised": v} for k, v in coverage.items()],
    }


def check_log(
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
    command: str | None = None,
    sinks: Sinks | None = None,
    skip_unreadable: bool = False,
    started: StartedWorker | None = None,
) -> tuple[CheckResult, list[CoverageItem]]:
    """Check a protocol filter against the reference in lockstep over ``data``; with
    ``save`` (or ``sinks``), one recording of both side by side, the divergences marked.
    Also what the log exercised (:func:`ekfviz.check.coverage.coverage`).

    :param every: look for the cause of every divergent event (``check --all``)
    :param own_truth: the source's own truth (a dataset's), where ``truth_path`` is None
    :param command: the command line, as the recording tells it (None: this process's)
    :param sinks: where the recording goes instead of ``save`` (a viewer's URL)
    :param skip_unreadable: a course module and a log it cannot read (landmarks first seen
        after the first line): a result that says so, the module not run (the battery)
    :param started: a worker already started for a user's filter, its module not yet
        imported (``ekfviz watch``'s)
    :raises InputError, FilterLineError, FilterSpecError, SinkError: one line each
    """
    from ekfviz.check.coverage import coverage
    from ekfviz.check.lockstep import course_cannot_read, lockstep, skipped

    make_filter = spec.load(started)
    truth, truth_files = study_truth(truth_path, own_truth)
    source = open_source(data, source_args)
    try:
        events = list(with_ids(source_events(source, truth, truth_path, warn=warn)))
        why = course_cannot_read(events) if getattr(make_filter, "style", "") == "functions" else ""
        if skip_unreadable and why:
            return skipped(why, tolerance), []
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
    exercised = coverage(events, result.reference, params, operations=True)
    if (save is not None or sinks is not None) and result.records:
        from ekfviz import viz

        said = command if command is not None else shlex.join(["ekfviz", *sys.argv[1:]])
        recorded = Recorded(data, truth, truth_files, source.files, said, events)
        _record_check(recorded, spec, params, result, sinks or viz.Sinks(save=save))
    return result, exercised


@dataclass(frozen=True, slots=True)
class Recorded:
    """What a check's recording says of its input: the log (``input_files``: what a
    dataset directory is read from), its truth (``truth_files``: what it was read from),
    the command line, and the log's events (the reference's own run is replayed from
    them where the check went on past a divergence)."""

    data: Path
    truth: GroundTruth | None
    truth_files: list[Path]
    input_files: Sequence[Path]
    command: str
    events: Sequence[LogEvent] = ()


def reference_alone(events: Sequence[LogEvent], params: FilterParams) -> EventBatch:
    """The reference's own run over ``events``: the built-in filter alone, where the
    lockstep starts it from the checked filter's state before every event (after a
    divergence that is the checked filter's state stepped once, not the reference's).

    :return: its records, up to the line it cannot go on at, if any
    """
    from ekfviz.core.batch import EventBatch
    from ekfviz.runner.replay import replay

    batches: list[EventBatch] = []
    with suppress(FilterLineError):  # its records up to that line are still its own
        batches.extend(replay(events, params))
    return EventBatch.joined(batches)


def _record_check(
    recorded: Recorded, spec: FilterSpec, params: FilterParams, result: CheckResult, sinks: Sinks
) -> None:
    """The recording of a check: the filter and the reference side by side."""
    from ekfviz import viz
    from ekfviz.viz.check import record_check

    shown = check_recording(recorded, spec, params, result)
    with viz.open_recording(shown.info, sinks) as recording:
        record_check(recording, shown.result, shown.runs, recorded.truth, shown.summary)


@dataclass(frozen=True, slots=True)
class CheckRecording:
    """What the recording of a check shows: the result as recorded (to its first
    divergence unless every event was checked), both runs, the run's description and the
    verdict as markdown."""

    result: CheckResult
    runs: list[Run]
    info: RunInfo
    summary: str


def check_recording(
    recorded: Recorded, spec: FilterSpec, params: FilterParams, result: CheckResult
) -> CheckRecording:
    """What the recording of a check of ``spec`` shows (see :func:`_record_check`)."""
    from ekfviz import viz
    from ekfviz.studies.runs import Run, RunSpec

    first = result.first_divergence
    if first is not None and not result.every:
        # without --all the recording ends at the first divergence, where it then opens
        kept = sum(1 for event in result.records.events.tolist() if event <= first.event)
        result = replace(
            result,
            records=result.records[:kept],
            reference=result.reference[:kept],
            differences=result.differences[:kept],
            divergences=(first,),
        )
    truth = recorded.truth
    reference = result.reference
    if first is not None and result.every and recorded.events:
        reference = reference_alone(recorded.events, params)
    runs = []
    for label, key, records in (
        ("reference (ekf)", "reference", reference),
        (spec.label, spec.key if spec.key != "reference" else "checked", result.records),
    ):
        if not len(records):
            continue
        consistency = Consistency(truth)
        consistency.add(records)
        evaluation = evaluate(records.last, truth, consistency)
        runs.append(Run(RunSpec(label, key, params), records, evaluation, 0.0))
    info = viz.run_info(
        name=f"{recorded.data.stem}-check",
        kind="check",
        command=recorded.command,
        parameters={"filter": spec.text, "tolerance": result.tolerance, **params.as_dict()},
        input_path=recorded.data,
        truth=truth,
        truth_path=recorded.truth_files[0] if recorded.truth_files else None,
        input_files=recorded.input_files,
        truth_files=recorded.truth_files,
    )
    verdict = json.dumps(result.to_json(), indent=2)
    summary = f"# Check of {utf8(spec.text)} against the reference\n\n```json\n{verdict}\n```\n"
    return CheckRecording(result, runs, info, summary)
