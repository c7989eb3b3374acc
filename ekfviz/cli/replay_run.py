"""What ``ekfviz replay`` does once its options are read: open the input, set the filter
up, record the run, print and write the evaluation, and say in one line what stopped it."""

from __future__ import annotations

import shlex
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer
from rich.markup import escape
from rich.progress import BarColumn, DownloadColumn, Progress, TaskID, TimeRemainingColumn

from ekfviz import __version__, signals
from ekfviz.association import AssociationError
from ekfviz.cli.common import (
    DEFAULT,
    RECORDINGS_DIR,
    check_outputs,
    err,
    fail,
    filter_module,
    human_output_to_stderr,
    out,
    print_json,
    refuse_output_over_input,
    release_held,
    say,
    show,
    warn,
    write_json,
)
from ekfviz.cli.options import (
    Association,
    FilterForm,
    FilterNoise,
    OdometryBias,
    OdometryScale,
    OptionGroup,
    UserFilter,
)
from ekfviz.cli.scans import ReplaySetup, replay_setup
from ekfviz.cli.sources import MotionNoiseChoice, OpenedLog, first_time, open_log, resolve
from ekfviz.core.errors import FilterError, InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent, EventKind, EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.errors import Evaluation
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.spec import FilterSpecError, load_filter, release
from ekfviz.sources import SourceArgs

if TYPE_CHECKING:
    from ekfviz.filters.plugged import FilterFactory
    from ekfviz.viz.run import RunLogger

RERUN = "Rerun output"
PROGRESS_MIN_BYTES = 1 << 20  # files under 1 MiB replay in well under a second


@dataclass(frozen=True, slots=True)
class Odometry(OptionGroup):
    """The systematic odometry errors taken out of every control."""

    odometry_scale: OdometryScale = DEFAULT.odometry_scale
    odometry_bias: OdometryBias = DEFAULT.odometry_bias


@dataclass(frozen=True, slots=True)
class RerunSinks(OptionGroup):
    """Where the recording goes."""

    save: Annotated[
        Path | None,
        typer.Option(
            help="Write the recording to this .rrd file.",
            show_default=False,
            rich_help_panel=RERUN,
        ),
    ] = None
    spawn: Annotated[
        bool, typer.Option("--spawn", help="Open the native Rerun viewer.", rich_help_panel=RERUN)
    ] = False
    serve: Annotated[
        bool,
        typer.Option(
            "--serve",
            help="Serve the web viewer on localhost (see --bind) until Ctrl-C.",
            rich_help_panel=RERUN,
        ),
    ] = False
    bind: Annotated[
        str | None,
        typer.Option(
            help="With --serve: the IP address to listen on \\[default: 127.0.0.1, this"
            " machine only]; 0.0.0.0 serves the recording to the whole network.",
            show_default=False,
            metavar="ADDRESS",
            rich_help_panel=RERUN,
        ),
    ] = None
    connect: Annotated[
        str | None,
        typer.Option(
            help="Stream to a running viewer at this gRPC URL.",
            show_default=False,
            rich_help_panel=RERUN,
        ),
    ] = None

    def check(self) -> None:
        """Refuse a --bind without --serve or a bad address, before any work."""
        from ekfviz import viz

        if self.bind is not None:
            if not self.serve:
                fail("--bind is the address of --serve: add --serve")
            try:
                viz.check_bind(self.bind)
            except viz.SinkError as error:
                fail(str(error))


@dataclass(frozen=True, slots=True)
class RerunOutput(RerunSinks):
    """Where the recording goes and how much of it is logged."""

    detail: Annotated[
        bool,
        typer.Option(
            "--detail",
            help="Log every landmark's ellipse at every update, even in a large map"
            " (by default a map of over 32 landmarks is logged whole every 25 steps).",
            rich_help_panel=RERUN,
        ),
    ] = False
    history: Annotated[
        bool,
        typer.Option(
            "--history",
            help="The classic figure: the map keeps every predicted (magenta) and updated"
            " (blue) robot ellipse up to the time cursor.",
            rich_help_panel=RERUN,
        ),
    ] = False


@dataclass(frozen=True, slots=True)
class ReplayRequest:
    """A replay as the command line asks for it."""

    ctx: typer.Context
    data: Path
    truth: Path | None
    source_args: SourceArgs
    no_truth: bool
    report: Path | None
    as_json: bool
    noise: FilterNoise
    odometry: Odometry
    motion_noise: MotionNoiseChoice
    init_pose: tuple[float, float, float] | None
    gate: float | None
    init_pose_sigma: tuple[float, float, float]
    form: FilterForm
    filter_spec: str
    user: UserFilter
    output: RerunOutput
    association: Association


@dataclass(slots=True)
class Opened:
    """The input opened and the filter set up for it."""

    log: OpenedLog
    setup: ReplaySetup
    params: FilterParams
    events: Iterator[AnyEvent]


