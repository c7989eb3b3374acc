"""``ekfviz compare``: several filters on one log, side by side in one recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.compare import CompareRequest, compare
from ekfviz.app.inputs import SourceArgs
from ekfviz.app.study import StudyRequest
from ekfviz.cli.console import TerminalReporter
from ekfviz.cli.options import (
    DEFAULT,
    Association,
    Execution,
    FilterForm,
    FilterNoise,
    InitPoseSigma,
    StudyLogArgument,
    SummaryReport,
    TruthOption,
    UserFilter,
    expands_options,
    study_save,
)
from ekfviz.cli.program import app, command_line, given_options
from ekfviz.cli.sources import NO_SOURCE_ARGS, NoTruthOption, with_source_options
from ekfviz.cli.study import print_study

FiltersOption = Annotated[
    list[str],
    typer.Option(
        "--filter",
        help="A filter to compare (ekf, a registered backend, PATH.py (a course module),"
        " PATH.py:ClassName, package.module:ClassName, any as LABEL=SPEC); repeat for"
        " each, the first is the baseline.",
        show_default=False,
    ),
]
LabelsOption = Annotated[
    list[str] | None,
    typer.Option(
        "--label",
        help="A name for each --filter, in order (repeat; fewer labels than filters"
        " leave the rest named by their file or class).",
        show_default=False,
    ),
]
CompareSave = Annotated[Path | None, study_save("compare")]


@app.command(name="compare")
@expands_options
@with_source_options
def compare_command(
    *,
    ctx: typer.Context,
    data: StudyLogArgument,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot...)
    filters: FiltersOption,
    labels: LabelsOption = None,
    user: UserFilter,
    truth: TruthOption = None,
    no_truth: NoTruthOption = False,
    save: CompareSave = None,
    report: SummaryReport = None,
    noise: FilterNoise,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    form: FilterForm,
    execution: Execution,
    association: Association,
) -> None:
    """Replay one log with several filters, each under filters/<name>/ in one recording.

    The filters share the step and event timelines, so that scrubbing moves them all
    together; a grid of maps sits above overlaid NIS (and NEES, landmark error) plots,
    and a table compares them, the first filter being the baseline.
    """
    study = StudyRequest(
        data=data, truth=truth, source_args=source_args, no_truth=no_truth, save=save,
        report=report, filter=form.values(noise, init_pose_sigma),
        execution=execution.values(), association=association.values(),
        given=given_options(ctx), command=command_line(),
    )  # fmt: skip
    request = CompareRequest(study, tuple(filters), tuple(labels or ()), user.worker())
    print_study(compare(request, TerminalReporter()))
