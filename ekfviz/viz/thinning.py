"""Which predicts of a run are logged: the filter runs on every one, the recording not.

The one logging policy for high-rate odometry (MRCLAM's 67 Hz, Victoria Park's 62,000
inputs): a record of a predict is logged when

- its log time is at least ``PREDICT_INTERVAL_S`` after the last record logged (so
  that logged poses are at most that plus one control's span apart), or
- it is the last predict before an update, or the last record of the run, or
- it has no time (an untimed log, whose controls are steps, not samples), or the
  recording asks for every record (``--detail``).

Every update and the initialisation are logged; the whole map's ellipses of such a log
every ``MAP_EVERY_S`` seconds of log time, the observed landmarks' at every update (see
:mod:`ekfviz.viz.recorder`). So the robot, its ellipse and the
trajectory have a value at most ``PREDICT_INTERVAL_S`` of log time old at any point of
the timeline, the state each update starts from is in the recording, and the filter
itself stays exact: only what is logged is thinned, never what is computed.
"""

from __future__ import annotations

from ekfviz.core.records import EventKind, EventRecord

PREDICT_INTERVAL_S = 0.5  # seconds of log time: 2 poses a second at least (MRCLAM: < 10 cm)


class PredictThinning:
    """Decide record by record what is logged (see the module).

    :param interval_s: the least log time between two logged predicts, or None to log
        every record
    """

    def __init__(self, interval_s: float | None = PREDICT_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._held: EventRecord | None = None  # the latest predict not logged (yet)
        self._last_time: float | None = None  # of the latest record logged
        self.skipped = 0  # predicts never logged

    def admit(self, record: EventRecord) -> list[EventRecord]:
        """The records to log now, in order, given the next one of the run."""
        interval = self.interval_s
        if record.kind is EventKind.PREDICT and interval is not None and record.time is not None:
            if self._last_time is None or record.time - self._last_time >= interval:
                if self._held is not None:
                    self.skipped += 1
                self._held = None
                self._last_time = record.time
                return [record]
            if self._held is not None:
                self.skipped += 1
            self._held = record
            return []
        out = self.drain()
        out.append(record)
        if record.time is not None:
            self._last_time = record.time
        return out

    @property
    def held(self) -> bool:
        """Whether a predict is held back (logged, or not, once the next record comes)."""
        return self._held is not None

    def passes(self, record: EventRecord) -> bool:
        """Whether ``record`` is logged at once with nothing before it (what :meth:`admit`
        would return as ``[record]``): the common case, answered without a list."""
        if self._held is not None:
            return False
        if record.time is None:
            return True
        if self.interval_s is None or record.kind is not EventKind.PREDICT:
            self._last_time = record.time
            return True
        return False

    def drain(self) -> list[EventRecord]:
        """The predict held back, if any: the run ended, or an update or note follows."""
        held, self._held = self._held, None
        return [] if held is None else [held]
