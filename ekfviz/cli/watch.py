"""``ekfviz watch``: check a filter again on every save, into the viewer that stays open
(also ``check --watch`` and ``replay --filter PATH.py --watch``)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ekfviz import signals
from ekfviz.check.lockstep import DEFAULT_TOLERANCE
from ekfviz.cli.check_run import (
    CheckLog,
    CheckRequest,
    EveryOption,
    Tolerance,
    log_entry,
    per_log_path,
    prepared_input,
    print_verdict,
    report_document,
)
from ekfviz.cli.common import (
    DEFAULT,
    RECORDINGS_DIR,
    _option,
    app,
    check_outputs,
    err,
    fail,
    filter_module,
    given,
    out,
    plain,
    release_held,
    rendered,
    say,
    warn,
    write_json,
)
from ekfviz.cli.options import (
    FilterForm,
    FilterNoise,
    InitPoseSigma,
    TruthOption,
    UserFilter,
    expands_options,
)
from ekfviz.cli.replay_run import ReplayRequest, RerunSinks
from ekfviz.cli.sources import NO_SOURCE_ARGS, InitPoseOption, NoTruthOption, with_source_options
from ekfviz.core.errors import InputError
from ekfviz.core.tables import Styled, one_line
from ekfviz.filters.spec import BUILTIN, FilterSpec, FilterSpecError, target_of
from ekfviz.samples import write_battery
from ekfviz.sources import SourceArgs

if TYPE_CHECKING:
    from ekfviz.app.watch import CheckInput, CheckOutcome, WatchedRun
    from ekfviz.viz.run import Sinks

WatchFilter = Annotated[
    str,
    typer.Argument(
        help="The filter to watch: PATH.py (a course module of init_landmarks, predict,"
        " update) or PATH.py:ClassName.",
        show_default=False,
        metavar="FILTER",
    ),
]
WatchReport = Annotated[
    Path | None,
    _option(
        "Keep the newest run's result here as JSON (check's report, with the run's number"
        " and the files whose save started it), replaced at every run.",
        show_default=False,
    ),
]


@app.command()
@expands_options
@with_source_options
def watch(
    *,
    filter_text: WatchFilter,
    data: CheckLog = None,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot...)
    every: EveryOption = False,
    truth: TruthOption = None,
    no_truth: NoTruthOption = False,
    tolerance: Tolerance = DEFAULT_TOLERANCE,
    report: WatchReport = None,
    output: RerunSinks,
    user: UserFilter,
    init_pose: InitPoseOption = None,
    noise: FilterNoise,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    form: FilterForm,
) -> None:
    """Check a filter against the reference now and again on every save, until Ctrl-C.

    Each save of the filter's files (the module and the files beside it that it imports)
    or of the log runs the check again, as a new recording in the same viewer (spawned
    by default, or --connect, --serve), the run before drawn grey in the map; the verdict
    is printed and logged with it. A save during a run cancels the run. --save keeps the
    newest complete recording, --report the newest run's result (an error: its file,
    line and message; the last good recording stays). Without DATA it runs the bundled
    battery.
    """
    request = CheckRequest(
        data=data, filter_text=filter_text, every=every, truth=truth, tolerance=tolerance,
        report=report, save=output.save, user=user, init_pose=init_pose, noise=noise,
        init_pose_sigma=init_pose_sigma, form=form, source_args=source_args, no_truth=no_truth,
    )  # fmt: skip
    run_watch(request, output)


def run_watch(request: CheckRequest, output: RerunSinks | None = None) -> None:
    """Watch as asked: the filter and the logs checked once, then again at every save.

    :param output: where the recordings go (None: ``check``'s ``--save`` only, beside
        the viewer opened where a display exists)
    """
    from ekfviz.app.watch import WatchHooks, WatchRequest
    from ekfviz.app.watch import watch as watch_runs
    from ekfviz.sandbox.host import WorkerFault
    from ekfviz.viz.run import SinkError

    signals.as_interrupts()  # (a replay defers them): the first Ctrl-C ends the watch
    spec, module = _filter(request, output)
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as folder:
        sinks, save = _sinks(request, output)
        inputs, files = _inputs(request, Path(folder), save)
        release_held()  # said as they come from now on: the watch runs until Ctrl-C
        printer = _Printer(request, spec)
        logs = ", ".join(str(path) for path in files) or "the battery"
        out.print(plain(f"Watching {module} (and the modules beside it that it imports) on"
                        f" {logs}; Ctrl-C ends the watch."), soft_wrap=True)  # fmt: skip
        try:
            watch_runs(
                WatchRequest(spec, module, inputs, files, request.tolerance, request.every,
                             sinks),
                WatchHooks(printer.run, printer.note, warn),
            )  # fmt: skip
        except signals.Interrupted as stop:
            kept = [str(path) for path in printer.saved if path.exists()]
            out.print(
                plain(
                    f"Stopped ({stop.name}) after {printer.runs} run(s)"
                    + (f"; the newest complete recording is in {', '.join(kept)}" if kept else "")
                )
            )
            raise SystemExit(stop.exit_code) from None
        except (WorkerFault, FilterSpecError, InputError, SinkError) as error:
            fail(str(error))


# replay's options that a watch (a check) does not take, by parameter name
REPLAY_ONLY = ("as_json", "odometry_scale", "odometry_bias", "motion_noise", "gate",
               "association", "gate_probability", "confirm", "confirm_window", "detail",
               "history")  # fmt: skip


def watch_replay(request: ReplayRequest) -> None:
    """``replay --filter PATH.py --watch``: the watch of that filter on the replay's log,
    its recordings where the replay's would go."""
    if request.filter_spec == BUILTIN:
        fail("--watch checks a filter of yours on every save: add --filter PATH.py")
    refused = [f"--{name.replace('_', '-')}" for name in REPLAY_ONLY if given(name)]
    if refused:
        fail(f"{', '.join(refused).replace('--as-json', '--json')}: replay's own; --watch"
             " checks the filter against the reference on every save, without them")  # fmt: skip
    run_watch(
        CheckRequest(
            data=request.data, filter_text=request.filter_spec, every=False,
            truth=request.truth, tolerance=DEFAULT_TOLERANCE, report=request.report,
            save=request.output.save, user=request.user, init_pose=request.init_pose,
            noise=request.noise, init_pose_sigma=request.init_pose_sigma, form=request.form,
            source_args=request.source_args, no_truth=request.no_truth,
        ),
        request.output,
    )  # fmt: skip