def run_replay(request: ReplayRequest) -> None:
    """Replay as asked; every error is one line and its exit code (see the module)."""
    from ekfviz import app as pipeline  # rerun loads only for commands that record
    from ekfviz import viz

    check_outputs_of(request)
    params = _params(request)
    make_filter = _filter(request)
    logger: list[RunLogger] = []  # the logger once open, for what a stop kept
    sinks = None
    try:
        try:
            opened = open_input(request, params, make_filter is None or make_filter is EkfSlam)
            sinks, note = viz.resolve_default_sinks(
                viz.Sinks(
                    save=request.output.save, spawn=request.output.spawn,
                    serve=request.output.serve, connect=request.output.connect,
                    bind=request.output.bind or viz.LOOPBACK,
                ),
                request.data, RECORDINGS_DIR, name=opened.log.source.name,
            )  # fmt: skip
            _record(request, opened, make_filter, sinks, note, logger)
        finally:  # a user's filter ended (its output said) before the line saying why
            release(make_filter)
    except pipeline.RunStopped as stopped:
        fail(_stopped(stopped, logger, sinks), code=stopped.exit_code)
    except (InputError, FilterError, AssociationError, viz.SinkError) as error:
        fail(str(error))
    except (KeyboardInterrupt, signals.Terminated) as signal_error:  # outside the replay itself
        name = "SIGTERM" if isinstance(signal_error, signals.Terminated) else "SIGINT"
        saved_to = logger[0].recording.saved_to if logger else None
        kept = (
            f"the finished recording is saved in {saved_to}"
            if saved_to is not None
            else "nothing was written; existing files are left as they were"
        )
        fail(
            f"{request.data}: interrupted ({name}): {kept}", code=143 if name == "SIGTERM" else 130
        )


def check_outputs_of(request: ReplayRequest) -> None:
    """Refuse bad output paths and options before any work; --json keeps stdout."""
    check_outputs(
        ("--save", request.output.save), ("--report", request.report),
        inputs=[request.data, request.truth, filter_module(request.filter_spec)],
    )  # fmt: skip
    request.output.check()
    if request.as_json:
        human_output_to_stderr()


def _params(request: ReplayRequest) -> FilterParams:
    params = request.form.params(request.noise, request.init_pose_sigma, log=request.data)
    odometry = request.odometry
    if min(odometry.odometry_scale) <= 0:
        fail("--odometry-scale values must be positive")
    return replace(
        params, odometry_scale=odometry.odometry_scale, odometry_bias=odometry.odometry_bias
    )


def _filter(request: ReplayRequest) -> FilterFactory | None:
    try:
        return load_filter(request.filter_spec, request.user.worker())
    except FilterSpecError as error:
        fail(str(error))


def open_input(request: ReplayRequest, params: FilterParams, builtin: bool) -> Opened:
    """The input opened, its defaults applied, the filter and associator set up for it."""
    opened = open_log(request.data, request.source_args, request.truth, request.no_truth)
    # a dataset directory's files are known now: none of them may be written over
    refuse_output_over_input(
        ("--save", request.output.save), ("--report", request.report),
        inputs=[*opened.source.files, *opened.truth_files],
    )  # fmt: skip
    start, events = first_time(opened.events())
    params, notes = resolve(
        params, opened, start, request.init_pose, request.motion_noise, request.gate
    )
    for text in notes:
        out.print(text, soft_wrap=True)
    setup = replay_setup(
        request.ctx, opened, params, builtin=builtin, assoc=request.association.params()
    )
    return Opened(log=opened, setup=setup, params=setup.params, events=events)


def _record(
    request: ReplayRequest,
    opened: Opened,
    make_filter: FilterFactory | None,
    sinks: Any,
    note: str | None,
    logger: list[RunLogger],
) -> None:
    """Replay into the recording, then print and write the evaluation."""
    from ekfviz import app as pipeline
    from ekfviz import viz

    setup, params, truth_xy = opened.setup, opened.params, opened.log.truth
    info = viz.run_info(
        name=opened.log.source.name,
        command=shlex.join(["ekfviz", *sys.argv[1:]]),
        parameters={**params.as_dict(), "filter": request.filter_spec, **setup.parameters},
        input_path=request.data,
        truth=truth_xy,
        truth_path=opened.log.truth_files[0] if opened.log.truth_files else None,
        input_files=opened.log.source.files,
        truth_files=opened.log.truth_files,
    )
    output = request.output
    with (
        open_progress(opened.log.source.progress_paths) as progress,
        viz.open_run(
            info, sinks, detail=output.detail, history=output.history, sensor=setup.sensor,
            gps_reference=setup.reference is not None,
        ) as run,
        signals.as_exceptions(),
    ):  # fmt: skip
        logger.append(run)
        file_of = opened.log.source.file_of
        warnings = FilterWarnings(request.data, file_of)
        events = opened.events
        if progress is not None:
            events = opened.log.events(progress)  # read from the start, with a bar
        evaluation = pipeline.replay_log(
            events, params, make_filter=make_filter, name=request.filter_spec,
            data=request.data, truth=truth_xy, logger=run, on_record=warnings.add, scans=setup,
            file_of=file_of,
        )  # fmt: skip
        if progress is not None:
            progress.close()
        extra = setup.extra  # what the run added (scans, the reference): see finish()
        warnings.summarise()
        release_held()  # the log is read whole: its warnings, before the results
        print_evaluation(evaluation, setup.truth_of_last())
        setup.print_summary(extra)
        document = {
            **report_json(evaluation, params, request.data, info.input_sha256),
            "filter": request.filter_spec,
            **extra,
        }
        if request.report is not None:
            write_json(request.report, document)
        if request.as_json:
            print_json(document)
        if truth_xy is not None:
            mismatch_note(params, truth_xy)
        if note:
            out.print(note)
        if run.url:
            out.print(f"Serving the web viewer at [bold]{run.url}[/] (Ctrl-C to stop)")
        run.wait_while_serving()


