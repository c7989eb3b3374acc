"""What the recorder holds until its next send: the events logged so far, with whether
each logs the whole map.

A send is due after ``FLUSH_EVERY`` events or once the events held carry
``FLUSH_LANDMARKS`` landmarks, and it takes exactly the events up to there: the same
events go into every send whatever batches they came in, so that the recording does not
depend on them (the text log joins a predict's line to the update after it within one
send).
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.batch import EventBatch
from ekfviz.core.types import BoolArray
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Clock

# Events between two sends of the buffered data, one chunk per entity: each chunk costs
# ~0.1 ms in the main thread and as much in Rerun's encoder, whatever its size.
FLUSH_EVERY = 4096
FLUSH_LANDMARKS = 1 << 20  # ... or sooner, once the events held hold this many landmarks


class PendingEvents:
    """The events not sent yet, in order, each with whether it logs the whole map."""

    def __init__(self) -> None:
        self._held: list[tuple[EventBatch, BoolArray]] = []
        self.count = 0  # events held
        self.landmarks = 0  # landmarks of the maps of the events held

    def __bool__(self) -> bool:
        return self.count > 0

    @property
    def due(self) -> bool:
        return self.count >= FLUSH_EVERY or self.landmarks >= FLUSH_LANDMARKS

    def add(self, events: EventBatch, whole: BoolArray) -> None:
        """Hold ``events`` (``whole``: whether each logs the whole map)."""
        self._held.append((events, whole))
        self.count += len(events)
        self.landmarks += int(events.n_landmarks.sum())

    def take_due(self, clock: Clock) -> Batch | None:
        """The events up to where the first send falls due, as a batch; None where none
        is due. They are held no more."""
        if not self.due:
            return None
        count = landmarks = 0
        for k, (events, whole) in enumerate(self._held):
            at = np.cumsum(events.n_landmarks) + landmarks
            due = (count + 1 + np.arange(len(events)) >= FLUSH_EVERY) | (at >= FLUSH_LANDMARKS)
            hits = np.flatnonzero(due)
            if not hits.size:
                count, landmarks = count + len(events), int(at[-1]) if len(at) else landmarks
                continue
            cut = int(hits[0]) + 1
            sent = [*self._held[:k], (events[:cut], whole[:cut])]
            rest = [(events[cut:], whole[cut:])] if cut < len(events) else []
            self._held = rest + self._held[k + 1 :]
            self.count = sum(len(e) for e, _ in self._held)
            self.landmarks = sum(int(e.n_landmarks.sum()) for e, _ in self._held)
            return _batch(sent, clock)
        return None

    def take(self, clock: Clock) -> Batch | None:
        """Every event held, as one batch in event order (None where none is); none is
        held after."""
        held, self._held = self._held, []
        self.count = self.landmarks = 0
        return _batch(held, clock) if held else None


def _batch(held: list[tuple[EventBatch, BoolArray]], clock: Clock) -> Batch:
    """The batch of a send of the events ``held``."""
    events = EventBatch.joined([events for events, _ in held])
    whole = np.concatenate([np.zeros(0, dtype=bool), *(whole for _, whole in held)])
    return Batch.of(events, whole, clock)
