"""The one form of a run's events (ekfviz.core.batch): however a run's events are cut into
batches, joined, taken apart or viewed one at a time, each event holds the same state; a
batch holds what the filter's state was after each event, and no more than that."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from simulated import classic_run

from ekfviz.core.batch import (
    INIT,
    KINDS,
    PREDICT,
    UPDATE,
    BatchBuilder,
    EventBatch,
    Extras,
    StateParts,
)
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Control, LogEvent, Observations, Sighting
from ekfviz.filters.ekf import EkfSlam
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import loop

LARGE_MAP = np.random.default_rng(2).uniform(-5.0, 20.0, (40, 2))
# logs that meet every kind of event and extra: a map that grows, a skipped observation
# (a warning), times, a large map; each replayed once (see runs)
LOGS = {
    "plain": lambda: classic_run(150, seed=5),
    "growing-map": lambda: classic_run(120, seed=5, first_seen=40),
    "a-warning": lambda: classic_run(90, seed=5, zero_range_at=30),
    "timed": lambda: classic_run(90, seed=5, timed=True),
    "large-map": lambda: classic_run(60, LARGE_MAP, seed=5),
    "predicts-alone": lambda: classic_run(80, seed=3, only_controls_from=40),
}
_RUNS: dict[str, tuple[list[LogEvent], EventBatch]] = {}


def run(name: str) -> tuple[list[LogEvent], EventBatch]:
    """A log of ``LOGS`` and its replay's events in one batch."""
    if name not in _RUNS:
        log = LOGS[name]()
        _RUNS[name] = log, EventBatch.joined(replay(log, FilterParams()))
    return _RUNS[name]


def columns(batch: EventBatch) -> list[tuple[Any, ...]]:
    """What each event of ``batch`` holds, as bytes and plain values (NaN compares equal
    as bytes): the one definition the tests compare batches by."""
    out = []
    for record in batch:
        observations = record.observations
        extra = (record.warnings, record.covariance, record.association)
        matrices = (record.correlation, record.path_xytheta, record.full_cov)
        out.append((
            record.event, record.step, record.kind, record.line, record.time,
            record.pose.tobytes(), record.pose_cov.tobytes(),
            None if record.control is None else record.control.tobytes(),
            record.landmark_ids.tolist(), record.landmarks_xy.tobytes(),
            record.landmark_covs.tobytes(),
            None if observations is None else tuple(
                getattr(observations, name).tobytes()
                for name in ("ids", "z", "z_pred", "innovation", "S", "nis", "initialised",
                             "skipped")
            ),
            extra,
            tuple(None if m is None else np.asarray(getattr(m, "matrix", m)).tobytes()
                  for m in matrices),
        ))  # fmt: skip
    return out


def pieces(batch: EventBatch, cuts: list[int]) -> Iterator[EventBatch]:
    """``batch`` cut at ``cuts`` (sorted event rows), in order."""
    bounds = [0, *cuts, len(batch)]
    for lo, hi in itertools.pairwise(bounds):
        yield batch[lo:hi]


@settings(max_examples=60, deadline=None)
@given(name=st.sampled_from(sorted(LOGS)), data=st.data())
def test_a_run_cut_anywhere_and_joined_is_the_same_run(name: str, data: st.DataObject) -> None:
    _, whole = run(name)
    cuts = sorted(data.draw(st.sets(st.integers(0, len(whole)), max_size=8)))
    parts = list(pieces(whole, cuts))
    expected = columns(whole)
    assert sum(len(part) for part in parts) == len(whole)
    assert columns(EventBatch.joined(parts)) == expected
    start = 0
    for part in parts:  # each piece alone holds its own events whole
        assert columns(part) == expected[start : start + len(part)]
        start += len(part)


