"""``ekfviz replay``: replay a log through a filter, record it, print the evaluation."""

from __future__ import annotations

import shlex
import sys
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from ekfviz import signals
from ekfviz.association import AssociationError
from ekfviz.cli.common import (
    DEFAULT,
    DEFAULT_FILTER_TIMEOUT_S,
    RECORDINGS_DIR,
    FilterMemory,
    FilterOption,
    FilterTimeout,
    FilterWarnings,
    InitPoseSigma,
    LandmarkInitOption,
    LogArgument,
    OdometryBias,
    OdometryScale,
    PythonOption,
    SigmaAlpha,
    SigmaBearing,
    SigmaRange,
    SigmaX,
    SigmaY,
    TruthOption,
    UpdateOption,
    app,
    check_outputs,
    fail,
    filter_params,
    human_output_to_stderr,
    mismatch_note,
    open_progress,
    out,
    print_evaluation,
    print_json,
    report_json,
    worker_options,
    write_json,
)
from ekfviz.cli.scans import (
    DEFAULT_ASSOCIATION,
    AssociationOption,
    Confirm,
    ConfirmWindow,
    GateProbability,
    replay_setup,
)
from ekfviz.cli.sources import (
    NO_SOURCE_ARGS,
    GateOption,
    InitPoseOption,
    MotionNoiseChoice,
    MotionNoiseOption,
    NoTruthOption,
    first_time,
    open_log,
    resolve,
    with_source_options,
)
from ekfviz.filters.ekf import EkfSlam, FilterError
from ekfviz.filters.spec import BUILTIN, FilterSpecError, load_filter
from ekfviz.io.errors import InputError
from ekfviz.sources import SourceArgs


