"""``ekfviz check``: a filter in lockstep with the reference, every divergence and its cause."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.app.check import DEFAULT_TOLERANCE, CheckedLog, CheckOutcome, CheckRequest, check
from ekfviz.app.inputs import SourceArgs
from ekfviz.cli.checking import CheckLog, EveryOption, Tolerance, print_verdict
from ekfviz.cli.console import (
    TerminalReporter,
    note,
    out,
    plain,
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
)
from ekfviz.cli.program import app, command_line, given_options
from ekfviz.cli.sources import NO_SOURCE_ARGS, InitPoseOption, NoTruthOption, with_source_options

if TYPE_CHECKING:
    pass

CheckFilter = Annotated[
    str,
    typer.Option(
        "--filter",
        help="The filter to check: PATH.py (a course module of init_landmarks, predict,"
        " update), PATH.py:ClassName or package.module:ClassName.",
        show_default=False,
    ),
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
        from ekfviz.cli.checking import run_watch

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
