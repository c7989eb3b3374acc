"""What a replay adds to the filter beyond its source's events: the built-in filter with
the models the source implies, the associator of id-less scans, the source's reference
(Victoria Park's GPS) and the association's report. :class:`ReplaySetup` is what
:func:`ekfviz.app.replaying.replay_log` takes as its :class:`~ekfviz.app.replaying.ScanHooks`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.app.inputs import OpenedLog
from ekfviz.app.settings import Given
from ekfviz.association import AssociationParams
from ekfviz.association.evaluation import AssociationTally
from ekfviz.core.batch import EventBatch
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.filters.ekf import EkfSlam
from ekfviz.io.text import WarningCallback
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.sources import Reference

if TYPE_CHECKING:
    from ekfviz.association.associator import Associator
    from ekfviz.viz.run import RunLogger


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
    warn: WarningCallback
    _scans: bool = False
    _last: EventBatch | None = None  # the last batch of the run's events
    # the summary lines of what finish() found (the reference's)
    summaries: list[str] = field(default_factory=list)
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
        """The truth as the evaluation of the last event saw it."""
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
            fitted = self.reference.fit(self.warn)
            if fitted is not None:
                logger.log_reference(fitted)
                extra[self.reference.key] = fitted.results
                self.summaries.append(fitted.summary)
        if extra:  # for ekfviz info
            logger.add_results(extra)
        return extra

    def summary_lines(self) -> list[str]:
        """The association's counts and the reference's summary, one line each."""
        lines = []
        association = self.extra.get("association")
        if isinstance(association, dict):
            text = ", ".join(f"{k} {_fmt(v)}" for k, v in association.items())
            lines.append(f"Association: {text}")
        return lines + self.summaries


def _fmt(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def replay_setup(
    opened: OpenedLog,
    params: FilterParams,
    *,
    builtin: bool,
    assoc: AssociationParams | None,
    given: Given,
    warn: WarningCallback,
) -> ReplaySetup:
    """The filter with the models the source implies, the associator and the reference.

    :param builtin: the run's filter is the built-in (a source may need it)
    :param assoc: the association of id-less scans (``--association`` and its settings)
    :param given: whether an option was given (the source's defaults replace the others)
    :raises InputError: a source that only the built-in filter replays, given another
    :raises UsageError: an association the filter cannot run
    """
    data, truth = opened.source.path, opened.truth
    models = opened.source.models(params, given)
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
        tally=AssociationTally(truth, models.recorded_sensor), warn=warn,
    )  # fmt: skip
