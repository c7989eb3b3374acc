"""Which predicts of a run are logged: the filter runs on every one, the recording not.

The one logging policy for high-rate odometry (MRCLAM's 67 Hz, Victoria Park's 62,000
inputs): a predict is logged when

- its log time is at least ``PREDICT_INTERVAL_S`` after the last event logged (so
  that logged poses are at most that plus one control's span apart), or
- it is the last predict before an update, or the last event of the run, or
- it has no time (an untimed log, whose controls are steps, not samples), or the
  recording asks for every event (``--detail``).

Every update and the initialisation are logged; the whole map's ellipses of such a log
every ``MAP_EVERY_S`` seconds of log time, the observed landmarks' at every update (see
:mod:`ekfviz.viz.recorder`). So the robot, its ellipse and the
trajectory have a value at most ``PREDICT_INTERVAL_S`` of log time old at any point of
the timeline, the state each update starts from is in the recording, and the filter
itself stays exact: only what is logged is thinned, never what is computed.
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.batch import PREDICT, EventBatch

PREDICT_INTERVAL_S = 0.5  # seconds of log time: 2 poses a second at least (MRCLAM: < 10 cm)


class PredictThinning:
    """Decide event by event what is logged (see the module).

    :param interval_s: the least log time between two logged predicts, or None to log
        every event
    """

    def __init__(self, interval_s: float | None = PREDICT_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._held: EventBatch | None = None  # the latest predict not logged (yet)
        self._last_time: float | None = None  # of the latest event logged
        self.skipped = 0  # predicts never logged

    @property
    def held(self) -> bool:
        """Whether a predict is held back (logged, or not, once the next event comes)."""
        return self._held is not None

    def admit(self, events: EventBatch) -> EventBatch:
        """The events to log now, in order, given the next ones of the run: a predict
        held back before them first, where it is logged; the last of them held back,
        where it may not be."""
        interval = self.interval_s
        before = self._held
        if interval is None or (before is None and bool(np.isnan(events.times).all())):
            return events  # every event logged (an untimed log: its predicts are steps)
        keep: list[int] = []
        # the predict held back: a row of these events, -1 the one held from before
        held = None if before is None else -1
        last_time = self._last_time
        for row, (kind, time) in enumerate(
            zip(events.kinds.tolist(), events.times.tolist(), strict=True)
        ):
            timed = time == time  # (not NaN)
            if kind == PREDICT and timed:
                if held is not None:  # replaced, whichever way: never logged
                    self.skipped += 1
                if last_time is None or time - last_time >= interval:
                    held, last_time = None, time
                    keep.append(row)
                else:
                    held = row
                continue
            if held is not None:  # an update or an untimed event follows: logged
                keep.append(held)
                held = None
            keep.append(row)
            if timed:
                last_time = time
        self._last_time = last_time
        self._held = before if held == -1 else None if held is None else events.take([held])
        logged = events.take([row for row in keep if row >= 0])
        if before is not None and -1 in keep:
            return EventBatch.joined([before, logged])
        return logged

    def drain(self) -> EventBatch | None:
        """The predict held back, if any: the run ended, or a note follows."""
        held, self._held = self._held, None
        return held
