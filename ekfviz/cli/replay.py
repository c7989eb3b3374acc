"""``ekfviz replay``: replay a log through a filter, record it, print the evaluation."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.inputs import SourceArgs
from ekfviz.app.outputs import saved_line
from ekfviz.app.replay import RecordingOutput, ReplayRequest, ReplayResult, replay
from ekfviz.app.settings import BUILTIN
from ekfviz.cli.console import (
    TerminalReporter,
    fail,
    human_output_to_stderr,
    out,
    print_json,
    release_held,
    say,
    show,
)
from ekfviz.cli.options import (
    DEFAULT,
    RERUN_OUTPUT,
    Association,
    FilterForm,
    FilterNoise,
    FilterOption,
    InitPoseSigma,
    LogArgument,
    OdometryBias,
    OdometryScale,
    OptionGroup,
    RerunSinks,
    Triple,
    TruthOption,
    UserFilter,
    WatchOption,
    expands_options,
)
from ekfviz.cli.program import app, command_line, given_options
from ekfviz.cli.sources import (
    NO_SOURCE_ARGS,
    GateOption,
    InitPoseOption,
    MotionNoiseChoice,
    MotionNoiseOption,
    NoTruthOption,
    with_source_options,
)

ReportOption = Annotated[
    Path | None, typer.Option(help="Write the evaluation as JSON here.", show_default=False)
]
JsonOption = Annotated[
    bool,
    typer.Option(
        "--json", help="Print the evaluation as JSON on stdout (the rest goes to stderr)."
    ),
]


@dataclass(frozen=True, slots=True)
class Odometry(OptionGroup):
    """The systematic odometry errors taken out of every control."""

    odometry_scale: OdometryScale = DEFAULT.odometry_scale
    odometry_bias: OdometryBias = DEFAULT.odometry_bias


@dataclass(frozen=True, slots=True)
class RerunOutput(RerunSinks):
    """Where the recording goes and how much of it is logged."""

    detail: Annotated[
        bool,
        typer.Option(
            "--detail",
            help="Log every landmark's ellipse at every update, even in a large map"
            " (by default a map of over 32 landmarks is logged whole every 25 steps).",
            rich_help_panel=RERUN_OUTPUT,
        ),
    ] = False
    history: Annotated[
        bool,
        typer.Option(
            "--history",
            help="The classic figure: the map keeps every predicted (magenta) and updated"
            " (blue) robot ellipse up to the time cursor.",
            rich_help_panel=RERUN_OUTPUT,
        ),
    ] = False

    def values(self) -> RecordingOutput:
        return RecordingOutput(
            save=self.save, spawn=self.spawn, serve=self.serve, bind=self.bind,
            connect=self.connect, detail=self.detail, history=self.history,
        )  # fmt: skip


@app.command(name="replay")
@expands_options
@with_source_options
def replay_command(
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
    otherwise the recording is saved to recordings/<input name>.rrd. With --watch and
    --filter PATH.py: the filter checked again on every save (see ekfviz watch).
    """
    if watch:
        _watch(ctx, data, truth, source_args, no_truth, report, noise, init_pose,
               init_pose_sigma, form, filter_spec, user, output)  # fmt: skip
        return
    if as_json:  # stdout for the document; what is printed for people goes to stderr
        human_output_to_stderr()
    request = ReplayRequest(
        data=data, truth=truth, source_args=source_args, no_truth=no_truth, report=report,
        filter=form.values(noise, init_pose_sigma), odometry_scale=odometry.odometry_scale,
        odometry_bias=odometry.odometry_bias, motion_noise=motion_noise, init_pose=init_pose,
        gate=gate, filter_spec=filter_spec, worker=user.worker(), output=output.values(),
        association=association.values(), given=given_options(ctx), command=command_line(),
    )  # fmt: skip
    result = replay(request, TerminalReporter())
    try:
        _print(result, as_json)
        if result.served is not None:
            result.served.wait_until_interrupted()
    except KeyboardInterrupt:  # while the results were printed: the recording is whole
        kept = "nothing was written; existing files are left as they were"
        if result.saved_to is not None:
            kept = f"the finished recording is saved in {result.saved_to}"
        fail(f"{data}: interrupted (SIGINT): {kept}", code=130)
    finally:
        if result.served is not None:
            result.served.close()
    if result.sink_error is not None:
        fail(result.sink_error)


def _print(result: ReplayResult, as_json: bool) -> None:
    """The evaluation, the summaries and notes; the report with ``--json``."""
    release_held()  # the log is read whole: its warnings, before the results
    show(result.table)
    say(result.lines)
    for line in result.summaries:
        out.print(line, soft_wrap=True, markup=False)
    if as_json:
        print_json(result.report)
    say(result.notes)
    if result.saved_to is not None:
        out.print(saved_line(result.saved_to), soft_wrap=True, markup=False, highlight=False)
    if result.served is not None:
        out.print(f"Serving the web viewer at [bold]{result.served.url}[/] (Ctrl-C to stop)")


def _watch(
    ctx: typer.Context,
    data: Path,
    truth: Path | None,
    source_args: SourceArgs,
    no_truth: bool,
    report: Path | None,
    noise: FilterNoise,
    init_pose: Triple | None,
    init_pose_sigma: Triple,
    form: FilterForm,
    filter_spec: str,
    user: UserFilter,
    output: RerunOutput,
) -> None:
    """``replay --filter PATH.py --watch``: the watch of that filter on the replay's log,
    its recordings where the replay's would go."""
    from ekfviz.app.check import CheckRequest
    from ekfviz.cli.checking import refuse_replay_only, run_watch

    if filter_spec == BUILTIN:
        fail("--watch checks a filter of yours on every save: add --filter PATH.py")
    given = given_options(ctx)
    refuse_replay_only(given)
    request = CheckRequest(
        filter_text=filter_spec, data=data, truth=truth, source_args=source_args,
        no_truth=no_truth, report=report, save=output.save, worker=user.worker(),
        init_pose=init_pose, filter=form.values(noise, init_pose_sigma), given=given,
        command=command_line(),
    )  # fmt: skip
    run_watch(request, output)
