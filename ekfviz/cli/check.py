"""``ekfviz check``: a filter in lockstep with the reference, every divergence and its cause."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.app.check import DEFAULT_TOLERANCE, CheckedLog, CheckOutcome, CheckRequest, check
from ekfviz.app.inputs import SourceArgs
from ekfviz.app.text import Styled, one_line
from ekfviz.cli.console import (
    DEBUG,
    TerminalReporter,
    err,
    note,
    out,
    plain,
    rendered,
    say,
    say_user_traceback,
    show,
)
from ekfviz.cli.options import (
    DEFAULT,
    FilterForm,
    FilterNoise,
    InitPoseSigma,
    TruthOption,
    UserFilter,
    WatchOption,
    _option,
    expands_options,
    piped_input,
)
from ekfviz.cli.program import app, command_line, given_options
from ekfviz.cli.sources import NO_SOURCE_ARGS, InitPoseOption, NoTruthOption, with_source_options

if TYPE_CHECKING:
    from ekfviz.check.coverage import Item as CoverageItem
    from ekfviz.check.lockstep import CheckResult

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
CheckFilter = Annotated[
    str,
    typer.Option(
        "--filter",
        help="The filter to check: PATH.py (a course module of init_landmarks, predict,"
        " update), PATH.py:ClassName or package.module:ClassName.",
        show_default=False,
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
CheckReport = Annotated[Path | None, _option("Write the result as JSON here.", show_default=False)]
CheckSave = Annotated[
    Path | None,
    _option(
        "Write a recording of the filter and the reference side by side here (with the"
        " battery, one per log: NAME-classic.rrd, NAME-edge.rrd).",
        show_default=False,
    ),
]


@app.command(name="check")
@expands_options
@with_source_options
def check_command(
    *,
    ctx: typer.Context,
    data: CheckLog = None,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot...)
    filter_text: CheckFilter = "",
    every: EveryOption = False,
    truth: TruthOption = None,
    no_truth: NoTruthOption = False,
    tolerance: Tolerance = DEFAULT_TOLERANCE,
    report: CheckReport = None,
    save: CheckSave = None,
    user: UserFilter,
    init_pose: InitPoseOption = None,
    noise: FilterNoise,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    form: FilterForm,
    watch: WatchOption = False,
) -> None:
    """Check a filter against the built-in reference, event by event.

    Before every event the reference starts from the filter's own state and applies the
    same event; the results are compared by landmark id, so every divergent event is a
    place where the filter's algebra differs, and its cause is named when a mistake of
    the catalogue (README) reproduces it. Without DATA it runs the bundled battery.
    Exit status 0 when every event matches, 1 at a divergence, 2 for bad input or a
    filter that fails.
    """
    request = CheckRequest(
        filter_text=filter_text, data=data, truth=truth, source_args=source_args,
        no_truth=no_truth, every=every, tolerance=tolerance, report=report, save=save,
        worker=user.worker() if filter_text else None, init_pose=init_pose,
        filter=form.values(noise, init_pose_sigma), given=given_options(ctx),
        command=command_line(),
    )  # fmt: skip
    if watch:
        from ekfviz.cli.watch import run_watch

        run_watch(request)
        return
    outcome = check(request, TerminalReporter())
    for checked in outcome.logs:
        _print(checked, outcome, every)
    if outcome.failed:
        raise typer.Exit(2)
    if outcome.diverged:
        raise typer.Exit(1)


def _print(checked: CheckedLog, outcome: CheckOutcome, every: bool) -> None:
    """The verdict on one log, its notes before and where it was saved after."""
    for text in checked.notes:  # what was chosen for the run (the start pose)
        note(text)
    print_verdict(
        checked.log, checked.name, checked.result, checked.missing, every, battery=outcome.battery
    )
    if checked.saved is not None:
        out.print(plain(checked.saved))


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