def _filter(request: CheckRequest, output: RerunSinks | None) -> tuple[FilterSpec, Path]:
    """The filter to watch, and its file; one line and exit 2 where there is none."""
    if not request.filter_text:
        fail("give the filter to watch: PATH.py (or PATH.py:ClassName)")
    module = filter_module(request.filter_text)
    if module is None:
        fail(f"{request.filter_text}: watch follows a filter's file: PATH.py or PATH.py:ClassName")
    check_outputs(
        ("--report", request.report), ("--save", request.save),
        inputs=[request.data, request.truth, module],
    )  # fmt: skip
    for given_path in (request.data, request.truth):  # (one deleted later is waited for)
        if given_path is not None and not given_path.exists():
            fail(f"{given_path}: no such file or folder")
    if output is not None:
        output.check()
    spec = FilterSpec.parse(request.filter_text, worker=request.user.worker())
    try:
        target_of(spec.text)
    except FilterSpecError as error:
        fail(str(error))
    return spec, module


def _sinks(request: CheckRequest, output: RerunSinks | None) -> tuple[Sinks, Path | None]:
    """The viewer each run is sent to, and where the newest recording is kept: as asked,
    else a spawned viewer where a display exists, else a file under recordings/."""
    from ekfviz import viz

    asked = viz.Sinks(save=request.save)
    if output is not None:
        asked = viz.Sinks(save=output.save, spawn=output.spawn, serve=output.serve,
                          connect=output.connect, bind=output.bind or viz.LOOPBACK)  # fmt: skip
    name = f"{Path(request.filter_text.split(':')[0]).stem}-watch"
    if not asked.any:
        try:
            asked, note = viz.resolve_default_sinks(asked, Path(name), RECORDINGS_DIR, name)
        except viz.SinkError as error:
            fail(str(error))
        if note:
            out.print(plain(note.replace("saved the recording to", "keeping the newest"
                                         " recording in")), soft_wrap=True)  # fmt: skip
    viewer = viz.Sinks(spawn=asked.spawn, serve=asked.serve, connect=asked.connect,
                       bind=asked.bind)  # fmt: skip
    return viewer, asked.save


