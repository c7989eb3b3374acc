"""Drive the filter through a stream of log events and emit its states in batches.

The event loop (:func:`replay`) reads the log one event ahead, numbers each event
(:class:`~ekfviz.core.steps.StepCounter`), moves or corrects the filter and appends its
state to the batch being built (:class:`Events`), which checks the whole covariance
where due (:mod:`ekfviz.runner.checks`) and hands sealed batches on in order
(:mod:`ekfviz.runner.batches`). What an observation line does lives in
:mod:`ekfviz.runner.observe`; how a failure is named by its line, in
:mod:`ekfviz.runner.errors`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from itertools import chain
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.core.batch import INIT, PREDICT, UPDATE, EventBatch, Extras
from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent, Control, Drive, Observations, ScanAssociation
from ekfviz.core.steps import StepCounter
from ekfviz.core.types import FloatArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.plugged import FilterFactory, Plugged, PluginError
from ekfviz.runner.batches import BATCH_EVENTS, BATCH_LANDMARKS, BatchStream
from ekfviz.runner.checks import WholeCovariance
from ekfviz.runner.errors import FilterLineError, initial_error, line_error
from ekfviz.runner.observe import Observer

if TYPE_CHECKING:  # the association is loaded by a log with scans (or --gate) only
    from ekfviz.association.associator import Associator

__all__ = ["FilterLineError", "corrected_controls", "plugged", "replay"]

MOVES = (Control, Drive)  # the events that move the filter (a tuple: isinstance's fastest)


def replay(
    events: Iterable[AnyEvent],
    params: FilterParams | None = None,
    *,
    make_filter: FilterFactory | None = None,
    name: str = "ekf",
    full_cov: bool = False,
    slam: EkfSlam | None = None,
    associator: Associator | None = None,
    batch_events: int = BATCH_EVENTS,
) -> Iterator[EventBatch]:
    """Run EKF-SLAM over ``events`` lazily, its states in batches of consecutive events.

    The filter is the built-in :class:`~ekfviz.filters.ekf.EkfSlam` unless
    ``make_filter`` names another class of the
    :class:`~ekfviz.filters.protocol.SlamFilter` protocol (constructed as
    ``make_filter(params)``, called ``name`` in messages): its state is checked after
    every event, and what it saw at an update is derived from its state before it
    (:class:`~ekfviz.filters.plugged.Plugged`). A filter with a ``finish()`` method works
    offline (a batch smoother): it takes every event, ``finish()`` is called after the
    last, and its events are the initialisation and the state after ``finish()``, at
    the last step.

    Events are numbered as :class:`~ekfviz.core.steps.StepCounter` says: event 0 / step
    0 is the initialisation (the prior pose, plus the landmarks of the log's first line
    when that line is an observation), a batch of its own. The whole covariance is
    checked and its correlation taken where due (:mod:`ekfviz.runner.checks`). An error
    of the event stream (bad input, an interrupt) is raised only after the batch of the
    events before it, checked, has been yielded.

    Id-less scans go through ``associator`` (:mod:`ekfviz.association`), which pairs
    them and folds them into the filter; at the last event the landmarks still tentative
    are removed. Drive events (a vehicle's raw controls) need a filter with a vehicle
    model (:class:`~ekfviz.filters.model_ekf.ModelEkfSlam`).

    :param full_cov: also keep the full (3+2N)^2 covariance of every event
    :param slam: the built-in filter to run, made by the caller (with its models)
    :param associator: for logs with scans
    :param batch_events: the most events of a batch
    :raises FilterLineError: the filter cannot go on at a line (a non-finite state, a
        protocol filter that raised or showed a broken state, ...)
    """
    params = _checked_arguments(events, params)
    if params.corrects_odometry:  # every filter sees the corrected controls
        events = corrected_controls(events, params)
    ekf = slam if slam is not None else _made(params, make_filter, name)
    out = Events(ekf, full_cov, batch_events)
    observer = Observer(ekf, params, associator)
    counter = StepCounter()
    try:
        stream = with_last(events)
        first, last = next(stream, (None, True))
        pending = out.initialise(first, last, observer)
        counter.initialise()
        yield from out.stream.ready()  # the initialisation: a batch of its own
        for log_event, last in chain(pending, stream):
            if out.step(log_event, last, counter, observer):
                yield from out.stream.ready()
        if out.offline:
            assert isinstance(ekf, Plugged)
            out.finish_offline(ekf, counter.event + 1, counter.step)
        yield from out.stream.rest()
    except GeneratorExit:  # the consumer stopped: nothing more goes to it
        raise
    except BaseException:  # the batches of the events before the error, then the error
        yield from out.stream.rest()
        raise
    finally:
        out.checks.close()


class Events:
    """What each event of one replay adds to its batches: the filter's state, and the
    checks of its whole covariance where due.

    :param ekf: the filter
    :param full_cov: keep the whole covariance of every event
    :param batch_events: the most events of a batch
    """

    def __init__(self, ekf: EkfSlam | Plugged, full_cov: bool, batch_events: int) -> None:
        self._ekf = ekf
        self._full_cov = full_cov
        self.checks = WholeCovariance(ekf)
        self.stream = BatchStream(batch_events)
        self._builder = builder = self.stream.builder
        self._append = builder.append
        self._last_row = batch_events - 1  # a batch is sealed once it has its last row
        self.offline = isinstance(ekf, Plugged) and ekf.offline  # events only after finish()

    def step(
        self, log_event: AnyEvent, last: bool, counter: StepCounter, observer: Observer
    ) -> bool:
        """Move or correct the filter by ``log_event`` and append its state (see
        :meth:`add`; an offline filter's, none); whether the batch is due to be sealed.

        :raises FilterLineError: the filter cannot go on at the event's line
        """
        line, time = log_event.line, log_event.time
        try:
            if isinstance(log_event, MOVES):
                event, step = counter.predict()
                control = move(self._ekf, log_event)
                if last:
                    observer.finish()
                return not self.offline and self.add(
                    PREDICT, event, step, line, time, control, None, None, (), last
                )
            event, step = counter.update()
            observations, association, warnings = observer.observe(log_event, last)
            return not self.offline and self.add(
                UPDATE, event, step, line, time, None, observations, association, warnings,
                last,
            )  # fmt: skip
        except FilterError as error:
            found = line_error(error, log_event, event)
            if found is error:
                raise
            raise found from error

    def add(
        self,
        kind: int,
        event: int,
        step: int,
        line: int,
        time: float | None,
        control: tuple[float, float] | None,
        observations: Observations | None,
        association: ScanAssociation | None,
        warnings: tuple[str, ...],
        last: bool,
        *,
        now: bool = False,
        path: FloatArray | None = None,
    ) -> bool:
        """Append the filter's state after an event of ``kind`` (``INIT``, ``PREDICT``
        or ``UPDATE``), its whole covariance checked where due (at once where ``now``);
        whether the batch is due to be sealed.

        :raises FilterLineError: (at ``line``) the covariance is not finite
        """
        ekf, checks = self._ekf, self.checks
        map_parts = ekf.map_parts()
        covariance = correlation = work = None
        if kind != PREDICT or last or step >= checks.next_check:  # (a plain predict: none)
            check, correlate = checks.due(
                step, len(map_parts[0]), time, warnings, kind != PREDICT, last, now
            )
            if check or correlate:
                covariance, warnings, correlation, work = checks.work(
                    line, step, map_parts[0], check, correlate, warnings, now
                )
        extras = None
        if warnings or covariance or correlation or association or path is not None:
            extras = Extras(warnings, covariance, correlation, association, path)
        if self._full_cov:
            row = self._builder.add(
                ekf.state_parts(True), event=event, step=step, kind=kind, line=line,
                time=time, control=control, observations=observations, extras=extras,
            )  # fmt: skip
        else:
            pose, pose_cov = ekf.pose_block()
            row = self._append(
                event, step, kind, line, time, control, pose, pose_cov, map_parts,
                observations, extras,
            )  # fmt: skip
        if work is not None:
            self.stream.wait_for(row, work)
        return row >= self._last_row or self._builder.landmarks >= BATCH_LANDMARKS

    def initialise(
        self, first: AnyEvent | None, last: bool, observer: Observer
    ) -> list[tuple[AnyEvent, bool]]:
        """Event 0: the prior, with the landmarks of the log's ``first`` event when it
        is an observation (then used up); the events still to replay before the rest."""
        if first is None or isinstance(first, Control | Drive):
            # the prior holds when the log's first event begins, when it has a time
            start = None if first is None else first.time
            if isinstance(first, Control) and start is not None and first.dt is not None:
                start -= first.dt
            self.add(INIT, 0, 0, 0, start, None, None, None, (), first is None, now=True)
            return [] if first is None else [(first, last)]
        try:
            observations, association = observer.fold(first, last)
            warnings = self._ekf.warnings
            self.add(
                INIT, 0, 0, first.line, first.time, None, observations, association, warnings,
                last, now=True,
            )  # fmt: skip
        except FilterError as error:
            found = initial_error(error, first.line)
            if found is error:
                raise
            raise found from error
        return []

    def finish_offline(self, ekf: Plugged, event: int, step: int) -> None:
        """An offline filter's estimate of the whole run, after its ``finish()``: at the
        last step, with the path of every step where the filter gives it (a smoother's).

        :raises FilterLineError: (line 0) ``finish()`` or the path failed
        """
        try:
            ekf.finish()
            path = ekf.path()
        except PluginError as error:
            raise FilterLineError(0, f"after the last event: {error}") from error
        self.add(UPDATE, event, step, 0, None, None, None, None, (), True, now=True, path=path)


def move(ekf: EkfSlam | Plugged, event: Control | Drive) -> tuple[float, float] | None:
    """Move the filter by a control, or drive its vehicle model; the control's (d,
    alpha), None for a drive."""
    if isinstance(event, Control):
        ekf.predict(event.d, event.alpha, event.dt)
        return event.d, event.alpha
    drive = getattr(ekf, "drive", None)
    if drive is None:
        raise FilterError("speed and steering controls need a filter with a vehicle model")
    drive(event.segments)
    return None


def plugged(make_filter: FilterFactory, params: FilterParams, name: str) -> Plugged:
    """``make_filter(params)`` behind :class:`Plugged`, its state at construction checked.

    :raises FilterLineError: (line 0) the constructor raised, or showed a broken state
    """
    try:
        made = make_filter(params)
    except PluginError as error:  # a filter in a worker says what went wrong itself
        raise FilterLineError(0, f"filter {name}: {error}") from error
    except Exception as error:  # the user's constructor: any exception is its fault
        message = f"filter {name}: construction raised {type(error).__name__}: {error}"
        raise FilterLineError(0, message) from error
    try:
        return Plugged(made, name, params)
    except PluginError as error:
        raise FilterLineError(0, f"event 0 (init): {error}") from error


def _made(params: FilterParams, make_filter: FilterFactory | None, name: str) -> EkfSlam | Plugged:
    """The built-in filter, or ``make_filter``'s behind :class:`Plugged`."""
    if make_filter is None or make_filter is EkfSlam:
        return EkfSlam(params)
    return plugged(make_filter, params, name)


def _checked_arguments(events: object, params: FilterParams | None) -> FilterParams:
    """The parameters (the defaults for None), the arguments' types checked."""
    if isinstance(events, str | Path):  # (iterated, a path's characters: no events)
        raise TypeError(f"replay takes events, not a path: replay(read_log({str(events)!r}))")
    if params is not None and not isinstance(params, FilterParams):
        raise TypeError(f"params: expected FilterParams(...), got {type(params).__name__}")
    return params if params is not None else FilterParams()


def corrected_controls(events: Iterable[AnyEvent], params: FilterParams) -> Iterator[AnyEvent]:
    """The events with every control's systematic odometry errors taken out
    (:meth:`FilterParams.corrected`); the rest as they are."""
    for event in events:
        if isinstance(event, Control):
            d, alpha = params.corrected(event.d, event.alpha)
            yield Control(event.line, d, alpha, event.time, event.dt)
        else:
            yield event


def with_last(events: Iterable[AnyEvent]) -> Iterator[tuple[AnyEvent, bool]]:
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
