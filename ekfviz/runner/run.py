"""One run composed: events through a filter (and an association) to its consumers.

Every command that replays is a configuration of :func:`run`:

============  ==========================================================================
command       consumers of the batches
============  ==========================================================================
replay        the recorder (Rerun), the consistency counts, the association's tally or
              the GPS reference fit of a source that has one; the evaluation at the end
compare,      per filter: the batches kept (for the study's recording), the
sweep         consistency counts, the association's tally; the evaluation at the end
consistency   per trial: the NEES and NIS of every step (:mod:`ekfviz.studies.montecarlo`)
calibrate     per candidate: NEES and NIS after the fitted time, the consistency counts
check, grade  not a run: the checked filter event by event, the reference re-run from
              its state before each (:mod:`ekfviz.check.lockstep`)
============  ==========================================================================

A consumer is a function called with every batch (:class:`~ekfviz.core.batch.EventBatch`),
in event order: a bound ``add`` of
:class:`~ekfviz.evaluation.consistency.Consistency` or
:class:`~ekfviz.association.evaluation.AssociationTally`, a list's ``append``, the
recorder's ``log``. The filter is the built-in unless ``make_filter`` names another
(see :func:`~ekfviz.runner.replay.replay` for how a protocol filter is driven).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

from ekfviz.core.batch import EventBatch
from ekfviz.core.records import AnyEvent, EventRecord
from ekfviz.runner.replay import replay

if TYPE_CHECKING:
    from ekfviz.association.associator import Associator
    from ekfviz.core.params import FilterParams
    from ekfviz.filters.ekf import EkfSlam
    from ekfviz.filters.plugged import FilterFactory


# what takes a run's batches, one at a time (what it returns is its own business)
Consumer = Callable[[EventBatch], object]


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
    """Replay ``events`` and call each consumer with every batch, in turn.

    :param slam: the built-in filter made with other models (Victoria Park's vehicle and
        laser), instead of one made from ``params``
    :param associator: pairs id-less scans with landmarks; None: the log's ids
    :returns: the view of the last event (None only if the replay yielded nothing)
    :raises FilterLineError: the filter cannot go on at a line of the log; the consumers
        have every batch before it
    """
    last = None
    for batch in replay(
        events, params, make_filter=make_filter, name=name, slam=slam, associator=associator
    ):
        for consumer in consumers:
            consumer(batch)
        last = batch
    return None if last is None else last.last


def every_event(batches: Iterable[EventBatch]) -> list[EventRecord]:
    """Every event of ``batches`` viewed as a record, in order: for a reader of a few
    events one at a time (a test, a short log)."""
    return [record for batch in batches for record in batch]
