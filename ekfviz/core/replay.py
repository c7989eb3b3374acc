"""Drive the filter through a stream of log events and yield one record per event."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from itertools import chain

import numpy as np

from ekfviz.core.filter import EkfSlam, FilterError, FilterParams
from ekfviz.core.records import Control, EventKind, EventRecord, LogEvent, Sighting


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

    :param full_cov: also keep the full (3+2N)^2 covariance in every record
    """
    ekf = EkfSlam(params)
    stream = iter(events)
    first = next(stream, None)
    pending: list[LogEvent] = []
    if isinstance(first, Sighting):
        with _at_line(first.line):
            observations = ekf.observe(first.ids, first.z)
        yield ekf.record(
            event=0,
            step=0,
            kind=EventKind.INIT,
            line=first.line,
            time=first.time,
            observations=observations,
            full_cov=full_cov,
        )
    else:
        yield ekf.record(event=0, step=0, kind=EventKind.INIT, full_cov=full_cov)
        if first is not None:
            pending.append(first)

    step = 0
    step_has_update = True  # the initialisation counts as step 0's update
    for event, log_event in enumerate(chain(pending, stream), start=1):
        if isinstance(log_event, Control):
            step += 1
            step_has_update = False
            with _at_line(log_event.line):
                ekf.predict(log_event.d, log_event.alpha)
            yield ekf.record(
                event=event,
                step=step,
                kind=EventKind.PREDICT,
                line=log_event.line,
                time=log_event.time,
                control=np.array([log_event.d, log_event.alpha]),
                full_cov=full_cov,
            )
        else:
            if step_has_update:
                step += 1
            step_has_update = True
            with _at_line(log_event.line):
                observations = ekf.observe(log_event.ids, log_event.z)
            yield ekf.record(
                event=event,
                step=step,
                kind=EventKind.UPDATE,
                line=log_event.line,
                time=log_event.time,
                observations=observations,
                full_cov=full_cov,
            )


@contextmanager
def _at_line(line: int) -> Iterator[None]:
    """Name the log line in a filter error raised inside the block."""
    try:
        yield
    except FilterError as error:
        raise FilterLineError(line, str(error)) from error
