"""Drive the filter through a stream of log events and yield one record per event."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import replace
from itertools import chain
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ekfviz.core.correlation import CorrelationCadence, correlation_of
from ekfviz.core.errors import FilterError
from ekfviz.core.health import NOT_FINITE, CovarianceCheck, check_covariance, check_interval
from ekfviz.core.params import FilterParams
from ekfviz.core.records import (
    AnyEvent,
    Control,
    Drive,
    EventKind,
    EventRecord,
    EventRows,
    Observations,
    Scan,
    ScanAssociation,
    Sighting,
    frozen,
)
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.plugged import FilterFactory, Plugged, PluginError
from ekfviz.runner.beside import Beside

if TYPE_CHECKING:  # the association is loaded by a log with scans (or --gate) only
    from ekfviz.association.associator import Associator


class FilterLineError(FilterError):
    """The filter could not go on at a line of the log.

    :param line: the log line whose event failed
    """

    def __init__(self, line: int, message: str, motion: bool | None = None) -> None:
        self.line = line
        self.motion = motion  # the line's event a motion (a predict) or not; None: unknown
        super().__init__(message)

    def __reduce__(self) -> tuple[type[FilterLineError], tuple[int, str, bool | None]]:
        # rebuilt from its arguments where a study's worker process hands it back
        return type(self), (self.line, str(self), self.motion)


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


def corrected_controls(events: Iterable[AnyEvent], params: FilterParams) -> Iterator[AnyEvent]:
    """The events with every control's systematic odometry errors taken out
    (:meth:`FilterParams.corrected`); the rest as they are."""
    for event in events:
        if isinstance(event, Control):
            d, alpha = params.corrected(event.d, event.alpha)
            # not dataclasses.replace: this runs for every control of every replay
            yield Control(event.line, d, alpha, event.time, event.dt)
        else:
            yield event


def replay(
    events: Iterable[AnyEvent],
    params: FilterParams | None = None,
    *,
    make_filter: FilterFactory | None = None,
    name: str = "ekf",
    full_cov: bool = False,
    slam: EkfSlam | None = None,
    associator: Associator | None = None,
    event_rows: EventRows | None = None,
) -> Iterator[EventRecord]:
    """Run EKF-SLAM over ``events`` lazily, one record per event.

    The filter is the built-in :class:`~ekfviz.filters.ekf.EkfSlam` unless
    ``make_filter`` names another class of the
    :class:`~ekfviz.filters.protocol.SlamFilter` protocol (constructed as
    ``make_filter(params)``, called ``name`` in messages): its state is checked after
    every event, and what it saw at an update is derived from its state before it
    (:class:`~ekfviz.filters.plugged.Plugged`). A filter with a ``finish()`` method works
    offline (a batch smoother): it takes every event, ``finish()`` is called after the
    last, and its records are the initialisation and the state after ``finish()``, at the
    last step.

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

    Id-less scans go through ``associator`` (:mod:`ekfviz.association`), which pairs
    them and folds them into the filter; at the last event the landmarks still tentative
    are removed. Drive events (a vehicle's raw controls) need a filter with a vehicle
    model (:class:`~ekfviz.filters.model_ekf.ModelEkfSlam`).

    :param full_cov: also keep the full (3+2N)^2 covariance in every record
    :param slam: the built-in filter to run, made by the caller (with its models)
    :param associator: for logs with scans
    :param event_rows: where the built-in filter's plain events go as columns instead
        of records (see :class:`~ekfviz.core.records.EventRows`): every predict of a
        control but the last event's and those whose covariance is checked, and, where
        the rows take updates, every update by ids that keeps the map of the record before
        it, raised no warning and whose covariance is not checked nor its correlation
        due; None: a record for every event
    :raises FilterLineError: the filter cannot go on at a line (a non-finite state, a
        protocol filter that raised or showed a broken state, ...)
    """
    if isinstance(events, str | Path):  # (iterated, a path's characters: no events)
        raise TypeError(f"replay takes events, not a path: replay(read_log({str(events)!r}))")
    if params is not None and not isinstance(params, FilterParams):
        raise TypeError(f"params: expected FilterParams(...), got {type(params).__name__}")
    params = params if params is not None else FilterParams()
    if params.corrects_odometry:  # every filter sees the corrected controls
        events = corrected_controls(events, params)
    ekf: EkfSlam | Plugged
    if slam is not None:
        ekf = slam
    elif make_filter is None or make_filter is EkfSlam:
        ekf = EkfSlam(params)
    else:
        ekf = plugged(make_filter, params, name)
    gate, R = params.gate, params.R
    rows = event_rows if isinstance(ekf, EkfSlam) and not full_cov else None
    update_rows = rows if rows is not None and rows.takes_updates else None
    next_check = 0  # the step from which the whole covariance is due for a check
    cadence = CorrelationCadence()
    # the work on a large P (the check, the correlation) is done beside the filter, the
    # records that wait for it held back in order (see ekfviz.runner.beside)
    beside = Beside()

    def correlated(record: EventRecord, last: bool) -> EventRecord:
        """The record, with the correlation matrix of P where it is due."""
        if (record.kind is not EventKind.PREDICT or last) and cadence.due(
            record.step, record.n_landmarks, last, record.time
        ):
            return with_correlation(record)
        return record

    def with_correlation(record: EventRecord) -> EventRecord:
        """The record with the correlation of P; or as it is, the correlation asked of
        ``beside`` (a large P)."""
        P = ekf.P
        if Beside.takes(P):
            beside.ask(P, ids=record.landmark_ids)
            return record
        return replace(record, correlation=correlation_of(P, record.landmark_ids))

    def checked(line: int, warnings: tuple[str, ...]) -> dict[str, Any]:
        """Check the whole covariance now; its problems join the event's warnings."""
        check, warnings = checked_pair(line, warnings, now=True)
        return {"covariance": check, "warnings": warnings}

    def checked_pair(
        line: int, warnings: tuple[str, ...], now: bool = False
    ) -> tuple[CovarianceCheck | None, tuple[str, ...]]:
        """The check of the whole covariance and the event's warnings with its problems
        (no dictionary per event); (None, warnings) where the check is asked of
        ``beside`` (a large P, unless ``now``), which adds both to the record.

        :raises FilterLineError: P is not finite
        """
        nonlocal next_check
        P = ekf.P
        next_check = step + check_interval(ekf.dim)
        if not now and Beside.takes(P):
            if not Beside.finite(P):
                raise FilterLineError(line, NOT_FINITE)
            beside.ask(P, check=True)
            return None, warnings
        check = check_covariance(P)
        if not check.finite:
            raise FilterLineError(line, check.problems()[0])
        return check, warnings + tuple(check.problems())

    try:
        step = 0
        stream = _with_last(events)
        first, last = next(stream, (None, True))
        extra: dict[str, Any]
        if isinstance(first, Sighting | Scan):
            try:
                observations, association = _observe(ekf, first, associator, last)
            except PluginError as error:
                raise FilterLineError(first.line, f"event 0 (init): {error}", False) from error
            except FilterError as error:
                raise FilterLineError(first.line, str(error), False) from error
            extra = checked(first.line, ekf.warnings)
            record = correlated(ekf.record(
                event=0, step=0, kind=EventKind.INIT, line=first.line, time=first.time,
                observations=observations, full_cov=full_cov, association=association, **extra,
            ), last)  # fmt: skip
            yield from beside.hold(record) if beside.busy else (record,)
            pending: list[tuple[AnyEvent, bool]] = []
        else:
            extra = checked(0, ())
            # the prior holds when the log's first event begins, when it has a time
            start = None if first is None else first.time
            if isinstance(first, Control) and start is not None and first.dt is not None:
                start -= first.dt
            record = correlated(
                ekf.record(
                    event=0, step=0, kind=EventKind.INIT, time=start, full_cov=full_cov, **extra
                ),
                first is None,
            )
            yield from beside.hold(record) if beside.busy else (record,)
            pending = [] if first is None else [(first, last)]

        map_ids = record.landmark_ids  # the map of the last record (an update row's own)
        step_has_update = True  # the initialisation counts as step 0's update
        event = 0
        # per event, below: the record's arguments by name (no dictionary unpacked), the
        # correlation's cadence asked only where it can be due (updates, the last event)
        covariance: CovarianceCheck | None
        offline = isinstance(ekf, Plugged) and ekf.offline  # records only after finish()
        gate_said = False  # --gate on a log of scans: said at the first
        for event, (log_event, last) in enumerate(chain(pending, stream), start=1):
            # the filter's own errors name the line; "try" costs nothing until one is raised
            try:
                if isinstance(log_event, Control | Drive):
                    step += 1
                    step_has_update = False
                    if isinstance(log_event, Drive):
                        _drive(ekf, log_event)
                    else:
                        ekf.predict(log_event.d, log_event.alpha, log_event.dt)
                    if last and associator is not None and isinstance(ekf, EkfSlam):
                        associator.finish(ekf)
                    if offline:
                        continue
                    if step >= next_check or last:
                        covariance, warnings = checked_pair(log_event.line, ())
                    elif rows is not None and type(log_event) is Control:
                        # the buffers fold P's pending changes in: read them whether the
                        # row is written or, while records are held (they come first),
                        # a record made, so that the filter's floats never depend on
                        # when the thread beside it is done
                        x, P = ekf.buffers  # type: ignore[union-attr]  # rows: the built-in filter's
                        if not beside.busy:
                            rows.add(event, step, log_event.line, log_event.time,
                                     (log_event.d, log_event.alpha), x, P)  # fmt: skip
                            continue
                        covariance, warnings = None, ()
                    else:
                        covariance, warnings = None, ()
                    record = ekf.record(
                        event=event, step=step, kind=EventKind.PREDICT, line=log_event.line,
                        time=log_event.time,
                        control=(log_event.d, log_event.alpha) if type(log_event) is Control
                        else _control(log_event),
                        full_cov=full_cov, warnings=warnings, covariance=covariance,
                    )  # fmt: skip
                    if last:
                        record = correlated(record, last)
                    if beside.busy:  # records held: this one behind them
                        yield from beside.hold(record)
                    else:
                        yield record
                else:
                    if step_has_update:
                        step += 1
                    step_has_update = True
                    rejected: tuple[str, ...] = ()
                    if gate is not None and isinstance(log_event, Sighting):
                        from ekfviz.association.gating import gated  # --gate only

                        log_event, rejected = gated(
                            ekf.x, ekf.P, ekf.landmark_ids, log_event, R, gate
                        )
                    elif gate is not None and not gate_said and isinstance(log_event, Scan):
                        gate_said = True  # said once, at the first scan
                        rejected = (_GATE_ON_SCANS.format(gate=gate),)
                    if type(log_event) is Sighting:  # by its ids (the common case: no call)
                        observations, association = ekf.observe(log_event.ids, log_event.z), None
                    else:
                        observations, association = _observe(ekf, log_event, associator, last)
                    if offline:
                        continue
                    warnings = rejected + ekf.warnings
                    if step >= next_check or last or warnings:
                        covariance, warnings = checked_pair(log_event.line, warnings)
                    else:
                        covariance = None
                    # a plain update by ids, in the map of the last record: a row (see
                    # EventRows), unless its correlation is due
                    due: bool | None = None  # asked of the cadence once, here or below
                    if (
                        update_rows is not None
                        and covariance is None
                        and association is None
                        and not beside.busy
                        and ekf.settled_ids() is map_ids  # type: ignore[union-attr]  # update_rows: the built-in filter's
                    ):
                        due = cadence.due(step, len(map_ids), last, log_event.time)
                        if not due:
                            x, P = ekf.buffers  # type: ignore[union-attr]
                            update_rows.add_update(
                                event, step, log_event.line, log_event.time, observations, x, P,
                                map_ids,
                            )  # fmt: skip
                            continue
                    record = ekf.record(
                        event=event, step=step, kind=EventKind.UPDATE, line=log_event.line,
                        time=log_event.time, observations=observations, full_cov=full_cov,
                        warnings=warnings, covariance=covariance, association=association,
                    )  # fmt: skip
                    map_ids = record.landmark_ids
                    if due is None:
                        due = cadence.due(step, record.n_landmarks, last, record.time)
                    if due:
                        record = with_correlation(record)
                    if beside.busy:
                        yield from beside.hold(record)
                    else:
                        yield record
            except FilterLineError as error:  # (raised at this event's line: its kind)
                if error.motion is None and error.line == log_event.line:
                    error.motion = isinstance(log_event, Control | Drive)
                raise
            except PluginError as error:
                kind = "predict" if isinstance(log_event, Control) else "update"
                raise FilterLineError(
                    log_event.line, f"event {event} ({kind}): {error}",
                    isinstance(log_event, Control | Drive),
                ) from error  # fmt: skip
            except FilterError as error:
                raise FilterLineError(
                    log_event.line, str(error), isinstance(log_event, Control | Drive)
                ) from error
        if offline:
            assert isinstance(ekf, Plugged)
            try:
                ekf.finish()
            except PluginError as error:
                raise FilterLineError(0, f"after the last event: {error}") from error
            # the estimate of the whole run, at its last step (where the truth's last pose is),
            # with the path of every step where the filter gives it (a smoother's)
            try:
                path = ekf.path()
            except PluginError as error:
                raise FilterLineError(0, f"after the last event: {error}") from error
            final = ekf.record(event=event + 1, step=step, kind=EventKind.UPDATE, **checked(0, ()))
            record = correlated(replace(final, path_xytheta=path), True)
            yield from beside.hold(record) if beside.busy else (record,)

        yield from beside.rest()
    except GeneratorExit:  # the consumer stopped: nothing more goes to it
        raise
    except BaseException:  # the records held before the error, then the error
        yield from beside.rest()
        raise
    finally:
        beside.close()


_GATE_ON_SCANS = (
    "--gate {gate:g} gates observations by landmark id; a scan's measurements are gated by"
    " the association (--gate-probability), not by it"
)


def _observe(
    ekf: EkfSlam | Plugged, event: Sighting | Scan, associator: Associator | None, last: bool
) -> tuple[Observations, ScanAssociation | None]:
    """Fold an observation in: by its ids, or a scan through the association (any
    filter: a protocol one with ``remove_landmarks`` for tentative landmarks), with what
    the association decided (None for an observation by ids)."""
    if isinstance(event, Sighting):
        return ekf.observe(event.ids, event.z), None
    if associator is None:
        raise FilterError("a scan has no landmark ids: it needs --association nn or jcbb")
    from ekfviz.association.associator import Associator
    from ekfviz.association.params import AssociationError

    if isinstance(ekf, Plugged):  # at the first scan: a log with ids needs no removal
        try:
            Associator.check_filter(ekf, associator.params)
        except AssociationError as error:
            raise FilterError(f"filter {ekf.name}: {error}") from error
    observations, association = associator.process(ekf, event)
    if last:  # the end of the run: nothing tentative is left in the map
        removed = associator.finish(ekf)
        if removed:
            both = np.union1d(association.removed, removed)
            association = replace(association, removed=frozen(both), tentative=frozen(both[:0]))
    return observations, association


def _control(event: Control | Drive) -> tuple[float, float] | None:
    return (event.d, event.alpha) if isinstance(event, Control) else None


def _drive(ekf: EkfSlam | Plugged, event: Drive) -> None:
    drive = getattr(ekf, "drive", None)
    if drive is None:
        raise FilterError("speed and steering controls need a filter with a vehicle model")
    drive(event.segments)


def _with_last(events: Iterable[AnyEvent]) -> Iterator[tuple[AnyEvent, bool]]:
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
