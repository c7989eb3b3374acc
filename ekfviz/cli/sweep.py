"""``ekfviz sweep``: one log replayed with filter parameters varied."""

from __future__ import annotations

import enum
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import (
    DEFAULT,
    DEFAULT_FILTER_TIMEOUT_S,
    ExecutorOption,
    FilterMemory,
    FilterOption,
    FilterTimeout,
    InitPoseSigma,
    LandmarkInitOption,
    PythonOption,
    SchedulerOption,
    SigmaAlpha,
    SigmaBearing,
    SigmaRange,
    SigmaX,
    SigmaY,
    StudyLogArgument,
    TruthOption,
    UpdateOption,
    Workers,
    _option,
    app,
    fail,
    filter_params,
    study_executor,
    worker_options,
)
from ekfviz.cli.scans import (
    DEFAULT_ASSOCIATION,
    AssociationOption,
    Confirm,
    ConfirmWindow,
    GateProbability,
    study_association,
)
from ekfviz.cli.study import run_study
from ekfviz.filters.spec import BUILTIN, FilterSpec
from ekfviz.io.errors import InputError
from ekfviz.studies.executors import ExecutorName


class Preset(str, enum.Enum):
    TUNING = "tuning"


@app.command()
def sweep(
    data: StudyLogArgument,
    truth: TruthOption = None,
    save: Annotated[
        Path | None,
        _option(
            "Write the recording here \\[default: recordings/<input>-sweep.rrd].",
            show_default=False,
        ),
    ] = None,
    report: Annotated[
        Path | None, _option("Write the summary as JSON here.", show_default=False)
    ] = None,
    vary: Annotated[
        list[str] | None,
        _option(
            "NAME=V1,V2,...: values absolute (0.5) or factors of the baseline (x10, /10);"
            " repeat to vary several.",
            metavar="NAME=VALUES",
            show_default=False,
        ),
    ] = None,
    one_at_a_time: Annotated[
        bool,
        typer.Option(
            "--one-at-a-time",
            help="Vary each --vary on its own around the baseline, not as a grid.",
        ),
    ] = False,
    preset: Annotated[
        Preset | None,
        _option(
            "tuning: each noise sigma x10 and /10, one at a time (11 variants).", show_default=False
        ),
    ] = None,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
    filter_spec: FilterOption = BUILTIN,
    python: PythonOption = None,
    filter_timeout: FilterTimeout = DEFAULT_FILTER_TIMEOUT_S,
    filter_memory: FilterMemory = None,
    workers: Workers = None,
    executor: ExecutorOption = ExecutorName.LOCAL,
    scheduler: SchedulerOption = None,
    association: AssociationOption = None,
    gate_probability: GateProbability = DEFAULT_ASSOCIATION.gate_probability,
    confirm: Confirm = DEFAULT_ASSOCIATION.confirm,
    confirm_window: ConfirmWindow = DEFAULT_ASSOCIATION.confirm_window,
) -> None:
    """Replay one log with filter parameters varied around a baseline, side by side.

    Every variant lands in one recording under variants/<name>/ on shared timelines, so
    that scrubbing moves them all together; a table compares them.
    """
    from ekfviz.studies.sweep import SweepError, build_variants, parse_vary, tuning_preset

    baseline = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range),
        init_pose_sigma,
        landmark_init,
        update,
        log=data,
    )
    try:
        pairing = study_association(data, association, gate_probability, confirm, confirm_window)
    except InputError as error:
        fail(str(error))
    try:
        if preset is Preset.TUNING:
            if vary:
                raise SweepError("--preset tuning and --vary: give one or the other")
            variants = tuning_preset(baseline)
        elif vary:
            variants = build_variants(
                baseline, [parse_vary(text) for text in vary], one_at_a_time=one_at_a_time
            )
        else:
            raise SweepError("nothing to vary: give --vary NAME=VALUES or --preset tuning")
    except SweepError as error:
        fail(str(error))
    spec = FilterSpec(filter_spec, worker=worker_options(python, filter_timeout, filter_memory))
    variants = [replace(variant, filter=spec, association=pairing) for variant in variants]
    runner = study_executor(executor, scheduler, workers)
    run_study(
        data,
        truth,
        variants,
        target=save,
        report=report,
        workers=workers,
        root="variants",
        parameters={
            "baseline": baseline.as_dict(),
            "filter": filter_spec,
            "variants": [variant.label for variant in variants],
        },
        report_extra={"baseline": baseline.as_dict()},
        executor=runner,
    )
