"""One run composed: events through a filter (and an association) to its consumers.

Every command that replays is a configuration of :func:`run`:

============  ==========================================================================
command       consumers of the records
============  ==========================================================================
replay        the recorder (Rerun), the consistency counts, the association's tally or
              the GPS reference fit of a source that has one; the evaluation at the end
compare,      per filter: :class:`Kept` (the records, for the study's recording), the
sweep         consistency counts, the association's tally; the evaluation at the end
consistency   per trial: the NEES and NIS of every step (:mod:`ekfviz.studies.montecarlo`)
calibrate     per candidate: NEES and NIS after the fitted time, the consistency counts
check, grade  not a run: the checked filter event by event, the reference re-run from
              its state before each (:mod:`ekfviz.check.lockstep`)
============  ==========================================================================

A consumer is anything with ``add(record)``; :class:`~ekfviz.evaluation.consistency.
Consistency` and :class:`~ekfviz.association.evaluation.AssociationTally` are consumers as
they are. The filter is the built-in unless ``make_filter`` names another (see
:func:`~ekfviz.runner.replay.replay` for how a protocol filter is driven).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from ekfviz.core.records import AnyEvent, EventRecord
from ekfviz.runner.replay import replay

if TYPE_CHECKING:
    from ekfviz.association.associator import Associator
    from ekfviz.filters.ekf import EkfSlam, FilterParams
    from ekfviz.filters.plugged import FilterFactory


class Consumer(Protocol):
    """What takes a run's records, one at a time, in event order."""

    def add(self, record: EventRecord) -> object:
        """Take one record (what it returns is the consumer's own business)."""


@dataclass(slots=True)
class Kept:
    """A consumer that keeps every record (a study's runs are recorded after they end)."""

    records: list[EventRecord] = field(default_factory=list)

    def add(self, record: EventRecord) -> None:
        self.records.append(record)


def run(
    events: Iterable[AnyEvent],
    params: FilterParams | None,
    consumers: Sequence[Consumer],
    *,
    make_filter: FilterFactory | None = None,
    name: str = "ekf",
    slam: EkfSlam | None = None,
    associator: Associator | None = None,
) -> EventRecord | None:
    """Replay ``events`` and hand every record to each consumer in turn.

    :param slam: the built-in filter made with other models (Victoria Park's vehicle and
        laser), instead of one made from ``params``
    :param associator: pairs id-less scans with landmarks; None: the log's ids
    :returns: the last record (None only if the replay yielded nothing)
    :raises FilterLineError: the filter cannot go on at a line of the log; the consumers
        have every record before it
    """
    last = None
    for record in replay(
        events, params, make_filter=make_filter, name=name, slam=slam, associator=associator
    ):
        for consumer in consumers:
            consumer.add(record)
        last = record
    return last