@settings(max_examples=25, deadline=None)
@given(name=st.sampled_from(sorted(LOGS)), size=st.integers(1, 300))
def test_the_replays_batches_of_any_size_hold_the_same_events(name: str, size: int) -> None:
    log, whole = run(name)
    batches = list(replay(log, FilterParams(), batch_events=size))
    assert len(batches[0]) == 1 and batches[0].events.tolist() == [0]  # a batch of its own
    assert all(len(batch) <= size for batch in batches)
    assert columns(EventBatch.joined(batches)) == columns(whole)


@pytest.mark.parametrize("name", sorted(LOGS))
def test_an_event_viewed_alone_is_what_the_columns_hold(name: str) -> None:
    _, batch = run(name)
    assert batch.events.tolist() == list(range(len(batch)))
    for row in range(len(batch)):
        record = batch.event(row)
        assert record.kind is KINDS[int(batch.kinds[row])]
        assert (record.event, record.step, record.line) == (
            int(batch.events[row]), int(batch.steps[row]), int(batch.lines[row])
        )  # fmt: skip
        time = float(batch.times[row])
        assert record.time == (None if math.isnan(time) else time)
        assert np.array_equal(record.pose, batch.poses[row])
        assert np.array_equal(record.pose_cov, batch.pose_covs[row])
        assert record.n_landmarks == int(batch.n_landmarks[row])
        assert (record.observations is None) == (not batch.observed.present[row])
        assert record.warnings == batch.extra(row).warnings
    assert batch.event(-1).event == batch.last.event == len(batch) - 1
    with pytest.raises(IndexError):
        batch.event(len(batch))
    # the rows taken are the rows viewed
    rows = np.arange(0, len(batch), 3)
    assert columns(batch.take(rows)) == [columns(batch)[k] for k in rows.tolist()]


@pytest.mark.parametrize("name", ["plain", "growing-map"])
def test_each_map_is_stored_once_and_a_predict_keeps_the_map_before_it(name: str) -> None:
    """A predict moves the pose alone: it holds the map of the event before it, stored
    once (a map a batch, at most, beside the updates' own: a batch that starts with a
    predict holds the map before it again)."""
    log, batch = run(name)
    for part in replay(log, FilterParams(), batch_events=50):
        updates = int(np.count_nonzero(part.kinds != PREDICT))
        assert len(part.maps) == updates + bool(part.kinds[0] == PREDICT)
        predicts = np.flatnonzero(part.is_predict[1:]) + 1
        assert np.array_equal(part.map_of[predicts], part.map_of[predicts - 1])
    maps = [batch.event(k).landmarks_xy.tobytes() for k in range(len(batch))]
    assert all(maps[k] == maps[k - 1] for k in np.flatnonzero(batch.is_predict).tolist())
    # one ids array for as long as the map's ids do not change
    assert len(batch.maps.id_sets) == len({tuple(ids.tolist()) for ids in batch.maps.id_sets})
    expected_sets = 2 if name == "growing-map" else 1
    assert len(batch.maps.id_sets) == expected_sets


def test_a_batch_is_read_only() -> None:
    _, batch = run("plain")
    for column in (batch.events, batch.poses, batch.pose_covs, batch.maps.xy,
                   batch.maps.covs, batch.observed.nis, batch.controls):  # fmt: skip
        assert not column.flags.writeable
    record = batch.event(5)
    with pytest.raises(ValueError, match="read-only"):
        record.pose[0] = 1.0


def test_a_logs_events_and_an_updates_observations_cannot_be_changed() -> None:
    events, batch = run("plain")
    control = next(e for e in events if isinstance(e, Control))
    sighting = next(e for e in events if isinstance(e, Sighting))
    observations = batch.event(int(np.flatnonzero(batch.kinds == UPDATE)[0])).observations
    assert observations is not None
    for record, name in ((control, "d"), (sighting, "z"), (observations, "nis")):
        with pytest.raises(AttributeError):
            setattr(record, name, 0.0)
    with pytest.raises(ValueError, match="read-only"):
        observations.nis[0] = 1.0


