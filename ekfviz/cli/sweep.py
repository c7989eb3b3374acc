"""``ekfviz sweep``: one log replayed with filter parameters varied."""

from __future__ import annotations

import enum
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.cli.common import DEFAULT, _option, app, fail
from ekfviz.cli.options import (
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
    expands_options,
    study_save,
)
from ekfviz.cli.sources import NO_SOURCE_ARGS, NoTruthOption, study_input, with_source_options
from ekfviz.cli.study import run_study
from ekfviz.core.errors import InputError
from ekfviz.filters.spec import BUILTIN, FilterSpec
from ekfviz.sources import SourceArgs

if TYPE_CHECKING:
    from ekfviz.core.params import FilterParams
    from ekfviz.studies.runs import RunSpec


class Preset(str, enum.Enum):
    TUNING = "tuning"


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


@app.command()
@expands_options
@with_source_options
def sweep(
    *,
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
    start = study_input(form.params(noise, init_pose_sigma, log=data), data, source_args, truth,
                        no_truth)  # fmt: skip
    baseline = start.params
    try:
        pairing = association.for_study(data)
    except InputError as error:
        fail(str(error))
    variants = _variants(baseline, vary, one_at_a_time=one_at_a_time, preset=preset)
    spec = FilterSpec(filter_spec, worker=user.worker())
    variants = [replace(variant, filter=spec, association=pairing) for variant in variants]
    run_study(
        data, truth, variants, target=save, report=report, workers=execution.workers,
        root="variants",
        parameters={
            "baseline": baseline.as_dict(), "filter": filter_spec,
            "variants": [variant.label for variant in variants],
        },
        report_extra={"baseline": baseline.as_dict()}, executor=execution.make(),
        source_args=source_args, own_truth=start.own_truth, notes=start.notes,
        inputs=start.files,
    )  # fmt: skip


def _variants(
    baseline: FilterParams, vary: list[str] | None, *, one_at_a_time: bool, preset: Preset | None
) -> list[RunSpec]:
    """The variants asked for by --preset or --vary, or a one-line error."""
    from ekfviz.studies.sweep import SweepError, build_variants, parse_vary, tuning_preset

    try:
        if preset is Preset.TUNING:
            if vary:
                raise SweepError("--preset tuning and --vary: give one or the other")
            return tuning_preset(baseline)
        if vary:
            return build_variants(
                baseline, [parse_vary(text) for text in vary], one_at_a_time=one_at_a_time
            )
        raise SweepError("nothing to vary: give --vary NAME=VALUES or --preset tuning")
    except SweepError as error:
        fail(str(error))
