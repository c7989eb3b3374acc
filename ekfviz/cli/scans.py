"""What ``replay`` needs beyond reading its source: the association options and the
associator of id-less scans, the filter with the models the source implies, the source's
reference and the association report."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.association import AssociationParams, Method
from ekfviz.association.evaluation import AssociationTally
from ekfviz.cli.common import _option, given, out, warn
from ekfviz.cli.sources import OpenedLog
from ekfviz.core.batch import EventBatch
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.filters.ekf import EkfSlam
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.sources import Reference, open_source

if TYPE_CHECKING:
    from ekfviz.association.associator import Associator
    from ekfviz.viz.run import RunLogger

ASSOCIATION_PANEL = "Association (id-less scans)"

AssociationOption = Annotated[
    Method | None,
    _option(
        "known: the log's ids; nn or jcbb for id-less scans"
        " [default: known for logs with ids, jcbb for logs with scans].",
        ASSOCIATION_PANEL,
        show_default=False,
    ),
]
GateProbability = Annotated[
    float,
    _option(
        "Probability of the chi-square gates (individual and joint).",
        ASSOCIATION_PANEL,
        min=0.5,
        max=0.999999,
    ),
]
Confirm = Annotated[
    int,
    _option(
        "Sightings (the first included) that confirm a new landmark.", ASSOCIATION_PANEL, min=1
    ),
]
ConfirmWindow = Annotated[
    int,
    _option("Scans from a new landmark's first in which to confirm it.", ASSOCIATION_PANEL, min=1),
]


def association_params(
    association: Method | None, gate_probability: float, confirm: int, confirm_window: int
) -> AssociationParams | None:
    """The association the options ask for: none for ``known``, else the method (jcbb
    by default) with its gate and confirmation."""
    if association is Method.KNOWN:
        return None
    return AssociationParams(
        method=Method.JCBB if association is None else association,
        gate_probability=gate_probability,
        confirm=confirm,
        confirm_window=confirm_window,
    )


def study_association(
    data: Path,
    association: Method | None,
    gate_probability: float,
    confirm: int,
    confirm_window: int,
) -> AssociationParams | None:
    """The association of a study's runs (sweep, compare), as a replay's: none for
    ``known``, else the method asked for (jcbb by default) for the log's id-less scans.
    A source that is replayed on its own (Victoria Park: its vehicle and sensor models
    are the replay's) is refused in one line.
    """
    try:
        refusal = open_source(data).study_refusal
    except InputError:
        refusal = None  # the study's own reading says what is wrong with it
    if refusal is not None:
        raise InputError(data, 0, refusal)
    return association_params(association, gate_probability, confirm, confirm_window)


DEFAULT_ASSOCIATION = AssociationParams()


@dataclass(slots=True)
class ReplaySetup:
    """One replay's filter (the built-in one, with the source's models), associator and
    reference; ``slam`` is None for a protocol filter (which cannot replay scans)."""

    data: Path
    params: FilterParams
    truth: GroundTruth | None
    slam: EkfSlam | None
    sensor: RangeBearing  # the sensor seen from the events' pose (the laser's, at Victoria Park)
    associator: Associator | None
    reference: Reference | None
    parameters: dict[str, object]
    tally: AssociationTally
    _scans: bool = False
    _last: EventBatch | None = None  # the last batch of the run's events
    _summaries: list[str] = field(default_factory=list)
    # what finish() found (the association's counts, the reference's results), by key
    extra: dict[str, object] = field(default_factory=dict)

    def add(self, events: EventBatch) -> None:
        if len(events):
            self._last = events
        scans = self.tally.scans
        self.tally.add_batch(events)
        self._scans |= self.tally.scans > scans
        if self.reference is not None:
            self.reference.add(events)

    def truth_of(self, last: EventRecord) -> GroundTruth | None:
        """The truth under the estimate's ids (the association's pairing for scans)."""
        if self.truth is None or not self._scans:
            return self.truth
        return self.tally.relabelled_truth(last.landmark_ids)

    def truth_of_last(self) -> GroundTruth | None:
        """The truth as the evaluation of the last record saw it."""
        return self.truth if self._last is None else self.truth_of(self._last.last)

    def finish(self, logger: RunLogger) -> dict[str, object]:
        """The association report and the source's reference, if any (logged too, before
        the recording's layout, which frames the reference in the map); kept in
        :attr:`extra`."""
        extra = self.extra
        if self._last is None:
            return extra
        last = self._last.last
        if self._scans:
            extra["association"] = self.tally.report(last.landmark_ids)
        if self.reference is not None:
            fitted = self.reference.fit(warn)
            if fitted is not None:
                from ekfviz.viz.association import log_reference

                recorder = logger.recorder
                log_reference(recorder._rec.rec, recorder._rec.path, fitted.fit, fitted.steps)
                # the map frames the GPS too, with room for a jump's label beside it
                fit = fitted.fit
                recorder.frame(fit.reference_xy[~fit.jumps])
                recorder.frame(fit.reference_xy[fit.jumps], label_room=0.12)
                extra[self.reference.key] = fitted.results
                self._summaries.append(fitted.summary)
        if extra:  # for ekfviz info
            logger.add_results(extra)
        return extra

    def print_summary(self, extra: dict[str, object]) -> None:
        association = extra.get("association")
        if isinstance(association, dict):
            text = ", ".join(f"{k} {_fmt(v)}" for k, v in association.items())
            out.print(f"Association: {text}", soft_wrap=True)
        for line in self._summaries:
            out.print(line, soft_wrap=True)


def _fmt(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def replay_setup(
    ctx: typer.Context,
    opened: OpenedLog,
    params: FilterParams,
    *,
    builtin: bool,
    assoc: AssociationParams | None,
) -> ReplaySetup:
    """The filter with the models the source implies, the associator and the reference.

    :param builtin: the run's filter is the built-in (a source may need it)
    :param assoc: the association of id-less scans (``--association`` and its settings)
    """
    data, truth = opened.source.path, opened.truth

    models = opened.source.models(params, lambda name: given(name, ctx))
    if models.builtin_only is not None and not builtin:
        raise InputError(data, 0, models.builtin_only)
    params = models.params
    parameters = dict(models.parameters)
    associator: Associator | None = None
    # only where it applies: a source whose observations all name their landmark has no
    # scans (nor is the association loaded for it, unless asked for)
    if assoc is not None and (not opened.source.ids_only or given("association")):
        from ekfviz.association.associator import Associator

        Associator.check_filter(models.slam, assoc)
        associator = Associator(
            assoc, models.sensor, params.R, scan_truth=None if truth is None else truth.scan_ids
        )
        parameters.update(assoc.as_dict())
    return ReplaySetup(
        data=data, params=params, truth=truth, slam=models.slam if builtin else None,
        sensor=models.recorded_sensor, associator=associator,
        reference=opened.source.reference(), parameters=parameters,
        tally=AssociationTally(truth, models.recorded_sensor),
    )  # fmt: skip
