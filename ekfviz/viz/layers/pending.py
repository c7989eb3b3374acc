"""What the recorder holds until its next send: records, and predicts given as columns.

A send is due after ``FLUSH_EVERY`` events or once the events held carry
``FLUSH_LANDMARKS`` landmarks: the same events go into every send whether the predicts
came as records or as columns (:class:`~ekfviz.core.records.EventRows`), so that the
recording does not depend on it (the text log joins a predict's line to the update
after it within one send).
"""

from __future__ import annotations

from collections.abc import Callable

from ekfviz.core.records import EventRecord, EventRows
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Clock

# Events between two sends of the buffered data, one chunk per entity: each chunk costs
# ~0.1 ms in the main thread and as much in Rerun's encoder, whatever its size.
FLUSH_EVERY = 4096
FLUSH_LANDMARKS = 1 << 20  # ... or sooner, once the buffered records hold this many landmarks


class PendingEvents:
    """The events not sent yet: the records, in order, and the first ``rows_held`` rows
    of the replay's rows (:meth:`event_rows`), if any, which the records' events
    interleave (both in event order)."""

    def __init__(self) -> None:
        self.records: list[tuple[EventRecord, bool]] = []  # with: logs the whole map
        self.count = 0  # events held, records and rows
        self.landmarks = 0  # landmarks of the maps of the events held
        self.rows: EventRows | None = None  # where a replay writes its plain events, if asked
        self.rows_held = 0
        self.rows_whole: list[bool] = []  # whether each row held logs the whole map
        # the (event, step, is an update) of the newest row held, till the recorder reads it
        self.newest_held: tuple[int, int, bool] | None = None

    def __bool__(self) -> bool:
        return self.count > 0

    def event_rows(self) -> EventRows:
        """The rows a replay writes its plain events to, made at the first call."""
        if self.rows is None:
            self.rows = EventRows(FLUSH_EVERY)
        return self.rows

    def latest(self, record: EventRecord | None) -> EventRecord | None:
        """The newer of ``record`` and the newest row (:meth:`EventRows.latest`)."""
        return record if self.rows is None else self.rows.latest(record)

    @property
    def due(self) -> bool:
        return self.count >= FLUSH_EVERY or self.landmarks >= FLUSH_LANDMARKS

    def add(self, record: EventRecord, whole: bool) -> bool:
        """Hold a record (with whether it logs the whole map); whether a send is due."""
        self.records.append((record, whole))
        self.count += 1
        self.landmarks += len(record.landmark_ids)
        return self.count >= FLUSH_EVERY or self.landmarks >= FLUSH_LANDMARKS

    def hold_rows(
        self,
        before: EventRecord | None,
        thinned: bool,
        log: Callable[[EventRecord], None],
        admit: Callable[[list[int], int, EventRecord], list[bool]],
        send: Callable[..., None],
    ) -> None:
        """Hold the rows written since the record ``before``, if any, calling
        ``send(series=True)`` wherever a send falls due among them, as after their records;
        or, where the thinning may drop some (it holds a predict back, ``thinned``, or
        the rows have times), ``log`` them as records one by one. The (event, step) of the
        last row held, and whether it is an update, go into :attr:`newest_held` before
        any send (a signal may raise in one).

        :param admit: given the steps of the update rows held, their number of
            landmarks and the newest of them as a record, whether each logs the whole
            map (see ``MapLayer.admit_rows``)
        """
        rows = self.rows
        if rows is None:
            return
        total = len(rows)
        new = total - self.rows_held
        if not new:
            return
        assert before is not None  # a replay's first event is a record
        if thinned or rows.timed:
            for record in rows.records(self.rows_held, before):
                log(record)
            return
        updates = rows.updates[self.rows_held : total]
        whole = [False] * new
        at = [k for k, update in enumerate(updates) if update is not None]
        if at:
            steps = rows.steps
            admitted = admit(
                [steps[self.rows_held + k] for k in at],
                len(before.landmark_ids),
                rows.update_record(self.rows_held + at[-1]),
            )
            for k, is_whole in zip(at, admitted, strict=True):
                whole[k] = is_whole
        del self.rows_whole[self.rows_held :]  # (a call cut short by a signal added some)
        self.rows_whole += whole
        self.newest_held = rows.events[total - 1], rows.steps[total - 1], updates[-1] is not None
        per_row = len(before.landmark_ids)  # a predict keeps the map of the record before
        count, landmarks = self.count + new, self.landmarks + per_row * new
        if count < FLUSH_EVERY and landmarks < FLUSH_LANDMARKS:  # no send due among them
            self.count, self.landmarks, self.rows_held = count, landmarks, total
            return
        while new:
            due = FLUSH_EVERY - self.count  # rows until a send is due
            if per_row:
                due = min(due, -(-(FLUSH_LANDMARKS - self.landmarks) // per_row))
            held = min(new, max(due, 1))
            self.rows_held += held
            self.count += held
            self.landmarks += per_row * held
            new -= held
            if self.due:
                send(series=True)

    def batch(self, clock: Clock) -> Batch:
        """Every event held, as one batch in event order; none is held after."""
        whole = self.rows_whole
        records, held = self.take()
        batch = Batch.of(records, clock, self.rows, held, whole)
        self.release(held)
        return batch

    def take(self) -> tuple[list[tuple[EventRecord, bool]], int]:
        """The records held and how many rows (the first of :attr:`rows`); none is held
        after. The caller :meth:`release` s the rows once it has read them."""
        records, held = self.records, self.rows_held
        self.records = []
        self.count = self.landmarks = 0
        return records, held

    def release(self, rows_read: int) -> None:
        """Forget the first ``rows_read`` rows (sent)."""
        if self.rows is not None and rows_read:
            self.rows.drop(rows_read)
        self.rows_held -= rows_read
        del self.rows_whole[:rows_read]
