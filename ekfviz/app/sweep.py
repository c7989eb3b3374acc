"""``sweep``: one log replayed with the filter's parameters varied around a baseline, side
by side in one recording (see :mod:`ekfviz.app.study`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

from ekfviz.app.reporting import Reporter
from ekfviz.app.settings import WorkerOptions
from ekfviz.app.study import StudyOutcome, StudyPlan, StudyRequest, opened_study, run_study
from ekfviz.core.params import FilterParams
from ekfviz.filters.spec import BUILTIN, FilterSpec
from ekfviz.studies.runs import RunSpec
from ekfviz.studies.sweep import SweepError, build_variants, parse_vary, tuning_preset


class Preset(str, enum.Enum):
    """A named set of variants: ``tuning``, each noise sigma x10 and /10, one at a time."""

    TUNING = "tuning"


@dataclass(frozen=True, slots=True)
class SweepRequest:
    """A sweep as asked: the study, the variants (``--vary NAME=V1,V2,...`` as a grid, or
    each on its own with ``one_at_a_time``; or a preset), the filter and how it runs."""

    study: StudyRequest
    vary: tuple[str, ...] = ()
    one_at_a_time: bool = False
    preset: Preset | None = None
    filter_spec: str = BUILTIN
    worker: WorkerOptions | None = None


def sweep(request: SweepRequest, reporter: Reporter) -> StudyOutcome:
    """Run every variant on the log, save the recording and the report.

    :raises Interrupted: SIGINT or SIGTERM, saying how many runs were done
    :raises InputError, UsageError, OutputError, FilterError: one line each
    """
    study = request.study
    start, pairing = opened_study(study, reporter)
    baseline = start.params
    spec = FilterSpec(request.filter_spec, worker=request.worker or WorkerOptions())
    variants = [
        replace(variant, filter=spec, association=pairing)
        for variant in _variants(baseline, request)
    ]
    plan = StudyPlan(
        specs=variants, root="variants",
        parameters={
            "baseline": baseline.as_dict(), "filter": request.filter_spec,
            "variants": [variant.label for variant in variants],
        },
        report_extra={"baseline": baseline.as_dict()}, executor=study.execution.make(),
        own_truth=start.own_truth, notes=start.notes, inputs=start.files,
    )  # fmt: skip
    return run_study(study, plan, reporter)


def _variants(baseline: FilterParams, request: SweepRequest) -> list[RunSpec]:
    """The variants asked for by the preset or ``vary``.

    :raises SweepError: neither or both, a ``vary`` that does not read
    """
    if request.preset is Preset.TUNING:
        if request.vary:
            raise SweepError("--preset tuning and --vary: give one or the other")
        return tuning_preset(baseline)
    if request.vary:
        changes = [parse_vary(text) for text in request.vary]
        return build_variants(baseline, changes, one_at_a_time=request.one_at_a_time)
    raise SweepError("nothing to vary: give --vary NAME=VALUES or --preset tuning")
