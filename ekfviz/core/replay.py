"""Drive the filter through a stream of log events and yield one record per event."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from itertools import chain
from typing import Any

from ekfviz.core.filter import EkfSlam, FilterError, FilterParams
from ekfviz.core.gating import gated
from ekfviz.core.health import check_covariance, check_interval
from ekfviz.core.records import (
    Control,
    EventKind,
    EventRecord,
    LogEvent,
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
    gate, R = ekf.params.gate, ekf.params.R
    next_check = 0  # the step from which the whole covariance is due for a check

    def checked(line: int, warnings: tuple[str, ...]) -> dict[str, Any]:
        """Check the whole covariance; its problems join the event's warnings."""
        nonlocal next_check
        check = check_covariance(ekf.P)
        next_check = step + check_interval(ekf.dim)
        if not check.finite:
            raise FilterLineError(line, check.problems()[0])
        return {"covariance": check, "warnings": warnings + tuple(check.problems())}

    step = 0
    stream = _with_last(events)
    first, last = next(stream, (None, True))
    extra: dict[str, Any]
    if isinstance(first, Sighting):
        try:
            observations = ekf.observe(first.ids, first.z)
        except FilterError as error:
            raise FilterLineError(first.line, str(error)) from error
        extra = checked(first.line, ekf.warnings)
        yield ekf.record(
            event=0, step=0, kind=EventKind.INIT, line=first.line, time=first.time,
            observations=observations, full_cov=full_cov, **extra,
        )  # fmt: skip
        pending: list[tuple[LogEvent, bool]] = []
    else:
        extra = checked(0, ())
        # the prior holds when the log's first event begins, when it has a time
        start = None if first is None else first.time
        if isinstance(first, Control) and start is not None and first.dt is not None:
            start -= first.dt
        yield ekf.record(
            event=0, step=0, kind=EventKind.INIT, time=start, full_cov=full_cov, **extra
        )
        pending = [] if first is None else [(first, last)]

    step_has_update = True  # the initialisation counts as step 0's update
    no_extra: dict[str, Any] = {}
    for event, (log_event, last) in enumerate(chain(pending, stream), start=1):
        # the filter's own errors name the line; "try" costs nothing until one is raised
        try:
            if isinstance(log_event, Control):
                step += 1
                step_has_update = False
                ekf.predict(log_event.d, log_event.alpha, log_event.dt)
                extra = checked(log_event.line, ()) if step >= next_check or last else no_extra
                yield ekf.record(
                    event=event, step=step, kind=EventKind.PREDICT, line=log_event.line,
                    time=log_event.time, control=(log_event.d, log_event.alpha),
                    full_cov=full_cov, **extra,
                )  # fmt: skip
            else:
                if step_has_update:
                    step += 1
                step_has_update = True
                rejected: tuple[str, ...] = ()
                if gate is not None:
                    log_event, rejected = gated(ekf.x, ekf.P, ekf.landmark_ids, log_event, R, gate)
                observations = ekf.observe(log_event.ids, log_event.z)
                warnings = rejected + ekf.warnings
                extra = (
                    checked(log_event.line, warnings)
                    if step >= next_check or last or warnings
                    else no_extra
                )
                yield ekf.record(
                    event=event, step=step, kind=EventKind.UPDATE, line=log_event.line,
                    time=log_event.time, observations=observations, full_cov=full_cov,
                    **extra,
                )  # fmt: skip
        except FilterLineError:
            raise
        except FilterError as error:
            raise FilterLineError(log_event.line, str(error)) from error


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