def drive(
    events: list[LogEvent], full_cov: bool
) -> tuple[list[tuple[np.ndarray, np.ndarray, list[int]]], EventBatch]:
    """The built-in filter's x, P and ids after every event of ``events`` (driven
    directly), and its replay's events in one batch."""
    ekf = EkfSlam()
    states = [(ekf.x.copy(), ekf.P.copy(), ekf.landmark_ids)]
    for k, event in enumerate(events):
        if isinstance(event, Control):
            ekf.predict(event.d, event.alpha)
        else:
            assert isinstance(event, Sighting)
            ekf.observe(event.ids, event.z)
        if k or isinstance(event, Control):  # (a first observation is the initialisation)
            states.append((ekf.x.copy(), ekf.P.copy(), ekf.landmark_ids))
        else:
            states[0] = (ekf.x.copy(), ekf.P.copy(), ekf.landmark_ids)
    return states, EventBatch.joined(replay(events, full_cov=full_cov))


@pytest.mark.parametrize("full_cov", [False, True])
def test_the_events_hold_the_filters_state_after_each(full_cov: bool) -> None:
    """Each event's pose, pose covariance and map are the filter's x and P blocks after
    it, to the bit, while the map grows past the buffers' first capacity; the whole P is
    kept only where asked for; the maps kept earlier stay what they were."""
    events = classic_run(45, loop(steps=4, landmarks=24).landmarks_xy, seed=4, first_seen=20)
    states, batch = drive(events, full_cov)
    assert len(states) == len(batch)
    for record, (x, P, ids) in zip(batch, states, strict=True):
        n = len(ids)
        assert np.array_equal(record.pose, x[:3]) and np.array_equal(record.pose_cov, P[:3, :3])
        assert record.landmark_ids.tolist() == ids
        assert np.array_equal(record.landmarks_xy.reshape(-1), x[3:])
        for i in range(n):
            block = slice(3 + 2 * i, 5 + 2 * i)
            assert np.array_equal(record.landmark_covs[i], P[block, block])
        if full_cov:
            assert record.full_cov is not None and np.array_equal(record.full_cov, P)
        else:
            assert record.full_cov is None
    assert not full_cov or all(batch.extra(k).full_cov is not None for k in range(len(batch)))


def test_a_long_run_keeps_no_covariance_of_the_whole_state() -> None:
    """Memory: a run's batches hold 3x3 pose covariances and 2x2 marginals, never a
    (3+2N)^2 covariance, unless asked for."""
    _, batch = run("large-map")
    assert all(extra.full_cov is None for extra in batch.extras.values())
    stored = sum(a.nbytes for a in (batch.poses, batch.pose_covs, batch.maps.xy, batch.maps.covs))
    n = 3 + 2 * int(batch.n_landmarks[-1])
    assert stored < len(batch) * n * n * 8 / 4


class _Cut:
    """A control whose (d, alpha) cannot be read: Ctrl-C, as it may raise anywhere."""

    def __iter__(self) -> Iterator[float]:
        raise KeyboardInterrupt


def test_an_event_cut_short_by_a_signal_is_never_read() -> None:
    """Ctrl-C raises anywhere, inside an append too: the event cut short does not count,
    and the next one takes its place whole."""
    x = np.arange(7.0)
    P = np.eye(7)
    builder = BatchBuilder()
    for event in range(3):
        builder.add_state(x + event, P, event=event, step=event, kind=PREDICT, line=event,
                          control=(1.0, 0.0), extras=Extras(warnings=(f"w{event}",)))  # fmt: skip
    with pytest.raises(KeyboardInterrupt):
        builder.add_state(x, P, event=99, step=99, kind=UPDATE, line=99, control=_Cut())  # type: ignore[arg-type]
    assert len(builder) == 3
    builder.add_state(x + 3, P, event=3, step=3, kind=PREDICT, line=3, control=(2.0, 0.5))
    batch = builder.build()
    assert batch.events.tolist() == [0, 1, 2, 3] and batch.lines.tolist() == [0, 1, 2, 3]
    assert batch.poses[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0]
    assert batch.controls.tolist()[-1] == [2.0, 0.5]
    assert sorted(batch.extras) == [0, 1, 2]
    assert len(builder) == 0 and len(builder.build()) == 0


