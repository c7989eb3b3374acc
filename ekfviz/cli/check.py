"""``ekfviz check``: a filter in lockstep with the reference, every divergence and its cause."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.check.lockstep import DEFAULT_TOLERANCE
from ekfviz.cli.check_run import CheckLog, CheckRequest, EveryOption, Tolerance, run_check
from ekfviz.cli.common import DEFAULT, _option, app
from ekfviz.cli.options import (
    FilterForm,
    FilterNoise,
    InitPoseSigma,
    TruthOption,
    UserFilter,
    WatchOption,
    expands_options,
)
from ekfviz.cli.sources import NO_SOURCE_ARGS, InitPoseOption, NoTruthOption, with_source_options
from ekfviz.sources import SourceArgs

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


@app.command()
@expands_options
@with_source_options
def check(
    *,
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
        data=data, filter_text=filter_text, every=every, truth=truth, tolerance=tolerance,
        report=report, save=save, user=user, init_pose=init_pose, noise=noise,
        init_pose_sigma=init_pose_sigma, form=form, source_args=source_args, no_truth=no_truth,
    )  # fmt: skip
    if watch:
        from ekfviz.cli.watch import run_watch

        run_watch(request)
    else:
        run_check(request)
