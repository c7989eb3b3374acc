"""``ekfviz sweep``: one log replayed with filter parameters varied."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.inputs import SourceArgs
from ekfviz.app.settings import BUILTIN
from ekfviz.app.study import StudyRequest
from ekfviz.app.sweep import Preset, SweepRequest, sweep
from ekfviz.cli.console import TerminalReporter
from ekfviz.cli.options import (
    DEFAULT,
    Association,
    Execution,
    FilterForm,
    FilterNoise,
    FilterOption,
    InitPoseSigma,
    StudyLogArgument,
    SummaryReport,
    TruthOption,
    UserFilter,
    _option,
    expands_options,
    study_save,
)
from ekfviz.cli.program import app, command_line, given_options
from ekfviz.cli.sources import NO_SOURCE_ARGS, NoTruthOption, with_source_options
from ekfviz.cli.study import print_study

SweepSave = Annotated[Path | None, study_save("sweep")]
VaryOption = Annotated[
    list[str] | None,
    _option(
        "NAME=V1,V2,...: values absolute (0.5) or factors of the baseline (x10, /10);"
        " repeat to vary several.",
        metavar="NAME=VALUES",
        show_default=False,
    ),
]
OneAtATime = Annotated[
    bool,
    typer.Option(
        "--one-at-a-time",
        help="Vary each --vary on its own around the baseline, not as a grid.",
    ),
]
PresetOption = Annotated[
    Preset | None,
    _option(
        "tuning: each noise sigma x10 and /10, one at a time (11 variants).", show_default=False
    ),
]


@app.command(name="sweep")
@expands_options
@with_source_options
def sweep_command(
    *,
    ctx: typer.Context,
    data: StudyLogArgument,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot...)
    truth: TruthOption = None,
    no_truth: NoTruthOption = False,
    save: SweepSave = None,
    report: SummaryReport = None,
    vary: VaryOption = None,
    one_at_a_time: OneAtATime = False,
    preset: PresetOption = None,
    noise: FilterNoise,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    form: FilterForm,
    filter_spec: FilterOption = BUILTIN,
    user: UserFilter,
    execution: Execution,
    association: Association,
) -> None:
    """Replay one log with filter parameters varied around a baseline, side by side.

    Every variant lands in one recording under variants/<name>/ on shared timelines, so
    that scrubbing moves them all together; a table compares them.
    """
    study = StudyRequest(
        data=data, truth=truth, source_args=source_args, no_truth=no_truth, save=save,
        report=report, filter=form.values(noise, init_pose_sigma),
        execution=execution.values(), association=association.values(),
        given=given_options(ctx), command=command_line(),
    )  # fmt: skip
    request = SweepRequest(
        study, vary=tuple(vary or ()), one_at_a_time=one_at_a_time, preset=preset,
        filter_spec=filter_spec, worker=user.worker(),
    )  # fmt: skip
    print_study(sweep(request, TerminalReporter()))