def test_a_state_handed_in_is_one_event_of_the_batch() -> None:
    """The builder's API for a filter that hands in x, P, ids and what it observed (a
    check's events), one event at a time: copies, numbered as given."""
    rng = np.random.default_rng(1)
    builder = BatchBuilder()
    ekf = EkfSlam()
    observations = ekf.observe([4, 7], np.array([[0.1, 3.0], [-0.4, 5.0]]))
    x, P = ekf.x.copy(), ekf.P.copy()
    builder.add_state(x, P, landmark_ids=[4, 7], event=0, step=0, kind=INIT, line=1,
                      observations=observations)  # fmt: skip
    x[0] += 1.0  # the caller goes on changing its state
    builder.add_state(x, P, landmark_ids=[4, 7], event=1, step=1, kind=PREDICT, line=2,
                      control=(1.0, 0.0))  # fmt: skip
    batch = builder.build()
    assert batch.poses[:, 0].tolist() == [ekf.x[0], ekf.x[0] + 1.0]
    assert batch.maps.id_sets[0].tolist() == [4, 7] and len(batch.maps.id_sets) == 1
    first = batch.event(0)
    assert first.observations is not None
    assert np.array_equal(first.observations.nis, observations.nis, equal_nan=True)
    assert first.observations.initialised.tolist() == [True, True]
    assert batch.event(1).observations is None and batch.event(1).control is not None
    with pytest.raises(ValueError, match="expected x of length 3\\+2N"):
        builder.add_state(rng.normal(size=4), np.eye(4), event=2, step=2, kind=PREDICT)
    parts = StateParts.of(ekf.x, ekf.P)
    assert parts.landmark_ids.tolist() == [1, 2]  # 1..N without ids


@pytest.mark.parametrize("shared", [3, 2, 0])
def test_each_updates_observations_are_read_back_shared_arrays_or_not(shared: int) -> None:
    """A batch's observations are each update's own, to the bit, whether its updates
    share their ids and flags (a classic log's lines: one array each) or not."""
    ekf = EkfSlam()
    ekf.observe([1, 2, 3], np.array([[0.1, 3.0], [-0.4, 5.0], [0.9, 2.0]]))
    ids = np.array([1, 2, 3])
    lines = [np.array([[0.1 + k / 50, 3.0], [-0.4, 5.0 - k / 10], [0.9, 2.0]]) for k in range(3)]
    builder = BatchBuilder()
    found = []
    for k, z in enumerate(lines):
        line_ids = ids if k < shared else np.array([3, 1, 2]) if k % 2 else ids.copy()
        observations = ekf.observe(line_ids, z if k < shared else z[[2, 0, 1]])
        found.append(observations)
        builder.add(ekf.state_parts(), event=k, step=k, kind=UPDATE, observations=observations)
    builder.add(ekf.state_parts(), event=3, step=4, kind=PREDICT, control=(1.0, 0.0))
    batch = builder.build()
    assert batch.event(3).observations is None
    for row, observations in enumerate(found):
        read = batch.event(row).observations
        assert read is not None
        for name in (*Observations._fields, "z_pred", "innovation", "S", "nis"):
            assert getattr(read, name).tobytes() == getattr(observations, name).tobytes(), name


def test_joined_batches_share_what_their_events_share() -> None:
    """Joined, the batches of a replay keep one map where their events' maps are the
    same arrays (the last map of a batch, carried to the next)."""
    log = LOGS["plain"]()
    batches = list(replay(log, FilterParams(), batch_events=10))
    joined = EventBatch.joined(batches)
    assert len(joined.maps.id_sets) == 1
    assert columns(joined) == columns(run("plain")[1])
    assert EventBatch.joined([]).events.tolist() == []
    assert len(every_event(batches)) == len(joined) == len(log)  # (the first: event 0)
