"""One replay from its events through the filter to its consumers: the recorder, the
consistency count, what the command watches (the filter's warnings) and the scans'
hooks (the association, the source's reference); and the line that says why and where
a replay cut short stopped.

:func:`consumers_of` is the one place that says which consumer takes what: every record,
or the plain predicts and updates as columns (:class:`~ekfviz.core.records.EventRows`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from ekfviz import signals
from ekfviz.app.errors import RunStopped
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent, EventKind, EventRecord, EventRows
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
    at every record (the source's reference) and the truth under the association's
    pairing."""

    @property
    def slam(self) -> EkfSlam | None: ...

    @property
    def associator(self) -> Associator | None: ...

    @property
    def reads_predicts(self) -> bool: ...

    def add(self, record: EventRecord) -> None: ...

    def truth_of(self, last: EventRecord) -> GroundTruth | None: ...

    def finish(self, logger: RunLogger) -> object:
        """After the last record, before the recording's layout is made: what the run
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
    on_record: Callable[[EventRecord], None] | None,
    scans: ScanHooks | None,
) -> tuple[list[Consumer], EventRows | None]:
    """Who takes what of a replay: every record goes to the logger (Rerun), the
    consistency count, ``on_record``, the last record's keeper and the scans' hooks; the
    plain predicts and updates (by ids, no warning, no check) go to the logger as
    columns, their NIS and NEES to the consistency count (the returned rows), and not
    to ``on_record``."""
    consumers: list[Consumer] = [logger.log, consistency.add]
    if on_record is not None:
        consumers.append(on_record)
    consumers.append(last.add)
    if scans is not None:
        consumers.append(scans.add)
    # the plain predicts go to the recorder as columns (no other consumer reads a
    # predict's record) unless the hooks read them (a source's reference)
    rows = logger.event_rows() if scans is None or not scans.reads_predicts else None
    if rows is not None:
        # its plain updates too: only the recorder and the consistency count read them.
        # An update that the association decided (a scan) stays a record, for the
        # association's tally and view; an update by ids beside an associator (an
        # extended log that could have scans but has none here) is as plain as any
        rows.takes_updates = True
        rows.watch = consistency.add_rows
    return consumers, rows


def replay_log(
    events: Iterable[AnyEvent],
    params: FilterParams,
    *,
    make_filter: FilterFactory | None,
    name: str,
    data: Path,
    truth: GroundTruth | None,
    logger: RunLogger,
    on_record: Callable[[EventRecord], None] | None = None,
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
    consumers, rows = consumers_of(logger, consistency, last, on_record, scans)
    slam = None if scans is None else scans.slam
    associator = None if scans is None else scans.associator
    try:
        run(events, params, consumers, make_filter=make_filter, name=name, slam=slam,
            associator=associator, event_rows=rows)  # fmt: skip
    except (InputError, FilterLineError, KeyboardInterrupt, signals.Terminated) as cause:
        if rows is not None:  # where it stopped: maybe an event written as a row
            last.record = rows.latest(last.record)
            rows.settle()
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
        if rows is not None:  # the NIS and NEES of the rows not sent yet
            rows.settle()
        evaluation = evaluate(last.record, truth, consistency)
        logger.finish(evaluation)
    return evaluation


class _Last:
    """The last record so far; a signal that came during start-up stops the run at the
    initialisation, with its recording."""

    def __init__(self) -> None:
        self.record: EventRecord | None = None

    def add(self, record: EventRecord) -> None:
        self.record = record
        if record.event == 0:
            signals.raise_pending()
