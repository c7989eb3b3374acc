"""A replay's predicts written as columns (EventRows) record the same as their records,
across sends, with the text log's joined lines, with times and when a run stops."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from conftest import entity_rows
from simulated import classic_run

from ekfviz.core.params import FilterParams
from ekfviz.core.records import Control, EventKind, EventRows, LogEvent, Sighting
from ekfviz.filters.ekf import EkfSlam
from ekfviz.runner.replay import replay
from ekfviz.runner.run import run
from ekfviz.viz import style
from ekfviz.viz.layers import pending
from ekfviz.viz.recorder import Recorder

ENTITIES = (
    style.ROBOT, style.TRAJECTORY, style.POSE_PREDICTED, style.POSE_UPDATED, style.LOG,
    style.LANDMARK_ELLIPSES, style.OBSERVATIONS, style.NIS,
)  # fmt: skip


def events(
    steps: int, timed: bool = False, only_controls_from: int | None = None
) -> list[LogEvent]:
    """A simulated classic run (see simulated.classic_run)."""
    return classic_run(steps, seed=3, timed=timed, only_controls_from=only_controls_from)


def record(path: Path, log: list[LogEvent], rows: bool) -> Path:
    """Replay ``log`` into a recording, its predicts as rows or as records."""
    stream = rr.RecordingStream("test_event_rows")
    stream.save(str(path))
    recorder = Recorder(stream, blueprint=False)
    event_rows = recorder.pending.event_rows() if rows else None
    run(log, FilterParams(), [recorder.log_record], event_rows=event_rows)
    recorder.finish()
    stream.flush()
    return path


def same_rows(a: Path, b: Path) -> None:
    for entity in ENTITIES:
        rows_a, rows_b = entity_rows(a, f"/{entity}"), entity_rows(b, f"/{entity}")
        assert rows_a == rows_b, entity
        assert rows_a or entity == style.NIS, entity  # the comparison saw data


@pytest.mark.parametrize(
    ("flush_every", "timed", "only_controls_from"),
    [(4096, False, None), (37, False, None), (64, False, 40), (50, True, 40)],
    ids=["one-send", "many-sends", "predicts-alone", "timed-thinned"],
)
def test_predicts_as_rows_record_the_same_as_records(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    flush_every: int,
    timed: bool,
    only_controls_from: int | None,
) -> None:
    """The recording does not depend on how the predicts reach the recorder: every entity
    has the same rows, sends cut at the same events (a short FLUSH_EVERY), a stretch of
    predicts with no update between, and a timestamped log whose predicts are thinned."""
    monkeypatch.setattr(pending, "FLUSH_EVERY", flush_every)
    log = events(150, timed, only_controls_from)
    same_rows(record(tmp_path / "a.rrd", log, False), record(tmp_path / "b.rrd", log, True))


def test_the_replay_yields_no_record_for_a_predict_written_as_a_row() -> None:
    """Only the plain predicts of the built-in filter become rows: the last event and the
    initialisation stay records, and a row holds the pose the record would have."""
    log = events(60)
    records = list(replay(log, FilterParams()))
    rows = EventRows(4)  # grows past its first capacity
    kept = list(replay(log, FilterParams(), event_rows=rows))
    predicts = {r.event: r for r in records if r.kind is EventKind.PREDICT}
    assert set(rows.events) | {r.event for r in kept} == {r.event for r in records}
    assert not set(rows.events) & {r.event for r in kept}
    assert kept[0].event == 0 and kept[-1].event == records[-1].event
    assert len(rows) > 50
    for k, event in enumerate(rows.events):
        np.testing.assert_array_equal(rows.poses[k], predicts[event].pose)
        np.testing.assert_array_equal(rows.pose_covs[k], predicts[event].pose_cov)
        assert rows.controls[k] == tuple(predicts[event].control.tolist())  # type: ignore[union-attr]
    newest = rows.events[-1]
    (as_record,) = rows.records(len(rows) - 1, kept[-2])  # the newest row, as a record
    assert as_record.event == newest and rows.events[-1] != newest
    np.testing.assert_array_equal(as_record.pose, predicts[newest].pose)
    np.testing.assert_array_equal(as_record.control, predicts[newest].control)


def test_a_run_that_stops_after_a_row_ends_at_that_predict() -> None:
    """Where a replay stops in an update after a predict written as a row, the run's last
    event is that predict (the stop line and the evaluation see it), not the update
    before it."""
    log = events(20)
    bad_at = next(k for k, e in enumerate(log) if isinstance(e, Control) and k > 10) + 1
    broken = [*log[:bad_at], Sighting(999, np.array([1, 1]), np.array([[0.1, 5.0]] * 2))]
    rows = EventRows()
    kept = []
    with pytest.raises(Exception, match="same landmark twice"):
        for r in replay(broken, FilterParams(), event_rows=rows):
            kept.append(r)
    last = rows.latest(kept[-1])
    assert last is not None and last.kind is EventKind.PREDICT
    assert last.line == log[bad_at - 1].line
    reference = list(replay(log[:bad_at], FilterParams()))[-1]
    np.testing.assert_array_equal(last.pose, reference.pose)
    assert last.landmark_ids.tolist() == reference.landmark_ids.tolist()


def test_a_plugged_filter_and_full_covariances_keep_a_record_per_event() -> None:
    """A protocol filter's predicts are never rows (its state is checked at every
    event)."""

    class Mine(EkfSlam):  # a protocol filter: make_filter is not EkfSlam itself
        pass

    rows = EventRows()
    kept = list(replay(events(20), FilterParams(), make_filter=Mine, event_rows=rows))
    assert len(rows) == 0 and sum(r.kind is EventKind.PREDICT for r in kept) == 20


def test_a_row_left_half_written_is_never_read() -> None:
    """A signal raised inside add() (Ctrl-C becomes an exception anywhere) leaves a row
    with some columns written: it does not count, and dropping the rows clears it."""
    x, P = np.arange(5.0), np.eye(5)
    rows = EventRows(2)
    for event in (1, 3, 5):
        rows.add(event, event, 10 + event, None, (1.0, 0.0), x + event, P)
    rows.events.append(7)  # the half-written row: its event only
    rows.steps.append(7)
    assert len(rows) == 3
    before = next(iter(replay(events(3), FilterParams())))
    latest = rows.latest(before)
    assert latest is not None and latest.event == 5 and latest.line == 15
    rows.drop(3)
    assert len(rows) == 0 and rows.events == [] and rows.steps == []
    assert rows.latest(before) is not None and rows.latest(before).event == 5  # type: ignore[union-attr]
    rows.add(9, 9, 19, None, (1.0, 0.0), x, P)
    assert (rows.events, rows.steps, rows.lines) == ([9], [9], [19])