def _stopped(stopped: Any, logger: list[RunLogger], sinks: Any) -> str:
    """The line of a replay cut short: why, and what it kept where."""
    where = ""
    saved_to = logger[0].recording.saved_to if logger else None
    if stopped.kept and saved_to is not None:
        where = f"; the recording of everything before it is saved in {saved_to}"
        if saved_to != sinks.save:
            where += f" ({sinks.save} is left as it was)"
    elif sinks is not None and sinks.save is not None and sinks.save.exists():
        where = f"; {sinks.save} is left as it was"
    return f"{stopped.reason}{where}"


class FilterWarnings:
    """Print the filter's warnings as ``FILE:LINE: warning: ...``, the first few only:
    the recording's log holds all of them."""

    PRINTED = 10

    def __init__(self, data: Path, file_of: Callable[[bool], Path | None]) -> None:
        self._data = data
        self._file_of = file_of  # a dataset directory's file of the line (its source's)
        self.count = 0

    def add(self, record: EventRecord) -> None:
        for text in record.warnings:
            self.count += 1
            if self.count <= self.PRINTED:
                path = self._file_of(record.kind is EventKind.PREDICT) or self._data
                where = f"{path}:{record.line}" if record.line else str(self._data)
                warn(escape(f"{where}: {text}"))

    def summarise(self) -> None:
        if self.count > self.PRINTED:
            warn(
                f"{self.count - self.PRINTED} more filter warnings"
                f" ({self.count} in all) are in the recording's log"
            )


@dataclass(frozen=True, slots=True)
class ReadingBar:
    """A progress bar over the bytes read: called with the sum read so far; closed
    before the results are printed, so that they go where standard output goes."""

    bar: Progress
    task: TaskID

    def __call__(self, done: int) -> None:
        self.bar.update(self.task, completed=done)

    def close(self) -> None:
        self.bar.stop()  # (again at the block's end: a no-op)


@contextmanager
def open_progress(paths: list[Path]) -> Iterator[ReadingBar | None]:
    """A progress bar over the bytes of ``paths`` (read side by side, the bar told the
    sum of the bytes read) when they are long and standard error is a terminal, else
    nothing (rich's bar would still end with a blank line on a pipe or a file).

    What is printed to standard output while the bar is shown goes above it only where
    standard output is a terminal too; to a file or a pipe it goes as ever."""
    size = sum(path.stat().st_size for path in paths if path.is_file())  # else the reader says
    path = paths[0]
    if size < PROGRESS_MIN_BYTES or not err.is_terminal:
        yield None
        return
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        DownloadColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        redirect_stdout=sys.stdout.isatty(),  # the same screen: above the bar
    ) as bar:
        yield ReadingBar(bar, bar.add_task(f"replaying {path.name}", total=size))


def print_evaluation(evaluation: Evaluation, truth: GroundTruth | None) -> None:
    """The final landmark table and pose, with errors when the truth is known."""
    show(evaluation.table(truth))
    say(evaluation.lines(truth))


def mismatch_note(params: FilterParams, truth: GroundTruth) -> None:
    """Say so when the filter was told other noise levels than the simulator used."""
    told = params.as_dict()
    flags = [
        f"--{name.replace('_', '-')} " + " ".join(f"{v:g}" for v in np.atleast_1d(value))
        for name, value in (truth.simulated_with or {}).items()
        if name in told and not np.allclose(np.asarray(told[name], dtype=float), value)
    ]
    if flags:
        out.print(
            "[yellow]note:[/] the truth file says the log was simulated with other noise"
            f" levels than the filter was told; to match them: {' '.join(flags)}",
            soft_wrap=True,
        )


def report_json(
    evaluation: Evaluation, params: FilterParams, data: Path, sha256: str
) -> dict[str, object]:
    return {
        "ekfviz_version": __version__,
        "input": {"name": data.name, "sha256": sha256},
        "parameters": params.as_dict(),
        **evaluation.to_json(),
    }
