"""One replay from its events through the filter to its consumers: the recorder, the
consistency count, what the command watches (the filter's warnings) and the scans'
hooks (the association, the source's reference); and the line that says why and where
a replay cut short stopped.

:func:`consumers_of` is the one place that says who takes a replay's batches of events
(:class:`~ekfviz.core.batch.EventBatch`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from ekfviz import signals
from ekfviz.app.errors import RunStopped
from ekfviz.core.batch import EventBatch
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent, EventKind, EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import Consistency
from ekfviz.evaluation.errors import Evaluation, evaluate
from ekfviz.filters.plugged import FilterFactory
from ekfviz.runner.replay import FilterLineError
from ekfviz.runner.run import Consumer, run

if TYPE_CHECKING:
    from ekfviz.association.associator import Associator
    from ekfviz.filters.ekf import EkfSlam
    from ekfviz.viz.run import RunLogger


class ScanHooks(Protocol):
    """What a replay adds to the filter (see :mod:`ekfviz.app.scans`): the built-in
    filter with the models its source implies, the associator of id-less scans, a look
    at every batch of events (the association's tally, the source's reference) and the
    truth under the association's pairing."""

    @property
    def slam(self) -> EkfSlam | None: ...

    @property
    def associator(self) -> Associator | None: ...

    def add(self, events: EventBatch) -> None: ...

    def truth_of(self, last: EventRecord) -> GroundTruth | None: ...

    def finish(self, logger: RunLogger) -> object:
        """After the last batch, before the recording's layout is made: what the run
        adds to the recording (the source's reference, which the map then frames)."""
        ...


def stop_reason(
    cause: BaseException,
    data: Path,
    last: EventRecord | None,
    file_of: Callable[[bool], Path | None] | None = None,
) -> str:
    """One line saying why and where a replay stopped.

    :param file_of: the file of a motion's line number or an update's, where the input
        is a dataset directory of several (:meth:`~ekfviz.sources.Source.file_of`)
    """

    def where(motion: bool | None) -> Path:
        found = None if file_of is None or motion is None else file_of(motion)
        return data if found is None else found

    after = "at the start"
    if last is not None and last.line:
        path = where(last.kind is EventKind.PREDICT)
        after = f"after input line {last.line}" if path == data else (
            f"after line {last.line} of {path}")  # fmt: skip
    if isinstance(cause, KeyboardInterrupt):
        return f"{data}: interrupted (SIGINT) {after}"
    if isinstance(cause, signals.Terminated):
        return f"{data}: terminated (SIGTERM) {after}"
    if isinstance(cause, FilterLineError):
        return f"{where(cause.motion)}:{cause.line}: {cause}" if cause.line else f"{data}: {cause}"
    return str(cause)


def consumers_of(
    logger: RunLogger,
    consistency: Consistency,
    last: _Last,
    on_batch: Callable[[EventBatch], None] | None,
    scans: ScanHooks | None,
) -> list[Consumer]:
    """Who takes a replay's batches of events, in this order: the logger (Rerun), the
    consistency count, ``on_batch``, the last event's keeper and the scans' hooks."""
    consumers: list[Consumer] = [logger.log, consistency.add]
    if on_batch is not None:
        consumers.append(on_batch)
    consumers.append(last.add)
    if scans is not None:
        consumers.append(scans.add)
    return consumers


def replay_log(
    events: Iterable[AnyEvent],
    params: FilterParams,
    *,
    make_filter: FilterFactory | None,
    name: str,
    data: Path,
    truth: GroundTruth | None,
    logger: RunLogger,
    on_batch: Callable[[EventBatch], None] | None = None,
    scans: ScanHooks | None = None,
    file_of: Callable[[bool], Path | None] | None = None,
) -> Evaluation:
    """One replay: the events through the filter into the logger, judged at the end.

    Who takes what is :func:`consumers_of`'s. Bad input, a filter that cannot go on,
    Ctrl-C or SIGTERM stop the replay with the recording of everything before it kept
    and its last log line saying why.

    :param scans: the built-in filter with its source's models and the associator of
        id-less scans; the evaluation then sees the truth under the association's pairing
    :raises RunStopped: the replay was cut short (why, where, and whether it was kept)
    """
    consistency = Consistency(truth)
    last = _Last()
    consumers = consumers_of(logger, consistency, last, on_batch, scans)
    slam = None if scans is None else scans.slam
    associator = None if scans is None else scans.associator
    try:
        run(events, params, consumers, make_filter=make_filter, name=name, slam=slam,
            associator=associator)  # fmt: skip
    except (InputError, FilterLineError, KeyboardInterrupt, signals.Terminated) as cause:
        # where it stopped: the newest event the logger has, whole or in part
        last.record = logger.last or last.record
        if scans is not None and last.record is not None:
            truth = scans.truth_of(last.record)
        final = None if last.record is None else evaluate(last.record, truth, consistency)
        reason = stop_reason(cause, data, last.record, file_of)
        kept = logger.stop(reason, final)
        raise RunStopped(reason, cause, kept) from cause
    assert last.record is not None  # replay always yields the initialisation
    # a signal while the recording is finished is acted on once it is (and so kept)
    with signals.held():
        if scans is not None:
            truth = scans.truth_of(last.record)
            scans.finish(logger)  # before the layout: the map frames what it draws
        evaluation = evaluate(last.record, truth, consistency)
        logger.finish(evaluation)
    return evaluation


class _Last:
    """The last event so far; a signal that came during start-up stops the run at the
    initialisation (a batch of its own), with its recording."""

    def __init__(self) -> None:
        self.record: EventRecord | None = None

    def add(self, events: EventBatch) -> None:
        if len(events):
            self.record = events.last
            if self.record.event == 0:
                signals.raise_pending()
