"""``ekfviz compare``: several filters on one log, side by side in one recording."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.cli.common import DEFAULT, app, fail
from ekfviz.cli.options import (
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
from ekfviz.cli.sources import NO_SOURCE_ARGS, NoTruthOption, study_input, with_source_options
from ekfviz.cli.study import run_study
from ekfviz.core.errors import InputError
from ekfviz.filters.spec import FilterSpec
from ekfviz.sources import SourceArgs

if TYPE_CHECKING:
    from ekfviz.association import AssociationParams
    from ekfviz.core.params import FilterParams
    from ekfviz.studies.runs import RunSpec


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


@app.command()
@expands_options
@with_source_options
def compare(
    *,
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
    given = form.params(noise, init_pose_sigma, log=data)
    start = study_input(given, data, source_args, truth, no_truth)
    params = start.params
    try:
        pairing = association.for_study(data)
    except InputError as error:
        fail(str(error))
    run_study(
        data, truth, _specs(filters, labels, user, params, pairing), target=save, report=report,
        workers=execution.workers, root="filters",
        parameters={"filters": filters, "parameters": params.as_dict()},
        report_extra={"parameters": params.as_dict()}, executor=execution.make(),
        keep_going=True, source_args=source_args, own_truth=start.own_truth, notes=start.notes,
        inputs=start.files,
    )  # fmt: skip


def _specs(
    filters: list[str],
    labels: list[str] | None,
    user: UserFilter,
    params: FilterParams,
    pairing: AssociationParams | None,
) -> list[RunSpec]:
    """One run a filter, labelled (given labels first) and keyed apart (ekf, ekf-2)."""
    from ekfviz.studies.runs import RunSpec

    specs: list[RunSpec] = []
    keys: set[str] = set()
    given = list(labels or [])
    if len(given) > len(filters):
        fail(f"{len(given)} --label for {len(filters)} --filter: give at most one label a filter")
    twice = next((label for k, label in enumerate(given) if label in given[:k]), None)
    if twice is not None:  # two rows of one name: the table and the report could not tell
        fail(f"--label {twice} given twice: give each filter a name of its own")
    worker = user.worker()
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
    return specs


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
