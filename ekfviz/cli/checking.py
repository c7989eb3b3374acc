"""What ``check``, ``watch`` and ``replay --watch`` share on the command line: the log
argument, ``--all`` and ``--tolerance``, the verdict on one log as printed, and a watch
run with each of its runs printed."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.app.check import CheckRequest
from ekfviz.app.errors import Interrupted, UsageError
from ekfviz.app.text import Styled, one_line
from ekfviz.cli.console import (
    DEBUG,
    TerminalReporter,
    err,
    out,
    plain,
    release_held,
    rendered,
    say,
    say_user_traceback,
    show,
    warn,
)
from ekfviz.cli.options import RerunSinks, _option, piped_input

if TYPE_CHECKING:
    from ekfviz.app.check import CheckResult, CoverageItem
    from ekfviz.app.watch import CheckOutcome, WatchedRun

CheckLog = Annotated[
    Path | None,
    typer.Argument(
        help="A log in the classic or the extended format ('-': from standard input), or an"
        " MRCLAM dataset directory (with --robot) [default: the bundled battery: the classic"
        " sample, the edge log and the mid-run log]; the Victoria Park directory is for"
        " replay only.",
        show_default=False,
        callback=piped_input,
    ),
]
EveryOption = Annotated[
    bool,
    typer.Option(
        "--all",
        help="Go on after a divergence: find the cause of every divergent event and"
        " report them grouped.",
    ),
]
Tolerance = Annotated[
    float, _option("Largest difference allowed, |got - expected| / max(1, |expected|).", min=0.0)
]


def print_verdict(
    log: Path,
    name: str,
    result: CheckResult,
    missing: list[CoverageItem],
    every: bool,
    *,
    battery: bool,
) -> None:
    """The verdict on one log, as the report says it (no markup read in any name), and
    what the log did not exercise (``missing``)."""
    if battery:
        say([(Styled("log ", "bold"), Styled(name, "bold"), Styled(f" ({log.name})"))])
    say(result.verdict_lines(name, every))
    if result.first_divergence is not None and every and result.divergences:
        show(result.groups_table())
        say(result.group_lines())
    if result.error is not None:
        err.print(rendered((Styled("error: ", "bold red"),
                            Styled(one_line(f"{name}:{result.error_line}: {result.error}")))),
                  soft_wrap=True)  # fmt: skip
        if DEBUG["traceback"]:
            say_user_traceback(result.error_traceback)
    if missing:
        say([Styled(f"  not exercised by {name}:")])
        say([Styled(f"    - {item.untested}") for item in missing])


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