@app.command()
@with_source_options
def replay(
    ctx: typer.Context,
    data: LogArgument,
    truth: TruthOption = None,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot, --odom...)
    no_truth: NoTruthOption = False,
    report: Annotated[
        Path | None, typer.Option(help="Write the evaluation as JSON here.", show_default=False)
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json", help="Print the evaluation as JSON on stdout (the rest goes to stderr)."
        ),
    ] = False,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    odometry_scale: OdometryScale = DEFAULT.odometry_scale,
    odometry_bias: OdometryBias = DEFAULT.odometry_bias,
    motion_noise: MotionNoiseOption = MotionNoiseChoice.AUTO,
    init_pose: InitPoseOption = None,
    gate: GateOption = None,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
    filter_spec: FilterOption = BUILTIN,
    python: PythonOption = None,
    filter_timeout: FilterTimeout = DEFAULT_FILTER_TIMEOUT_S,
    filter_memory: FilterMemory = None,
    save: Annotated[
        Path | None,
        typer.Option(
            help="Write the recording to this .rrd file.",
            show_default=False,
            rich_help_panel="Rerun output",
        ),
    ] = None,
    spawn: Annotated[
        bool,
        typer.Option(
            "--spawn", help="Open the native Rerun viewer.", rich_help_panel="Rerun output"
        ),
    ] = False,
    serve: Annotated[
        bool,
        typer.Option(
            "--serve",
            help="Serve the web viewer on localhost (see --bind) until Ctrl-C.",
            rich_help_panel="Rerun output",
        ),
    ] = False,
    bind: Annotated[
        str | None,
        typer.Option(
            help="With --serve: the IP address to listen on \\[default: 127.0.0.1, this"
            " machine only]; 0.0.0.0 serves the recording to the whole network.",
            show_default=False,
            metavar="ADDRESS",
            rich_help_panel="Rerun output",
        ),
    ] = None,
    connect: Annotated[
        str | None,
        typer.Option(
            help="Stream to a running viewer at this gRPC URL.",
            show_default=False,
            rich_help_panel="Rerun output",
        ),
    ] = None,
    association: AssociationOption = None,
    gate_probability: GateProbability = DEFAULT_ASSOCIATION.gate_probability,
    confirm: Confirm = DEFAULT_ASSOCIATION.confirm,
    confirm_window: ConfirmWindow = DEFAULT_ASSOCIATION.confirm_window,
    detail: Annotated[
        bool,
        typer.Option(
            "--detail",
            help="Log every landmark's ellipse at every update, even in a large map"
            " (by default a map of over 32 landmarks is logged whole every 25 steps).",
            rich_help_panel="Rerun output",
        ),
    ] = False,
    history: Annotated[
        bool,
        typer.Option(
            "--history",
            help="The classic figure: the map keeps every predicted (magenta) and updated"
            " (blue) robot ellipse up to the time cursor.",
            rich_help_panel="Rerun output",
        ),
    ] = False,
) -> None:
    """Replay a log through EKF-SLAM, record it for Rerun and print the evaluation.

    With no Rerun output option, the native viewer opens where a display exists;
    otherwise the recording is saved to recordings/<input name>.rrd.
    """
    from ekfviz import pipeline, viz  # rerun loads only for commands that record

    check_outputs(("--save", save), ("--report", report))
    if bind is not None:
        if not serve:
            fail("--bind is the address of --serve: add --serve")
        try:
            viz.check_bind(bind)
        except viz.SinkError as error:
            fail(str(error))
    if as_json:
        human_output_to_stderr()
    params = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range),
        init_pose_sigma,
        landmark_init,
        update,
        log=data,
    )
    if min(odometry_scale) <= 0:
        fail("--odometry-scale values must be positive")
    params = replace(params, odometry_scale=odometry_scale, odometry_bias=odometry_bias)
    try:
        worker = worker_options(python, filter_timeout, filter_memory)
        make_filter = load_filter(filter_spec, worker)
    except FilterSpecError as error:
        fail(str(error))
    logger: viz.RunLogger | None = None
    try:
        opened = open_log(data, source_args, truth, no_truth)
        truth_xy = opened.truth
        start, events = first_time(opened.events())
        params, notes = resolve(params, opened, start, init_pose, motion_noise, gate)
        for text in notes:
            out.print(text, soft_wrap=True)
        setup = replay_setup(
            ctx, opened, params, make_filter is None or make_filter is EkfSlam, truth_xy,
            association, gate_probability, confirm, confirm_window,
        )  # fmt: skip
        params = setup.params
        sinks, note = viz.resolve_default_sinks(
            viz.Sinks(
                save=save, spawn=spawn, serve=serve, connect=connect, bind=bind or viz.LOOPBACK
            ),
            data,
            RECORDINGS_DIR,
            name=opened.source.name,
        )
        info = viz.run_info(
            name=opened.source.name,
            command=shlex.join(["ekfviz", *sys.argv[1:]]),
            parameters={**params.as_dict(), "filter": filter_spec, **setup.parameters},
            input_path=data,
            truth=truth_xy,
            truth_path=opened.truth_files[0] if opened.truth_files else None,
            input_files=opened.source.files,
            truth_files=opened.truth_files,
        )
        with (
            open_progress(opened.source.progress_paths) as progress,
            viz.open_run(
                info,
                sinks,
                detail=detail,
                history=history,
                sensor=setup.sensor,
                gps_reference=setup.reference is not None,
            ) as logger,
            signals.as_exceptions(),
        ):
            warnings = FilterWarnings(data)
            if progress is not None:
                events = opened.events(progress)  # read from the start, with a bar
            evaluation = pipeline.replay_log(
                events, params, make_filter=make_filter, name=filter_spec, data=data,
                truth=truth_xy, logger=logger, on_record=warnings.add, scans=setup,
            )  # fmt: skip
            extra = setup.finish(logger)
            warnings.summarise()
            print_evaluation(evaluation, setup.truth_of_last())
            setup.print_summary(extra)
            document = {
                **report_json(evaluation, params, data, info.input_sha256),
                "filter": filter_spec,
                **extra,
            }
            if report is not None:
                write_json(report, document)
            if as_json:
                print_json(document)
            if truth_xy is not None:
                mismatch_note(params, truth_xy)
            if note:
                out.print(note)
            if logger.url:
                out.print(f"Serving the web viewer at [bold]{logger.url}[/] (Ctrl-C to stop)")
            logger.wait_while_serving()
    except pipeline.RunStopped as stopped:
        where = ""
        saved_to = None if logger is None else logger.recording.saved_to
        if stopped.kept and saved_to is not None:
            where = f"; the recording of everything before it is saved in {saved_to}"
            if saved_to != sinks.save:
                where += f" ({sinks.save} is left as it was)"
        elif sinks.save is not None and sinks.save.exists():
            where = f"; {sinks.save} is left as it was"
        fail(f"{stopped.reason}{where}", code=stopped.exit_code)
    except (InputError, FilterError, AssociationError, viz.SinkError) as error:
        fail(str(error))
    except (KeyboardInterrupt, signals.Terminated) as signal_error:  # outside the replay itself
        name = "SIGTERM" if isinstance(signal_error, signals.Terminated) else "SIGINT"
        saved_to = None if logger is None else logger.recording.saved_to
        kept = (
            f"the finished recording is saved in {saved_to}"
            if saved_to is not None
            else "nothing was written; existing files are left as they were"
        )
        fail(f"{data}: interrupted ({name}): {kept}", code=143 if name == "SIGTERM" else 130)
