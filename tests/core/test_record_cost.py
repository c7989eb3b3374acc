"""The records of the built-in filter, made without per-field checks: the same as
``snapshot`` of its state, every field set, nothing shared that can change."""

from __future__ import annotations

import dataclasses

import numpy as np

from ekfviz.core.records import EventKind, EventRecord, kept_record, snapshot
from ekfviz.filters.ekf import EkfSlam
from ekfviz.runner.replay import replay
from ekfviz.sim.scenarios import classic


def _same(a: EventRecord, b: EventRecord) -> None:
    for field in dataclasses.fields(EventRecord):
        left, right = getattr(a, field.name), getattr(b, field.name)
        if isinstance(left, np.ndarray):
            assert isinstance(right, np.ndarray), field.name
            assert left.dtype == right.dtype and left.shape == right.shape, field.name
            np.testing.assert_array_equal(left, right, err_msg=field.name)
            assert not left.flags.writeable, field.name
        else:
            assert left == right, field.name


def test_kept_record_sets_every_field_as_the_dataclass_does() -> None:
    pose = np.array([1.0, 2.0, 0.5])
    arrays = (pose, np.eye(3), np.array([4], dtype=np.int64), np.ones((1, 2)), np.ones((1, 2, 2)))
    for array in arrays:
        array.setflags(write=False)
    made = kept_record(3, 2, EventKind.PREDICT, 7, *arrays, None, None, None, 1.5, ("w",))
    expected = EventRecord(3, 2, EventKind.PREDICT, 7, *arrays, time=1.5, warnings=("w",))
    # every slot is set (a field added to EventRecord but not to kept_record would raise)
    assert made == expected
    assert dataclasses.replace(made, line=8).line == 8
    try:
        made.line = 9  # type: ignore[misc]
    except dataclasses.FrozenInstanceError:
        pass
    else:
        raise AssertionError("a record can be changed")


def test_filter_records_equal_snapshots_of_its_state_and_stay_as_made() -> None:
    events = classic().run(seed=3).events
    ekf = EkfSlam()
    records = []
    for event, record in enumerate(replay(events, slam=ekf), start=0):
        records.append((record, ekf.x.copy()))
        again = snapshot(
            ekf.x, ekf.P, event=record.event, step=record.step, kind=record.kind,
            line=record.line, landmark_ids=np.array(ekf.landmark_ids), time=record.time,
            control=record.control, observations=record.observations,
            warnings=record.warnings, covariance=record.covariance,
        )  # fmt: skip
        _same(dataclasses.replace(record, correlation=None), again)
        assert event == record.event
    # the landmark means a predict's record shares with its update's stay what they were
    # when the later updates moved the map
    for record, x in records:
        np.testing.assert_array_equal(record.pose, x[:3])
        np.testing.assert_array_equal(record.landmarks_xy.reshape(-1), x[3:])
    moved = [r.landmarks_xy for r, _ in records if r.kind is EventKind.UPDATE]
    assert len({id(m) for m in moved}) == len(moved)  # a fresh copy at every update


def test_update_records_hold_the_states_blocks_as_the_map_and_its_buffers_grow() -> None:
    """A record's pose block, landmark marginals and means are copies of P's and x's
    blocks, also after the buffers grew (new arrays: the kept views are made again)."""
    slam = EkfSlam()
    rng = np.random.default_rng(4)
    for k in range(45):
        slam.predict(1.0, 0.1)
        ids = list(range(1, 2 + k))  # one more landmark each line: P grows, then moves
        z = np.column_stack([rng.uniform(-1, 1, len(ids)), rng.uniform(2, 10, len(ids))])
        slam.observe(ids, z)
        record = slam.record(event=2 * k + 2, step=k + 1, kind=EventKind.UPDATE)
        x, P = slam.x, slam.P
        assert np.array_equal(record.pose, x[:3]) and np.array_equal(record.pose_cov, P[:3, :3])
        for i in range(len(ids)):
            block = slice(3 + 2 * i, 5 + 2 * i)
            assert np.array_equal(record.landmark_covs[i], P[block, block])
            assert np.array_equal(record.landmarks_xy[i], x[block])
        assert not record.landmark_covs.flags.writeable
        slam.predict(0.5, 0.0)  # the predict's record: the pose moved, the map kept
        moved = slam.record(event=2 * k + 3, step=k + 2, kind=EventKind.PREDICT)
        assert np.array_equal(moved.pose_cov, slam.P[:3, :3])
        assert moved.landmark_covs is record.landmark_covs
