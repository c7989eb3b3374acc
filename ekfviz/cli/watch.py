"""``ekfviz watch``: check a filter again on every save, into the viewer that stays open
(also ``check --watch`` and ``replay --filter PATH.py --watch``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.app.check import DEFAULT_TOLERANCE, CheckRequest
from ekfviz.app.inputs import SourceArgs
from ekfviz.cli.checking import CheckLog, EveryOption, Tolerance, run_watch
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
    pass

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
