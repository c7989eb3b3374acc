"""``ekfviz watch``: check a filter again on every save, into the viewer that stays open
(also ``check --watch`` and ``replay --filter PATH.py --watch``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.app.check import DEFAULT_TOLERANCE, CheckRequest
from ekfviz.app.errors import Interrupted, UsageError
from ekfviz.app.inputs import SourceArgs
from ekfviz.app.text import Styled, one_line
from ekfviz.cli.check import CheckLog, EveryOption, Tolerance, print_verdict
from ekfviz.cli.console import TerminalReporter, err, out, plain, release_held, rendered, say, warn
from ekfviz.cli.options import (
    DEFAULT,
    FilterForm,
    FilterNoise,
    InitPoseSigma,
    RerunSinks,
    TruthOption,
    UserFilter,
    _option,
    expands_options,
)
from ekfviz.cli.program import app, command_line, given_options
from ekfviz.cli.sources import NO_SOURCE_ARGS, InitPoseOption, NoTruthOption, with_source_options

if TYPE_CHECKING:
    from ekfviz.app.watch import CheckOutcome, WatchedRun

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


@app.command(name="watch")
@expands_options
@with_source_options
def watch_command(
    *,
    ctx: typer.Context,
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
        filter_text=filter_text, data=data, truth=truth, source_args=source_args,
        no_truth=no_truth, every=every, tolerance=tolerance, report=report, save=output.save,
        worker=user.worker(), init_pose=init_pose, filter=form.values(noise, init_pose_sigma),
        given=given_options(ctx), command=command_line(),
    )  # fmt: skip
    run_watch(request, output)


def run_watch(request: CheckRequest, output: RerunSinks | None = None) -> None:
    """Watch as asked, each run printed, until Ctrl-C (exit 130, or 143 for SIGTERM).

    :param output: the viewer asked for (None: ``check``'s ``--save`` only, beside the
        viewer opened where a display exists)
    """
    from ekfviz.app.watch.start import Viewer, watch_check

    viewer = Viewer()
    if output is not None:
        viewer = Viewer(output.spawn, output.serve, output.connect, output.bind)
    release_held()  # said as they come: the watch runs until Ctrl-C
    printer = _Printer(battery=request.data is None, every=request.every)
    try:
        watch_check(request, viewer, TerminalReporter(), printer.run)
    except Interrupted as stop:
        kept = [str(path) for path in printer.saved if path.exists()]
        out.print(plain(
            f"Stopped ({stop.name}) after {printer.runs} run(s)"
            + (f"; the newest complete recording is in {', '.join(kept)}" if kept else "")
        ))  # fmt: skip
        raise SystemExit(stop.exit_code) from None


# replay's options that a watch (a check) does not take, by parameter name
REPLAY_ONLY = ("as_json", "odometry_scale", "odometry_bias", "motion_noise", "gate",
               "association", "gate_probability", "confirm", "confirm_window", "detail",
               "history")  # fmt: skip


def refuse_replay_only(given: frozenset[str]) -> None:
    """``replay --watch`` checks the filter: replay's own options are refused, in one line.

    :raises UsageError: one of them was given
    """
    refused = [f"--{name.replace('_', '-')}" for name in REPLAY_ONLY if name in given]
    if refused:
        raise UsageError(
            f"{', '.join(refused).replace('--as-json', '--json')}: replay's own; --watch"
            " checks the filter against the reference on every save, without them"
        )


class _Printer:
    """What the terminal shows of each run: one short block."""

    def __init__(self, *, battery: bool, every: bool) -> None:
        self.battery = battery
        self.every = every
        self.runs = 0
        self.saved: list[Path] = []

    def run(self, run: WatchedRun) -> None:
        self.runs = run.number
        self.saved = list(dict.fromkeys([*self.saved, *run.saved]))
        clock = time.strftime("%H:%M:%S", time.localtime(run.started))
        changed = ", ".join(path.name for path in run.changed)
        out.print()  # a blank line between two runs' blocks
        say([(Styled(f"run {run.number}", "bold"), Styled(f" at {clock}"),
              Styled(f": {changed} changed" if changed else ""))])  # fmt: skip
        for outcome in run.outcomes:
            self._outcome(outcome)
        for problem in run.problems:
            warn(problem)

    def _outcome(self, outcome: CheckOutcome) -> None:
        item, result, failure = outcome.input, outcome.result, outcome.failure
        if result is not None:
            print_verdict(item.log, item.name, result, [], self.every, battery=self.battery)
        elif self.battery:
            say([(Styled("log ", "bold"), Styled(item.name, "bold"))])
        if failure is not None and (result is None or not result.error):  # (else said)
            kept = f" ({item.save} is left as it was)" if item.save and item.save.exists() else ""
            line = f"{failure.where}: {failure.message}{kept}"
            err.print(rendered((Styled("error: ", "bold red"), Styled(one_line(line)))),
                      soft_wrap=True)  # fmt: skip
