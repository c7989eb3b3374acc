"""``ekfviz calibrate``: estimate a log's noise and odometry errors from its ground truth,
judge the candidate settings on held-out time, print the replay line of the best."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.calibrate import (
    FIT_SHARE,
    WINDOW_S,
    CalibrateRequest,
    calibrate,
    replay_line,
)
from ekfviz.app.inputs import SourceArgs
from ekfviz.cli.console import TerminalReporter, out, show_blocks
from ekfviz.cli.options import StudyLogArgument, TruthOption, not_nan
from ekfviz.cli.program import app
from ekfviz.cli.sources import NO_SOURCE_ARGS, with_source_options

Window = Annotated[
    float,
    typer.Option(
        help="Seconds of odometry per motion window of a timestamped log.",
        min=0.01,
        max=3600.0,
        callback=not_nan,
    ),
]
FitShare = Annotated[
    float,
    typer.Option(
        help="The share of the run (by time, untimed: by events) the noise is fitted on;"
        " the rest judges the candidate settings.",
        min=0.2,
        max=0.9,
        callback=not_nan,
    ),
]
CalibrationReport = Annotated[
    Path | None,
    typer.Option(
        help="Write every estimate, candidate and held-out figure as JSON here.",
        show_default=False,
    ),
]


@app.command(name="calibrate")
@with_source_options
def calibrate_command(
    data: StudyLogArgument,
    truth: TruthOption = None,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot, --odom...)
    window: Window = WINDOW_S,
    fit_share: FitShare = FIT_SHARE,
    report: CalibrationReport = None,
    verbose: Annotated[
        bool, typer.Option("--verbose", help="Say every warning of the fit, not a count of them.")
    ] = False,
) -> None:
    """Estimate the measurement noise, the motion noise and the systematic odometry errors
    from ground truth on the first part of the run, judge the candidates (the defaults, the
    estimates, the estimates scaled) on the rest, and print the replay line of the best.

    The truth is --truth (with true poses: a JSON file with "poses") or a dataset's own.
    """
    request = CalibrateRequest(data, truth, source_args, window, fit_share, report, verbose)
    calibrated = calibrate(request, TerminalReporter())
    show_blocks(calibrated.shown)
    if not calibrated.command:  # (the lines above say why no setting is recommended)
        return
    out.print(f"Replay with the recommended setting ({calibrated.best}):")
    if calibrated.program != "ekfviz":
        out.print(f"(ekfviz is not on your PATH: run it as {calibrated.program})", markup=False)
    # the line starts with "ekfviz replay", whatever runs here: scripts look for it
    out.print(replay_line(calibrated), soft_wrap=True, markup=False, highlight=False)
