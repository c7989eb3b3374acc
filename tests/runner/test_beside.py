"""The work on a large P done beside the filter (ekfviz.runner.beside): the events are
those made at once, in the same order, and a fault or an error of the input still comes
after every event before it."""

from __future__ import annotations

import contextlib
import threading
import time
import weakref
from collections.abc import Generator, Iterator
from typing import Any

import numpy as np
import pytest

import ekfviz.runner.beside as beside
from ekfviz.core.records import AnyEvent, Control, EventKind, EventRecord
from ekfviz.filters.ekf import EkfSlam
from ekfviz.runner.replay import FilterLineError, replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import loop


@pytest.fixture(scope="module")
def large() -> list[AnyEvent]:
    """A loop among 150 landmarks: P passes BESIDE_MIN_DIM early on."""
    return list(loop(steps=300, landmarks=150, max_range=30.0).run(seed=5).events)


def at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every P done at once, as before the thread."""
    monkeypatch.setattr(beside, "BESIDE_MIN_DIM", 10**9)


def counted(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The dimensions of the P given to the thread."""
    dims: list[int] = []
    work = beside.whole_covariance_work

    def spied(P: np.ndarray, check: bool, ids: Any, pending: Any = None) -> Any:
        dims.append(P.shape[0])
        return work(P, check, ids, pending)

    monkeypatch.setattr(beside, "whole_covariance_work", spied)
    return dims


def assert_same(ours: list[EventRecord], theirs: list[EventRecord]) -> None:
    assert [(r.event, r.kind, r.line) for r in ours] == [(r.event, r.kind, r.line) for r in theirs]
    for a, b in zip(ours, theirs, strict=True):
        assert a.covariance == b.covariance
        assert a.warnings == b.warnings
        assert np.array_equal(a.pose, b.pose) and np.array_equal(a.pose_cov, b.pose_cov)
        assert (a.correlation is None) == (b.correlation is None)
        if a.correlation is not None and b.correlation is not None:
            assert np.array_equal(a.correlation.matrix, b.correlation.matrix, equal_nan=True)
            assert a.correlation.factor == b.correlation.factor
            assert np.array_equal(a.correlation.landmark_ids, b.correlation.landmark_ids)


def no_thread_left() -> bool:
    return not any(t.name.startswith("ekfviz-whole-P") for t in threading.enumerate())


def test_the_events_are_those_made_at_once_in_the_same_order(
    large: list[AnyEvent], monkeypatch: pytest.MonkeyPatch
) -> None:
    dims = counted(monkeypatch)
    ours = every_event(replay(large))
    assert dims and min(dims) >= beside.BESIDE_MIN_DIM  # the thread did the large ones
    assert no_thread_left()
    checked = [r for r in ours if r.covariance is not None and r.covariance.dim >= 128]
    correlated = [r for r in ours if r.correlation is not None and r.correlation.dim >= 128]
    assert len(checked) >= 4 and len(correlated) >= 4
    at_once(monkeypatch)
    assert_same(ours, every_event(replay(large)))


class Faulty(EkfSlam):
    """The built-in filter, one entry of P set to ``value`` after its ``at``-th predict
    (a landmark's variance, which a predict leaves alone)."""

    def __init__(self, at: int, value: float) -> None:
        super().__init__()
        self.at, self.value, self.predicts = at, value, 0

    def predict(self, d: float, alpha: float, dt: float | None = None) -> None:
        super().predict(d, alpha, dt)
        self.predicts += 1
        if self.predicts == self.at:
            self._P[5, 5] = self.value


def checked_predict(events: list[AnyEvent]) -> tuple[int, int]:
    """The line of the second predict whose P is checked beside the filter, and how many
    predicts come up to it."""
    records = every_event(replay(events))
    record = [
        r
        for r in records
        if r.kind is EventKind.PREDICT and r.covariance is not None and r.covariance.dim >= 128
    ][1]
    predicts = sum(isinstance(e, Control) and e.line <= record.line for e in events)
    return record.line, predicts


@pytest.fixture(scope="module")
def checked(large: list[AnyEvent]) -> tuple[int, int]:
    """:func:`checked_predict` of the large loop, found once."""
    return checked_predict(large)


def test_a_p_not_finite_stops_the_run_at_its_line_after_every_event_before_it(
    large: list[AnyEvent], checked: tuple[int, int]
) -> None:
    line, predicts = checked
    records: list[EventRecord] = []
    with pytest.raises(FilterLineError, match="NaN or infinity") as caught:
        for batch in replay(large, slam=Faulty(predicts, np.nan)):
            records.extend(batch)
    assert caught.value.line == line
    assert [r.line for r in records] == [e.line for e in large if e.line < line]
    assert any(r.covariance is not None and r.covariance.dim >= 128 for r in records)
    assert no_thread_left()


