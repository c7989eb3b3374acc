"""``ekfviz compare``: several filters on one log, side by side in one recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import (
    DEFAULT,
    DEFAULT_FILTER_TIMEOUT_S,
    ExecutorOption,
    FilterMemory,
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
from ekfviz.filters.spec import FilterSpec
from ekfviz.io.errors import InputError
from ekfviz.studies.executors import ExecutorName


@app.command()
def compare(
    data: StudyLogArgument,
    filters: Annotated[
        list[str],
        typer.Option(
            "--filter",
            help="A filter to compare (ekf, a registered backend, PATH.py (a course module),"
            " PATH.py:ClassName, package.module:ClassName, any as LABEL=SPEC); repeat for"
            " each, the first is the baseline.",
            show_default=False,
        ),
    ],
    labels: Annotated[
        list[str] | None,
        typer.Option(
            "--label",
            help="A name for each --filter, in order (repeat; fewer labels than filters"
            " leave the rest named by their file or class).",
            show_default=False,
        ),
    ] = None,
    python: PythonOption = None,
    filter_timeout: FilterTimeout = DEFAULT_FILTER_TIMEOUT_S,
    filter_memory: FilterMemory = None,
    truth: TruthOption = None,
    save: Annotated[
        Path | None,
        _option(
            "Write the recording here \\[default: recordings/<input>-compare.rrd].",
            show_default=False,
        ),
    ] = None,
    report: Annotated[
        Path | None, _option("Write the summary as JSON here.", show_default=False)
    ] = None,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
    workers: Workers = None,
    executor: ExecutorOption = ExecutorName.LOCAL,
    scheduler: SchedulerOption = None,
    association: AssociationOption = None,
    gate_probability: GateProbability = DEFAULT_ASSOCIATION.gate_probability,
    confirm: Confirm = DEFAULT_ASSOCIATION.confirm,
    confirm_window: ConfirmWindow = DEFAULT_ASSOCIATION.confirm_window,
) -> None:
    """Replay one log with several filters, each under filters/<name>/ in one recording.

    The filters share the step and event timelines, so that scrubbing moves them all
    together; a grid of maps sits above overlaid NIS (and NEES, landmark error) plots,
    and a table compares them, the first filter being the baseline.
    """
    from ekfviz.studies.runs import RunSpec

    params = filter_params(
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
    specs: list[RunSpec] = []
    keys: set[str] = set()
    given = list(labels or [])
    if len(given) > len(filters):
        fail(f"{len(given)} --label for {len(filters)} --filter: give at most one label a filter")
    worker = worker_options(python, filter_timeout, filter_memory)
    parsed = [
        FilterSpec.parse(text, given[index] if index < len(given) else None, worker)
        for index, text in enumerate(filters)
    ]
    for spec in _by_folder(parsed):
        key = spec.key
        for count in range(2, len(filters) + 2):  # the same filter twice: ekf, ekf-2
            if key not in keys:
                break
            key = f"{spec.key}-{count}"
        keys.add(key)
        label = spec.label if spec.name else key
        specs.append(RunSpec(label=label, key=key, params=params, filter=spec, association=pairing))
    if not specs:
        fail("give at least one --filter")
    run_study(
        data,
        truth,
        specs,
        target=save,
        report=report,
        workers=workers,
        root="filters",
        parameters={"filters": filters, "parameters": params.as_dict()},
        report_extra={"parameters": params.as_dict()},
        executor=study_executor(executor, scheduler, workers),
        keep_going=True,
    )


def _by_folder(specs: list[FilterSpec]) -> list[FilterSpec]:
    """The specs, files of one name in several folders (every student's ``ekf_slam.py``)
    labelled ``FOLDER/NAME`` unless given a label."""
    from collections import Counter
    from dataclasses import replace

    counts = Counter(spec.label for spec in specs)
    folders: dict[str, set[str]] = {}
    for spec in specs:
        folders.setdefault(spec.label, set()).add(str(Path(spec.text.partition(":")[0]).parent))
    return [
        replace(spec, name=f"{Path(spec.text.partition(':')[0]).parent.name}/{spec.label}")
        if spec.name is None
        and counts[spec.label] > 1
        and len(folders[spec.label]) > 1
        and not spec.in_process
        else spec
        for spec in specs
    ]