def _inputs(
    request: CheckRequest, folder: Path, save: Path | None
) -> tuple[tuple[CheckInput, ...], tuple[Path, ...]]:
    """Each log checked (the log, or the battery written in ``folder``) prepared once,
    and the files followed for them (none for the battery, which does not change)."""
    from ekfviz.app.watch import CheckInput

    data = request.data
    if data is None and request.truth is not None:
        fail("--truth needs a log (DATA); the battery brings its own truth")
    logs: list[tuple[Path, Path | None, tuple[float, float, float] | None]] = (
        [(data, request.truth, request.init_pose)] if data is not None else []
    )
    logs += [] if data is not None else write_battery(folder)
    inputs, files = [], []
    for log, log_truth, start in logs:
        opened = prepared_input(request, log, log_truth, start)
        for note in opened.notes:
            out.print(plain(note), soft_wrap=True)
        target = save if data is not None or save is None else per_log_path(save, log)
        name = str(log) if data is not None else log.stem
        inputs.append(CheckInput(log, name, opened.params, log_truth, opened.own_truth,
                                 request.source_args, target))  # fmt: skip
        if data is not None:
            files += [*(opened.files or [log]), *([log_truth] if log_truth else [])]
    return tuple(inputs), tuple(dict.fromkeys(files))


class _Printer:
    """What the terminal shows of each run (one short block) and the report it writes."""

    def __init__(self, request: CheckRequest, spec: FilterSpec) -> None:
        self.request = request
        self.spec = spec
        self.runs = 0
        self.saved: list[Path] = []

    def note(self, text: str) -> None:
        out.print(plain(text), soft_wrap=True)

    def run(self, run: WatchedRun) -> None:
        """Print the run's block and replace the report."""
        self.runs = run.number
        self.saved = list(dict.fromkeys([*self.saved, *run.saved]))
        clock = time.strftime("%H:%M:%S", time.localtime(run.started))
        changed = ", ".join(path.name for path in run.changed)
        out.print()  # a blank line between two runs' blocks
        say([(Styled(f"run {run.number}", "bold"), Styled(f" at {clock}"),
              Styled(f": {changed} changed" if changed else ""))])  # fmt: skip
        battery = self.request.data is None
        for outcome in run.outcomes:
            self._outcome(outcome, battery)
        for problem in run.problems:
            warn(problem)
        if self.request.report is not None:
            write_json(self.request.report, self.document(run))

    def _outcome(self, outcome: CheckOutcome, battery: bool) -> None:
        item, result, failure = outcome.input, outcome.result, outcome.failure
        if result is not None:
            print_verdict(item.log, result, outcome.coverage, self.request.every,
                          battery=battery, coverage=False)  # fmt: skip
        elif battery:
            say([(Styled("log ", "bold"), Styled(item.name, "bold"))])
        if failure is not None:
            kept = f" ({item.save} is left as it was)" if item.save and item.save.exists() else ""
            if result is None or not result.error:  # (else print_verdict said it)
                line = f"{failure.where}: {failure.message}{kept}"
                err.print(rendered((Styled("error: ", "bold red"), Styled(one_line(line)))),
                          soft_wrap=True)  # fmt: skip

    def document(self, run: WatchedRun) -> dict[str, Any]:
        """Check's report of the run, with its number and the files that changed."""
        battery = self.request.data is None
        entries = []
        for outcome in run.outcomes:
            item, result, failure = outcome.input, outcome.result, outcome.failure
            if result is not None:
                entry = log_entry(item.log, result, outcome.coverage, battery=battery)
            else:
                entry = {"log": item.name, "match": False, "divergences": [], "causes": [],
                         "coverage": []}  # fmt: skip
            if failure is not None:
                entry["error"] = failure.to_json()
            entries.append(entry)
        params = run.outcomes[-1].input.params
        document = report_document(self.spec, params, entries, battery=battery)
        failures = [outcome.failure for outcome in run.outcomes if outcome.failure is not None]
        document["error"] = failures[0].to_json() if failures else None
        document["run"] = run.number
        document["files"] = [str(path) for path in run.changed]
        return document
