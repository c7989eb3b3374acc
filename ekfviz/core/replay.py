"""Drive the filter through a stream of log events and yield one record per event."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from itertools import chain

import numpy as np

from ekfviz.core.filter import EkfSlam, FilterError, FilterParams
from ekfviz.core.health import check_covariance, check_interval
from ekfviz.core.records import (
    Control,
    EventKind,
    EventRecord,
    LogEvent,
    Observations,
    Sighting,
)


class FilterLineError(FilterError):
    """The filter could not go on at a line of the log.

    :param line: the log line whose event failed
    """

    def __init__(self, line: int, message: str) -> None:
        self.line = line
        super().__init__(message)


def replay(
    events: Iterable[LogEvent],
    params: FilterParams | None = None,
    *,
    full_cov: bool = False,
) -> Iterator[EventRecord]:
    """Run EKF-SLAM over ``events`` lazily, one record per event.

    Event 0 / step 0 is the initialisation: the prior pose, plus the landmarks of the
    log's first line when that line is an observation. Every control starts a new step
    with a predict; an observation is the update of the current step, or starts a step
    of its own when the step already had one (a replay does not rely on controls and
    observations alternating).

    The whole covariance is checked (:func:`~ekfviz.core.health.check_covariance`) at
    the first and the last event, every :func:`~ekfviz.core.health.check_interval`
    steps and wherever an observation was skipped; its problems join the record's
    warnings. An error of the event stream (bad input, an interrupt) is raised only
    after the record of the last good event, checked, has been yielded.

    :param full_cov: also keep the full (3+2N)^2 covariance in every record
    :raises FilterLineError: the filter cannot go on at a line (a non-finite state, ...)
    """
    ekf = EkfSlam(params)
    next_check = 0  # the step from which the covariance is due for a check
    step = 0

    def record(
        *,
        event: int,
        kind: EventKind,
        last: bool,
        log_event: LogEvent | None = None,
        observations: Observations | None = None,
    ) -> EventRecord:
        nonlocal next_check
        warnings = ekf.warnings if observations is not None else ()
        check = None
        if step >= next_check or last or warnings:
            check = check_covariance(ekf.P)
            next_check = step + check_interval(ekf.dim)
            if not check.finite:
                raise FilterLineError(
                    0 if log_event is None else log_event.line, check.problems()[0]
                )
            warnings += tuple(check.problems())
        return ekf.record(
            event=event,
            step=step,
            kind=kind,
            line=0 if log_event is None else log_event.line,
            time=None if log_event is None else log_event.time,
            control=(
                np.array([log_event.d, log_event.alpha]) if isinstance(log_event, Control) else None
            ),
            observations=observations,
            full_cov=full_cov,
            warnings=warnings,
            covariance=check,
        )

    stream = _with_last(events)
    first, first_is_last = next(stream, (None, True))
    pending: list[tuple[LogEvent, bool]] = []
    if isinstance(first, Sighting):
        with _at_line(first.line):
            observations = ekf.observe(first.ids, first.z)
        yield record(
            event=0, kind=EventKind.INIT, last=first_is_last, log_event=first,
            observations=observations,
        )  # fmt: skip
    else:
        yield record(event=0, kind=EventKind.INIT, last=first is None)
        if first is not None:
            pending.append((first, first_is_last))

    step_has_update = True  # the initialisation counts as step 0's update
    for event, (log_event, last) in enumerate(chain(pending, stream), start=1):
        if isinstance(log_event, Control):
            step += 1
            step_has_update = False
            with _at_line(log_event.line):
                ekf.predict(log_event.d, log_event.alpha)
            yield record(event=event, kind=EventKind.PREDICT, last=last, log_event=log_event)
        else:
            if step_has_update:
                step += 1
            step_has_update = True
            with _at_line(log_event.line):
                observations = ekf.observe(log_event.ids, log_event.z)
            yield record(
                event=event, kind=EventKind.UPDATE, last=last, log_event=log_event,
                observations=observations,
            )  # fmt: skip


def _with_last(events: Iterable[LogEvent]) -> Iterator[tuple[LogEvent, bool]]:
    """Each event with whether it is the last one, reading one event ahead.

    An error of the stream while reading ahead (bad input, an interrupt) is raised
    after the event before it has been handed on as the last.
    """
    stream = iter(events)
    try:
        current = next(stream)
    except StopIteration:
        return
    while True:
        try:
            following = next(stream)
        except StopIteration:
            yield current, True
            return
        except BaseException:
            yield current, True
            raise
        yield current, False
        current = following


@contextmanager
def _at_line(line: int) -> Iterator[None]:
    """Name the log line in a filter error raised inside the block."""
    try:
        yield
    except FilterError as error:
        raise FilterLineError(line, str(error)) from error
