"""One ``ekfviz replay`` run logged to its recording, batch by batch.

:func:`open_run` opens the recording (see :mod:`ekfviz.viz.recording`) and hands out a
:class:`RunLogger` built on :class:`~ekfviz.viz.recorder.Recorder`: the events as they
come, the evaluation at the end or, for a run cut short, why and where it stopped.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import TYPE_CHECKING

import rerun as rr

from ekfviz.core.batch import EventBatch
from ekfviz.core.records import EventRecord
from ekfviz.evaluation.errors import Evaluation
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.viz.provenance import RunInfo
from ekfviz.viz.recorder import Recorder
from ekfviz.viz.recording import Recording, Sinks, any_values, finish_recorders, open_recording

if TYPE_CHECKING:
    from ekfviz.sources import FittedReference

TIME_PROPERTY = "time"  # the span of the time timeline: start, end (seconds), kind
RESULTS_PROPERTY = "results"  # a replay's results beside its evaluation, as JSON
GPS_LABEL_ROOM = 0.12  # room beside a GPS jump for its label, as a share of the map


class RunLogger:
    """Logs the events of one run; built by :func:`open_run`.

    :ivar recorder: the :class:`Recorder` doing the logging
    :ivar recording: the recording it logs to, with its sinks
    """

    def __init__(self, recorder: Recorder, recording: Recording) -> None:
        self.recorder = recorder
        self.recording = recording
        self.logged = 0  # events logged so far
        self._last: EventBatch | None = None  # the last batch logged

    @property
    def finished(self) -> bool:
        return self.recording.complete

    def log(self, events: EventBatch) -> None:
        """Log a batch of the run's events."""
        if len(events):
            self._last = events  # first: the recorder holds them all before any send
        self.recorder.log(events)
        self.logged += len(events)

    @property
    def last(self) -> EventRecord | None:
        """The last event logged (or being logged), viewed as a record."""
        return None if self._last is None else self._last.last

    def log_reference(self, fitted: FittedReference) -> None:
        """A source's reference fitted to the path (Victoria Park's GPS), in the map and
        over time; the map frames it, with room for a jump's label beside it. Before
        :meth:`finish`, whose layout frames what the map draws."""
        from ekfviz.viz.reference import log_reference  # (a run without one never loads it)

        fit = fitted.fit
        # a replay's recorder logs under no prefix: the entity paths are the reference's own
        log_reference(self.recording.rec, str, fit, fitted.steps)
        self.recorder.frame(fit.reference_xy[~fit.jumps])
        self.recorder.frame(fit.reference_xy[fit.jumps], label_room=GPS_LABEL_ROOM)

    def finish(self, evaluation: Evaluation | None) -> None:
        """Log the evaluation document and send the buffered series: the run is complete;
        the span of the ``time`` timeline, if any, goes into the properties."""
        finish_recorders(self.recording, [(self.recorder, evaluation)])
        span = self.recorder.time_span
        if span is not None:
            kind = "timestamp" if self.recorder.time_is_epoch else "duration"
            self.recording.rec.send_property(
                TIME_PROPERTY, any_values({"start": span[0], "end": span[1], "kind": kind})
            )

    def add_results(self, results: Mapping[str, object]) -> None:
        """Results of the run beside its evaluation (the association's counts, the GPS
        error of Victoria Park), as the property ``results`` that ``ekfviz info`` shows."""
        self.recording.rec.send_property(
            RESULTS_PROPERTY, any_values({"json": json.dumps(dict(results), default=str)})
        )

    def stop(self, reason: str, evaluation: Evaluation | None) -> bool:
        """End a run cut short (bad input, a numerical fault, a signal): log why as the
        last line, send what is buffered and keep the recording if it holds any event.

        :return: whether the recording is kept (and, with ``--save``, written)
        """
        if not self.logged:
            return False
        self.recording.partial = True
        self.recorder.note(reason, level=rr.TextLogLevel.ERROR)
        last = self.last
        finish_recorders(
            self.recording,
            [(self.recorder, evaluation)],
            status={
                "state": "stopped",
                "reason": reason,
                "event": -1 if last is None else last.event,
                "step": -1 if last is None else last.step,
                "line": -1 if last is None else last.line,
            },
        )
        return True


@contextmanager
def open_run(
    info: RunInfo,
    sinks: Sinks,
    *,
    detail: bool = False,
    history: bool = False,
    sensor: RangeBearing | None = None,
    gps_reference: bool = False,
) -> Iterator[RunLogger]:
    """A recording of one replay (see :func:`~ekfviz.viz.recording.open_recording`),
    logged by a RunLogger.

    :param detail: log every landmark's ellipse and error at every update (see
        :class:`~ekfviz.viz.recorder.Recorder`); by default a large map is logged whole
        only every ``MAP_EVERY_STEPS`` steps
    :param gps_reference: a GPS reference is logged after the run (its plot is laid out)
    """
    with open_recording(info, sinks) as recording:
        recorder = Recorder(
            recording.rec,
            truth=info.truth,
            run_documents=True,
            detail=detail,
            history=history,
            live_layout=sinks.spawn or sinks.serve or sinks.connect is not None,
            sensor=sensor,
            gps_reference=gps_reference,
        )
        yield RunLogger(recorder, recording)
