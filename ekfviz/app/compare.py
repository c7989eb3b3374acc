"""``compare``: several filters on one log, side by side in one recording (see
:mod:`ekfviz.app.study`), the first the baseline."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

from ekfviz.app.errors import in_family
from ekfviz.app.reporting import Reporter
from ekfviz.app.settings import WorkerOptions
from ekfviz.app.study import StudyOutcome, StudyPlan, StudyRequest, opened_study, run_study
from ekfviz.association import AssociationParams
from ekfviz.core.errors import UsageError
from ekfviz.core.params import FilterParams
from ekfviz.filters.spec import FilterSpec
from ekfviz.studies.runs import RunSpec


@dataclass(frozen=True, slots=True)
class CompareRequest:
    """A comparison as asked: the study, the filters (``LABEL=SPEC`` or ``SPEC``, the
    first the baseline), a label for the first few, how a user's filter runs."""

    study: StudyRequest
    filters: tuple[str, ...]
    labels: tuple[str, ...] = ()
    worker: WorkerOptions | None = None


def compare(request: CompareRequest, reporter: Reporter) -> StudyOutcome:
    """Run every filter on the log, save the recording and the report.

    :raises Interrupted: SIGINT or SIGTERM, saying how many runs were done
    :raises InputError, UsageError, OutputError, FilterError: one line each
    """
    study = request.study
    start, pairing = opened_study(study, reporter)
    params = start.params
    specs = _specs(request, params, pairing)
    plan = StudyPlan(
        specs=specs, root="filters",
        parameters={"filters": list(request.filters), "parameters": params.as_dict()},
        report_extra={"parameters": params.as_dict()}, executor=study.execution.make(),
        keep_going=True, own_truth=start.own_truth, notes=start.notes, inputs=start.files,
    )  # fmt: skip
    return run_study(study, plan, reporter)


def _specs(
    request: CompareRequest, params: FilterParams, pairing: AssociationParams | None
) -> list[RunSpec]:
    """One run a filter, labelled (given labels first) and keyed apart (ekf, ekf-2)."""
    filters, given = request.filters, list(request.labels)
    if len(given) > len(filters):
        raise UsageError(
            f"{len(given)} --label for {len(filters)} --filter: give at most one label a filter"
        )
    twice = next((label for k, label in enumerate(given) if label in given[:k]), None)
    if twice is not None:  # two rows of one name: the table and the report could not tell
        raise UsageError(f"--label {twice} given twice: give each filter a name of its own")
    with in_family():
        parsed = [
            FilterSpec.parse(text, given[index] if index < len(given) else None, request.worker)
            for index, text in enumerate(filters)
        ]
    specs: list[RunSpec] = []
    keys: set[str] = set()
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
        raise UsageError("give at least one --filter")
    return specs


def _by_folder(specs: list[FilterSpec]) -> list[FilterSpec]:
    """The specs, files of one name in several folders (every student's ``ekf_slam.py``)
    labelled ``FOLDER/NAME`` unless given a label."""
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
