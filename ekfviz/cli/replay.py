"""``ekfviz replay``: replay a log through a filter, record it, print the evaluation."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import DEFAULT, app
from ekfviz.cli.options import (
    Association,
    FilterForm,
    FilterNoise,
    FilterOption,
    InitPoseSigma,
    LogArgument,
    TruthOption,
    UserFilter,
    WatchOption,
    expands_options,
)
from ekfviz.cli.replay_run import Odometry, ReplayRequest, RerunOutput, run_replay
from ekfviz.cli.sources import (
    NO_SOURCE_ARGS,
    GateOption,
    InitPoseOption,
    MotionNoiseChoice,
    MotionNoiseOption,
    NoTruthOption,
    with_source_options,
)
from ekfviz.filters.spec import BUILTIN
from ekfviz.sources import SourceArgs

ReportOption = Annotated[
    Path | None, typer.Option(help="Write the evaluation as JSON here.", show_default=False)
]
JsonOption = Annotated[
    bool,
    typer.Option(
        "--json", help="Print the evaluation as JSON on stdout (the rest goes to stderr)."
    ),
]


@app.command()
@expands_options
@with_source_options
def replay(
    *,
    ctx: typer.Context,
    data: LogArgument,
    truth: TruthOption = None,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot, --odom...)
    no_truth: NoTruthOption = False,
    report: ReportOption = None,
    as_json: JsonOption = False,
    noise: FilterNoise,
    odometry: Odometry,
    motion_noise: MotionNoiseOption = MotionNoiseChoice.AUTO,
    init_pose: InitPoseOption = None,
    gate: GateOption = None,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    form: FilterForm,
    filter_spec: FilterOption = BUILTIN,
    user: UserFilter,
    output: RerunOutput,
    association: Association,
    watch: WatchOption = False,
) -> None:
    """Replay a log through EKF-SLAM, record it for Rerun and print the evaluation.

    With no Rerun output option, the native viewer opens where a display exists;
    otherwise the recording is saved to recordings/<input name>.rrd. With --filter
    PATH.py --watch, the filter is checked against the reference on every save instead
    (as ekfviz watch does).
    """
    request = ReplayRequest(
        ctx=ctx, data=data, truth=truth, source_args=source_args, no_truth=no_truth,
        report=report, as_json=as_json, noise=noise, odometry=odometry,
        motion_noise=motion_noise, init_pose=init_pose, gate=gate,
        init_pose_sigma=init_pose_sigma, form=form, filter_spec=filter_spec, user=user,
        output=output, association=association,
    )  # fmt: skip
    if watch:
        from ekfviz.cli.watch import watch_replay

        watch_replay(request)
    else:
        run_replay(request)