def test_an_indefinite_p_is_named_in_the_warnings_of_its_event(
    large: list[AnyEvent], checked: tuple[int, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    line, predicts = checked

    def run() -> list[EventRecord]:
        records: list[EventRecord] = []
        # a FilterLineError, if any, the same wherever the P is done: compared below
        with contextlib.suppress(FilterLineError):
            for batch in replay(large, slam=Faulty(predicts, -50.0)):
                records.extend(batch)
        return records

    dims = counted(monkeypatch)
    ours = run()
    assert dims
    faulty = next(r for r in ours if r.line == line)
    assert faulty.covariance is not None and faulty.covariance.min_eigenvalue < 0.0
    assert any("not positive semi-definite" in w for w in faulty.warnings)
    at_once(monkeypatch)
    assert_same(ours, run())


class Broken(Exception):
    pass


def cut(events: list[AnyEvent], after: int) -> Iterator[AnyEvent]:
    """The events up to ``after`` of them, then an error of the input."""
    yield from events[:after]
    raise Broken("line after: not a number")


def test_an_error_of_the_input_comes_after_the_held_events(large: list[AnyEvent]) -> None:
    """The event before the error is the last one: its P is checked (beside the filter)
    and it is handed on, checked, before the error."""
    after = len(large) // 2
    records: list[EventRecord] = []
    with pytest.raises(Broken):
        for batch in replay(cut(large, after)):
            records.extend(batch)
    assert [r.line for r in records] == [e.line for e in large[:after]]
    assert records[-1].covariance is not None and records[-1].covariance.dim >= 128
    assert records[-1].correlation is not None
    assert no_thread_left()


def test_a_consumer_that_stops_early_leaves_no_thread(large: list[AnyEvent]) -> None:
    stream = replay(large, batch_events=32)
    assert isinstance(stream, Generator)
    taken = every_event(next(stream) for _ in range(len(large) // 64))
    assert any(r.covariance is not None and r.covariance.dim >= 128 for r in taken)
    stream.close()
    assert no_thread_left()


def states(events: list[AnyEvent]) -> tuple[dict[int, bytes], EventRecord]:
    """Each event's pose and pose covariance as bytes, and the last event."""
    records = every_event(replay(events))
    return {r.event: r.pose.tobytes() + r.pose_cov.tobytes() for r in records}, records[-1]


def test_the_pending_changes_are_taken_off_in_the_thread(
    large: list[AnyEvent], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The filter hands its stored P and the rows of its pending changes to the thread,
    which takes them off (O(r n^2) the filter does not wait for): the same checks and
    correlations as at once."""
    pending: list[bool] = []
    work = beside.whole_covariance_work

    def spied(P: np.ndarray, check: bool, ids: Any, rows: Any = None) -> Any:
        pending.append(rows is not None)
        return work(P, check, ids, rows)

    at_once(monkeypatch)
    expected = every_event(replay(large))
    monkeypatch.undo()
    monkeypatch.setattr(beside, "whole_covariance_work", spied)
    assert_same(every_event(replay(large)), expected)
    assert any(pending)


@pytest.mark.slow
def test_the_filters_floats_do_not_depend_on_when_the_thread_is_done(
    large: list[AnyEvent], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Batches wait for a slow thread: what the filter computes meanwhile is the same."""
    at_once(monkeypatch)
    expected, last_expected = states(large)
    monkeypatch.undo()
    work = beside.whole_covariance_work

    def slow(P: np.ndarray, check: bool, ids: Any, pending: Any = None) -> Any:
        time.sleep(0.05)  # batches held over many events
        return work(P, check, ids, pending)

    monkeypatch.setattr(beside, "whole_covariance_work", slow)
    got, last = states(large)
    assert got == expected
    assert np.array_equal(last.landmarks_xy, last_expected.landmarks_xy)
    assert np.array_equal(last.landmark_covs, last_expected.landmark_covs)


def test_one_copy_of_p_at_a_time_however_fast_the_work_is_asked_for(
    large: list[AnyEvent], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A slow thread holds the replay back rather than copies of P piling up."""
    alive: list[int] = [0, 0]  # now, most

    class Counting:
        def __getattr__(self, name: str) -> Any:
            return getattr(np, name)

        @staticmethod
        def array(P: np.ndarray, dtype: Any = None) -> np.ndarray:
            copy = np.array(P, dtype=dtype)
            alive[0] += 1
            alive[1] = max(alive)
            weakref.finalize(copy, lambda: alive.__setitem__(0, alive[0] - 1))
            return copy

    work = beside.whole_covariance_work

    def slow(P: np.ndarray, check: bool, ids: Any, pending: Any = None) -> Any:
        time.sleep(0.02)
        return work(P, check, ids, pending)

    monkeypatch.setattr(beside, "np", Counting())
    monkeypatch.setattr(beside, "whole_covariance_work", slow)
    records = every_event(replay(large))
    assert sum(r.correlation is not None and r.correlation.dim >= 128 for r in records) >= 4
    assert alive[1] <= 2  # the one the thread reads, and the next one's
