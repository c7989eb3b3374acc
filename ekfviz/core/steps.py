"""How a run numbers its events and steps: the one rule every part of ekfviz counts by.

Event 0 / step 0 is the initialisation: the prior pose, plus the landmarks of the log's
first line when that line is an observation. Every later event is one more event. Every
control (a predict) starts a new step; an observation is the update of the current step,
or starts a step of its own when the step already had one (a log need not alternate
controls and observations).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass


@dataclass(slots=True)
class StepCounter:
    """The event and step of each event of a run, fed in order.

    >>> counter = StepCounter()
    >>> counter.initialise(), counter.predict(), counter.update(), counter.update()
    ((0, 0), (1, 1), (2, 1), (3, 2))

    :ivar event: the number of the last event counted (0: the initialisation)
    :ivar step: its step
    :ivar step_has_update: whether the current step has had its update (the
        initialisation counts as step 0's)
    """

    event: int = 0
    step: int = 0
    step_has_update: bool = True

    def initialise(self) -> tuple[int, int]:
        """The initialisation: event 0, step 0 (the counter starts over)."""
        self.event, self.step, self.step_has_update = 0, 0, True
        return 0, 0

    def predict(self) -> tuple[int, int]:
        """A control: the next event, in a new step."""
        self.event += 1
        self.step += 1
        self.step_has_update = False
        return self.event, self.step

    def update(self) -> tuple[int, int]:
        """An observation: the next event, the current step's update (a new step when
        the current one had its update already)."""
        self.event += 1
        if self.step_has_update:
            self.step += 1
        self.step_has_update = True
        return self.event, self.step

    def count(self, is_predict: bool) -> tuple[int, int]:
        """:meth:`predict` or :meth:`update`, as ``is_predict`` says."""
        return self.predict() if is_predict else self.update()


def log_steps(is_predict: Iterable[bool]) -> Iterator[tuple[int, int]]:
    """The (event, step) of each event of a log read from its start, as a replay numbers
    them: its first, when an observation, is the initialisation (event 0, step 0); every
    other is counted by :meth:`StepCounter.count` (``is_predict``: whether each event is
    a control)."""
    counter = StepCounter()
    for k, predict in enumerate(is_predict):
        yield counter.initialise() if k == 0 and not predict else counter.count(predict)
