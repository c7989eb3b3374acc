"""``replay``: a log through a filter into a recording, judged at the end.

:func:`replay` opens the input, sets the filter up for it (the models its source
implies, the associator of id-less scans), records the run to the sinks asked for,
writes the report and returns what the front end shows. :func:`replay_into` is its
middle part, for a front end that holds its own recording open across replays.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ekfviz import __version__, signals
from ekfviz.app.errors import RunStopped, in_family
from ekfviz.app.inputs import OpenedLog, first_time, open_log, resolve
from ekfviz.app.outputs import RECORDINGS_DIR, filter_module
from ekfviz.app.reporting import Reporter
from ekfviz.app.scans import ReplaySetup, replay_setup
from ekfviz.app.settings import (
    AssociationSettings,
    FilterSettings,
    Given,
    MotionNoiseChoice,
    Triple,
    filter_params,
)
from ekfviz.core.batch import EventBatch
from ekfviz.core.errors import OutputError, UsageError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent
from ekfviz.core.tables import Cell, Styled, TextTable
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.errors import Evaluation
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.spec import BUILTIN, load_filter, release
from ekfviz.io.files import check_outputs, refuse_output_over_input, write_json
from ekfviz.sandbox.options import WorkerOptions
from ekfviz.sources import SourceArgs

if TYPE_CHECKING:
    from ekfviz.filters.plugged import FilterFactory
    from ekfviz.viz import ServedViewer, Sinks
    from ekfviz.viz.run import RunLogger

PROGRESS_MIN_BYTES = 1 << 20  # files under 1 MiB replay in well under a second
FILTER_WARNINGS_SAID = 10  # the filter's warnings said one by one; the recording has all


@dataclass(frozen=True, slots=True)
class RecordingOutput:
    """Where the recording goes (none: a viewer where a display exists, else a file in
    ``recordings/``) and how much of it is logged.

    :param bind: the address ``serve`` listens on (None: this machine only)
    :param detail: every landmark's ellipse at every update, even in a large map
    :param history: the map keeps every robot ellipse up to the time cursor
    """

    save: Path | None = None
    spawn: bool = False
    serve: bool = False
    bind: str | None = None
    connect: str | None = None
    detail: bool = False
    history: bool = False


@dataclass(frozen=True, slots=True)
class ReplayRequest:
    """A replay as asked: the log (``source_args``: its format's options) and its truth,
    the filter and its settings, the recording and the report.

    :param init_pose: the filter's start (None: the true pose at the first event where
        the log comes with a timed truth, else the origin)
    :param gate: reject an observation of a known landmark past this NIS (None: none)
    :param filter_spec: ``ekf``, a registered backend, ``PATH.py:Class``, ...
    :param worker: how a user's filter runs (None: the defaults)
    :param given: the names of the options the user gave (the others yield to what the
        input states of itself)
    :param command: the command line, as the recording tells it
    """

    data: Path
    truth: Path | None = None
    source_args: SourceArgs = field(default_factory=SourceArgs)
    no_truth: bool = False
    report: Path | None = None
    filter: FilterSettings = field(default_factory=FilterSettings)
    odometry_scale: tuple[float, float] = (1.0, 1.0)
    odometry_bias: float = 0.0
    motion_noise: MotionNoiseChoice = MotionNoiseChoice.AUTO
    init_pose: Triple | None = None
    gate: float | None = None
    filter_spec: str = BUILTIN
    worker: WorkerOptions | None = None
    output: RecordingOutput = field(default_factory=RecordingOutput)
    association: AssociationSettings = field(default_factory=AssociationSettings)
    given: frozenset[str] = frozenset()
    command: str = "ekfviz replay"
    recordings_dir: Path = RECORDINGS_DIR

    def was_given(self, name: str) -> bool:
        return name in self.given


@dataclass(frozen=True, slots=True)
class ReplayResult:
    """What a replay shows: the final table and lines, the summaries (the association,
    a source's reference), notes, the report, and where the recording went.

    :param served: the web viewer serving the recording, if asked for: the front end
        shows it until the user is done, then closes it
    :param sink_error: what went wrong with a sink once the run was recorded (a
        ``--connect`` viewer that never answered): said after the results
    """

    evaluation: Evaluation
    truth: GroundTruth | None  # as the evaluation saw it (the association's pairing)
    table: TextTable
    lines: list[Cell]
    summaries: list[str]
    report: dict[str, object]
    notes: list[Cell]
    saved_to: Path | None = None
    served: ServedViewer | None = None
    sink_error: str | None = None


@dataclass(slots=True)
class OpenedReplay:
    """A replay's input opened and its filter set up, ready to record."""

    request: ReplayRequest
    log: OpenedLog
    setup: ReplaySetup
    params: FilterParams
    events: Iterator[AnyEvent]
    make_filter: FilterFactory | None


def replay(request: ReplayRequest, reporter: Reporter) -> ReplayResult:
    """Replay as asked (see the module).

    :raises RunStopped: the replay was cut short (why, where, what was kept)
    :raises InputError, UsageError, OutputError, FilterError: one line each, before any
        recording is made
    """

    _check_outputs(request)
    with in_family():
        make_filter = load_filter(request.filter_spec, request.worker)
    logger: list[RunLogger] = []  # the logger once open, for what a stop kept
    sinks: Sinks | None = None
    try:
        try:
            opened = open_replay(request, reporter, make_filter)
            sinks, note = _sinks(request, opened)
            result = _record(opened, sinks, reporter, logger)
        finally:  # a user's filter ended (its output said) before the line saying why
            release(make_filter)
    except RunStopped as stopped:
        stopped.saved_to = logger[0].recording.saved_to if logger else None
        stopped.left = None if sinks is None else sinks.save
        raise
    except (KeyboardInterrupt, signals.Terminated) as cause:  # outside the replay itself
        raise _interrupted(request.data, cause, logger) from None
    notes = result.notes + ([Styled(note)] if note else [])
    return replace(result, notes=notes)


def _check_outputs(request: ReplayRequest) -> None:
    """Refuse bad output paths and options before any work."""
    from ekfviz import viz

    output = request.output
    check_outputs(
        ("--save", output.save), ("--report", request.report),
        inputs=[request.data, request.truth, filter_module(request.filter_spec)],
    )  # fmt: skip
    if output.bind is not None:
        if not output.serve:
            raise UsageError("--bind is the address of --serve: add --serve")
        viz.check_bind(output.bind)
    if min(request.odometry_scale) <= 0:
        raise UsageError("--odometry-scale values must be positive")


def open_replay(
    request: ReplayRequest, reporter: Reporter, make_filter: FilterFactory | None
) -> OpenedReplay:
    """The input opened, its defaults applied, the filter and associator set up for it."""
    given: Given = request.was_given
    params = filter_params(request.filter, log=request.data, given=given, note=reporter.note)
    params = replace(
        params, odometry_scale=request.odometry_scale, odometry_bias=request.odometry_bias
    )
    log = open_log(
        request.data, request.source_args, request.truth, request.no_truth, reporter.warn
    )
    # a dataset directory's files are known now: none of them may be written over
    refuse_output_over_input(
        ("--save", request.output.save), ("--report", request.report),
        inputs=[*log.source.files, *log.truth_files],
    )  # fmt: skip
    start, events = first_time(log.events())
    params, notes = resolve(
        params, log, start, request.init_pose, request.motion_noise, request.gate
    )
    for text in notes:
        reporter.note(text)
    builtin = make_filter is None or make_filter is EkfSlam
    setup = replay_setup(
        log, params, builtin=builtin, assoc=request.association.params(), given=given,
        warn=reporter.warn,
    )  # fmt: skip
    return OpenedReplay(request, log, setup, setup.params, events, make_filter)


def _sinks(request: ReplayRequest, opened: OpenedReplay) -> tuple[Sinks, str | None]:
    """The sinks asked for, or the default ones, and a note saying which when defaulted."""
    from ekfviz import viz

    output = request.output
    asked = viz.Sinks(
        save=output.save, spawn=output.spawn, serve=output.serve, connect=output.connect,
        bind=output.bind or viz.LOOPBACK,
    )  # fmt: skip
    return viz.resolve_default_sinks(
        asked, request.data, request.recordings_dir, name=opened.log.source.name
    )


def _record(
    opened: OpenedReplay, sinks: Sinks, reporter: Reporter, logger: list[RunLogger]
) -> ReplayResult:
    """Replay into a recording of its own, written whole once the run is done."""
    from ekfviz import viz

    request, setup = opened.request, opened.setup
    info = viz.run_info(
        name=opened.log.source.name,
        command=request.command,
        parameters={**opened.params.as_dict(), "filter": request.filter_spec, **setup.parameters},
        input_path=request.data,
        truth=opened.log.truth,
        truth_path=opened.log.truth_files[0] if opened.log.truth_files else None,
        input_files=opened.log.source.files,
        truth_files=opened.log.truth_files,
    )
    done: list[ReplayResult] = []
    sink_error = None
    try:
        with viz.open_run(
            info, sinks, detail=request.output.detail, history=request.output.history,
            sensor=setup.sensor, gps_reference=setup.reference is not None,
        ) as run, signals.as_exceptions():  # fmt: skip
            logger.append(run)
            result = replay_into(opened, run, reporter)
            result = replace(result, report=_report(result, opened, info.input_sha256))
            if request.report is not None:
                write_json(request.report, result.report)
            done.append(result)
    except OutputError as error:  # on closing a recording that is whole: said after it
        if not done:
            raise
        sink_error = str(error)
    recording = logger[0].recording
    return replace(done[0], saved_to=recording.saved_to, served=recording.served,
                   sink_error=sink_error)  # fmt: skip


def replay_into(opened: OpenedReplay, logger: RunLogger, reporter: Reporter) -> ReplayResult:
    """Replay an opened input into ``logger`` (a recording open elsewhere: the caller
    closes it), the filter's warnings said as they come; the result's report holds the
    evaluation alone (:func:`replay` adds what describes the run). SIGINT and SIGTERM
    act as the caller's handlers say (:func:`replay` turns them into exceptions).

    :raises RunStopped: the replay was cut short (why, where, whether it was kept)
    """
    from ekfviz.app.replaying import replay_log

    request, setup = opened.request, opened.setup
    warnings = FilterWarnings(request.data, opened.log.source.file_of, reporter.warn)
    with _reading(opened, reporter) as events:
        evaluation = replay_log(
            events, opened.params, make_filter=opened.make_filter, name=request.filter_spec,
            data=request.data, truth=opened.log.truth, logger=logger, on_batch=warnings.add,
            scans=setup, file_of=opened.log.source.file_of,
        )  # fmt: skip
    warnings.summarise()
    truth = setup.truth_of_last()
    notes: list[Cell] = []
    if opened.log.truth is not None:
        notes += mismatch_notes(opened.params, opened.log.truth)
    return ReplayResult(
        evaluation=evaluation, truth=truth, table=evaluation.table(truth),
        lines=evaluation.lines(truth), summaries=setup.summary_lines(),
        report=evaluation.to_json(), notes=notes,
    )  # fmt: skip


@contextmanager
def _reading(opened: OpenedReplay, reporter: Reporter) -> Iterator[Iterator[AnyEvent]]:
    """The events to replay: read from the start again with a progress bar where the
    input is long (and the front end shows one), else as opened."""
    paths = opened.log.source.progress_paths
    size = sum(path.stat().st_size for path in paths if path.is_file())  # else the reader says
    if size < PROGRESS_MIN_BYTES:
        yield opened.events
        return
    with reporter.reading(f"replaying {paths[0].name}", size) as progress:
        yield opened.events if progress is None else opened.log.events(progress)


def _report(result: ReplayResult, opened: OpenedReplay, sha256: str) -> dict[str, object]:
    """The replay's JSON report: what was replayed, how, and the evaluation."""
    request = opened.request
    return {
        "ekfviz_version": __version__,
        "input": {"name": request.data.name, "sha256": sha256},
        "parameters": opened.params.as_dict(),
        **result.report,
        "filter": request.filter_spec,
        **opened.setup.extra,
    }


def _interrupted(data: Path, cause: BaseException, logger: list[RunLogger]) -> RunStopped:
    """A replay stopped by a signal outside the replay itself (while its input opened,
    while its recording closed): what was kept."""
    name = "SIGTERM" if isinstance(cause, signals.Terminated) else "SIGINT"
    saved_to = logger[0].recording.saved_to if logger else None
    kept = (
        f"the finished recording is saved in {saved_to}"
        if saved_to is not None
        else "nothing was written; existing files are left as they were"
    )
    stopped = RunStopped(f"{data}: interrupted ({name})", cause, kept=saved_to is not None)
    stopped.line = f"{data}: interrupted ({name}): {kept}"
    return stopped


class FilterWarnings:
    """Say the filter's warnings as ``FILE:LINE: ...``, the first few only: the
    recording's log holds all of them."""

    def __init__(
        self, data: Path, file_of: Callable[[bool], Path | None], warn: Callable[[str], None]
    ) -> None:
        self._data = data
        self._file_of = file_of  # a dataset directory's file of the line (its source's)
        self._warn = warn
        self.count = 0

    def add(self, events: EventBatch) -> None:
        for row in sorted(events.extras):
            for text in events.extras[row].warnings:
                self.count += 1
                if self.count <= FILTER_WARNINGS_SAID:
                    path = self._file_of(bool(events.is_predict[row])) or self._data
                    line = int(events.lines[row])
                    where = f"{path}:{line}" if line else str(self._data)
                    self._warn(f"{where}: {text}")

    def summarise(self) -> None:
        if self.count > FILTER_WARNINGS_SAID:
            self._warn(
                f"{self.count - FILTER_WARNINGS_SAID} more filter warnings"
                f" ({self.count} in all) are in the recording's log"
            )


def mismatch_notes(params: FilterParams, truth: GroundTruth) -> list[Cell]:
    """A note when the filter was told other noise levels than the simulator used."""
    told = params.as_dict()
    flags = [
        f"--{name.replace('_', '-')} " + " ".join(f"{v:g}" for v in np.atleast_1d(value))
        for name, value in (truth.simulated_with or {}).items()
        if name in told and not np.allclose(np.asarray(told[name], dtype=float), value)
    ]
    if not flags:
        return []
    return [(
        Styled("note:", "yellow"),
        Styled(" the truth file says the log was simulated with other noise levels than the"
               f" filter was told; to match them: {' '.join(flags)}"),
    )]  # fmt: skip
