"""A replay's plain updates written as columns (``EventRows.takes_updates``) record and
judge the same as their records: every entity of the recording, across sends, in a map
that grows, in a large map, around a warning, with --detail and with times; the NIS
count of the run; where a run that stopped got to."""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
from conftest import entity_rows
from simulated import classic_run
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core import correlation
from ekfviz.core import records as records_module
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Control, EventKind, EventRows, LogEvent, Sighting
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.evaluation.consistency import Consistency
from ekfviz.io.classic import format_classic
from ekfviz.io.extended import format_extended, read_log
from ekfviz.runner.replay import replay
from ekfviz.runner.run import run
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, classic_controls, simulate
from ekfviz.viz.layers import pending
from ekfviz.viz.recorder import Recorder


@pytest.fixture(autouse=True)
def _correlation_at_most_every_25_steps(monkeypatch: pytest.MonkeyPatch) -> None:
    """A small map takes its correlation at every update of a run's first 1000 steps
    (those updates are records): here from step 10 on every 25 steps."""
    monkeypatch.setattr(correlation, "EVERY_UPDATE_STEPS", 10)


def events(
    steps: int,
    landmarks_xy: FloatArray = CLASSIC_LANDMARKS_XY,
    *,
    timed: bool = False,
    first_seen: int = 0,
    zero_range_at: int | None = None,
) -> list[LogEvent]:
    """A simulated run (see simulated.classic_run)."""
    return classic_run(
        steps, landmarks_xy, seed=5, timed=timed, first_seen=first_seen,
        zero_range_at=zero_range_at,
    )  # fmt: skip


def record(
    path: Path,
    log: list[LogEvent],
    updates: bool,
    *,
    detail: bool = False,
    truth: GroundTruth | None = None,
) -> Path:
    """Replay ``log`` into a recording, its updates as rows or as records (its predicts
    as rows either way), with the true landmarks if given."""
    stream = rr.RecordingStream("test_update_rows")
    stream.save(str(path))
    recorder = Recorder(stream, blueprint=False, detail=detail, truth=truth)
    rows = recorder.pending.event_rows()
    rows.takes_updates = updates
    run(log, FilterParams(), [recorder.log_record], event_rows=rows)
    recorder.finish()
    stream.flush()
    return path


def every_entity(path: Path) -> dict[str, list[dict[str, object]]]:
    """Every entity's rows, temporal and static (not the recording's start time)."""
    from rerun.chunk import RrdReader

    entities = {chunk.entity_path for chunk in RrdReader(path).stream()} - {"/__properties"}
    found: dict[str, list[dict[str, object]]] = defaultdict(list)
    for entity in sorted(entities):
        found[entity] = entity_rows(path, entity) + entity_rows(path, entity, static=True)
    return found


def written_as_rows(log: list[LogEvent]) -> int:
    """How many updates of ``log`` a replay writes as rows."""
    rows = EventRows()
    rows.takes_updates = True
    for _ in replay(log, FilterParams(), event_rows=rows):
        pass
    return sum(update is not None for update in rows.updates)


LARGE_MAP = np.random.default_rng(2).uniform(-5.0, 20.0, (40, 2))
CASES = {
    "one-send": (events(150), 4096, False),
    "many-sends": (events(150), 37, False),
    "growing-map": (events(120, first_seen=40), 50, False),
    "large-map": (events(60, LARGE_MAP), 64, False),
    "a-warning": (events(90, zero_range_at=30), 41, False),
    "detail": (events(80), 30, True),
    "timed": (events(90, timed=True), 50, False),
}
# the true landmarks alone (their errors are drawn at every update); see true_landmarks
TRUE_LANDMARKS = {
    "one-send": CLASSIC_LANDMARKS_XY,
    "growing-map": CLASSIC_LANDMARKS_XY[:4],  # two landmarks the truth does not know
    "large-map": LARGE_MAP,
    "detail": CLASSIC_LANDMARKS_XY,
}


@pytest.mark.parametrize("case", list(CASES))
def test_updates_as_rows_record_the_same_as_records(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """The recording does not depend on how the updates reach the recorder: every
    entity has the same rows, temporal and static, and most updates were rows."""
    log, flush_every, detail = CASES[case]
    monkeypatch.setattr(pending, "FLUSH_EVERY", flush_every)
    updates = sum(isinstance(event, Sighting) for event in log)
    assert written_as_rows(log) > updates // 2
    for truth in (None, true_landmarks(case)):
        a = every_entity(record(tmp_path / "a.rrd", log, False, detail=detail, truth=truth))
        b = every_entity(record(tmp_path / "b.rrd", log, True, detail=detail, truth=truth))
        assert a.keys() == b.keys()
        assert any("landmarks" in entity for entity in a)
        if truth is not None:
            assert any("landmark_error" in entity for entity in a)
            nees = [row for row in a.get("/metrics/nees", []) if "event" in row]
            assert truth.has_poses == bool(nees)  # the NEES, at the updates
        for entity in a:
            assert a[entity] == b[entity], entity


def true_landmarks(case: str) -> GroundTruth | None:
    """The truth of a case that has one: its landmarks, or its poses too."""
    if case == "many-sends":
        return simulated_truth(150)  # the NEES and the true path at every update
    if case == "a-warning":
        return simulated_truth(90, cut=60)  # the true poses end before the log
    xy = TRUE_LANDMARKS.get(case)
    if xy is None:
        return None
    return GroundTruth(ids=np.arange(1, len(xy) + 1, dtype=np.int64), landmarks_xy=np.array(xy))


@pytest.mark.parametrize("copies", ["compiled", "numpy"])
def test_an_update_row_holds_what_its_record_would(
    copies: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The replay yields no record for an update written as a row, and the row made a
    record is the record the replay would have yielded, map and observations alike, to
    the bit, whether the rows are copied by the compiled module or by numpy; the rows'
    maps stay read-only and what they were after their store was filled and replaced."""
    if copies == "numpy":
        monkeypatch.setattr(records_module, "_rows", None)
    elif not records_module.HAVE_ROW_COPIES:
        pytest.skip("the compiled row copies were not built (no C compiler)")
    log = events(60, first_seen=20)
    records = {r.event: r for r in replay(log, FilterParams())}
    rows = EventRows(4)  # grows past its first capacity
    rows.takes_updates = True
    kept = list(replay(log, FilterParams(), event_rows=rows))
    at_rows = set(rows.events)
    assert at_rows | {r.event for r in kept} == set(records)
    assert not at_rows & {r.event for r in kept}
    assert kept[-1].event == max(records)
    update_rows = [k for k, update in enumerate(rows.updates) if update is not None]
    assert len(update_rows) > 30
    for k in update_rows:
        made, reference = rows.update_record(k), records[rows.events[k]]
        assert made.kind is EventKind.UPDATE and made.line == reference.line
        for name in ("pose", "pose_cov", "landmark_ids", "landmarks_xy", "landmark_covs"):
            np.testing.assert_array_equal(getattr(made, name), getattr(reference, name), name)
        _, _, xy, covs = rows.updates[k]  # type: ignore[misc]
        assert not xy.flags.writeable and not covs.flags.writeable
        assert made.observations is not None and reference.observations is not None
        for name in ("ids", "z", "z_pred", "innovation", "S", "nis", "initialised", "skipped"):
            np.testing.assert_array_equal(
                getattr(made.observations, name), getattr(reference.observations, name), name
            )
    # the map grew at step 20: the update that grew it is a record, not a row
    grown = next(r for r in kept if r.n_landmarks == 6)
    assert grown.kind is EventKind.UPDATE and grown.event not in at_rows


@pytest.mark.skipif(
    not records_module.HAVE_ROW_COPIES, reason="no compiled row copies (no C compiler)"
)
def test_the_compiled_row_copy_takes_what_numpy_takes() -> None:
    """``_rows.copy_row`` copies the pose, its covariance and the landmarks' means and
    2x2 diagonal blocks out of buffers of a larger capacity, as numpy's indexing does,
    and refuses buffers it cannot read that way."""
    from ekfviz.core._rows import copy_row

    rng = np.random.default_rng(3)
    capacity, n = 17, 5  # the state is 3 + 2 * 5 = 13 of the 17
    x, P = rng.normal(size=capacity), rng.normal(size=(capacity, capacity))
    poses, pose_covs = np.full((4, 3), np.nan), np.full((4, 3, 3), np.nan)
    xy, covs = np.full((9, 2), np.nan), np.full((9, 2, 2), np.nan)
    copy_row(x, P, poses, pose_covs, 2, xy, covs, 3, n)
    np.testing.assert_array_equal(poses[2], x[:3])
    np.testing.assert_array_equal(pose_covs[2], P[:3, :3])
    np.testing.assert_array_equal(xy[3:8], x[3:13].reshape(n, 2))
    for k in range(n):
        at = 3 + 2 * k
        np.testing.assert_array_equal(covs[3 + k], P[at : at + 2, at : at + 2])
    assert np.isnan(poses[[0, 1, 3]]).all() and np.isnan(xy[[0, 1, 2, 8]]).all()
    with pytest.raises(ValueError, match="square"):
        copy_row(x, np.zeros((capacity, capacity + 2)), poses, pose_covs, 0, xy, covs, 0, 1)
    with pytest.raises(ValueError, match="map_xy"):
        copy_row(x, P, poses, pose_covs, 0, xy, covs, 6, n)  # beyond the map's room
    with pytest.raises(ValueError, match="poses"):
        copy_row(x, P, poses, pose_covs, 4, xy, covs, 0, 0)
    with pytest.raises(ValueError, match="at least 0"):
        copy_row(x, P, poses, pose_covs, -1, xy, covs, 0, 0)
    with pytest.raises(ValueError, match="x"):
        copy_row(x[:12], P, poses, pose_covs, 0, xy, covs, 0, n)  # 12 < 3 + 2 * 5


def simulated_truth(steps: int, cut: int | None = None) -> GroundTruth:
    """The truth of :func:`events` (its landmarks and true poses), the poses after step
    ``cut`` left out."""
    controls = np.tile(classic_controls(), (steps // 29 + 1, 1))[:steps]
    sim = simulate(controls, CLASSIC_LANDMARKS_XY, seed=5)
    poses = sim.poses_xytheta if cut is None else sim.poses_xytheta[: cut + 1]
    return GroundTruth(ids=sim.landmark_ids, landmarks_xy=sim.landmarks_xy, poses_xytheta=poses)


@pytest.mark.parametrize(
    ("cut", "truth_steps"),
    [(None, 200), (150, 200), (None, 260)],
    ids=["every-pose", "poses-end-early", "poses-past-the-end"],
)
def test_the_consistency_counts_are_the_same_with_updates_as_rows(
    cut: int | None, truth_steps: int
) -> None:
    """The run's NIS and NEES counts see every update, the rows' through ``watch`` (each
    once, whether dropped, made records or settled) and the records' one by one; the
    updates past the truth's last pose are counted as such, and so are the true poses
    past the run's last step (a truth of a longer run: its NEES is said to be suspect)."""
    log = events(200, zero_range_at=50)
    truth = simulated_truth(truth_steps, cut)
    alone = Consistency(truth)
    for r in replay(log, FilterParams()):
        alone.add(r)
    rows = EventRows(16)
    rows.takes_updates = True
    counted = Consistency(truth)
    rows.watch = counted.add_rows
    for n, r in enumerate(replay(log, FilterParams(), event_rows=rows)):
        counted.add(r)
        if n % 3 == 0:
            rows.drop(len(rows) // 2)
        if n % 7 == 0 and len(rows) > 2:
            rows.records(len(rows) - 2, r)
        if n % 5 == 0:
            rows.settle()
    rows.settle()
    rows.drop(len(rows))
    assert counted.nis.total == alone.nis.total == 200
    assert counted.to_json() == alone.to_json()
    assert alone.nees.total == (201 if cut is None else 151)
    assert alone.without_true_pose == (0 if cut is None else 50)
    assert alone.unused_true_poses == truth_steps - 200
    said = [line for line in alone.summary() if "past the run's last step (200)" in line]
    assert len(said) == (truth_steps > 200)


def test_a_run_that_stops_after_an_update_row_keeps_that_map() -> None:
    """Where a replay stops after a predict written as a row after an update written as
    a row, the run's last event is that predict, with the map of that update."""
    log = events(30)
    bad_at = next(k for k, e in enumerate(log) if isinstance(e, Control) and k > 30) + 1
    broken = [*log[:bad_at], Sighting(999, np.array([1, 1]), np.array([[0.1, 5.0]] * 2))]
    rows = EventRows()
    rows.takes_updates = True
    kept = []
    with pytest.raises(Exception, match="same landmark twice"):
        for r in replay(broken, FilterParams(), event_rows=rows):
            kept.append(r)
    assert rows.updates[-1] is None and rows.updates[-2] is not None  # update, predict
    last = rows.latest(kept[-1])
    reference = list(replay(log[:bad_at], FilterParams()))[-1]
    assert last is not None and last.kind is EventKind.PREDICT and last.event == reference.event
    for name in ("pose", "pose_cov", "landmarks_xy", "landmark_covs"):
        np.testing.assert_array_equal(getattr(last, name), getattr(reference, name), name)
    rows.drop(len(rows))  # forgotten: the newest row and its map are kept
    last = rows.latest(kept[-1])
    assert last is not None
    np.testing.assert_array_equal(last.landmarks_xy, reference.landmarks_xy)


@pytest.mark.parametrize("extended", [False, True], ids=["classic", "extended"])
def test_the_command_reports_the_nis_of_every_update(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, extended: bool
) -> None:
    """``ekfviz replay`` of a log without truth (its updates written as rows) reports
    the NIS of every update, as counted from the records of a plain replay. An extended
    log could hold scans, so the replay sets up the association for it: its updates by
    ids are as plain, and rows too."""
    log = events(300)
    path = tmp_path / "run.txt"
    path.write_text(format_extended(log, None) if extended else format_classic(log, None))
    read = list(read_log(path))
    alone = Consistency()
    for r in replay(read, FilterParams()):
        alone.add(r)
    written: list[int] = []
    add_update = EventRows.add_update

    def counted(self: EventRows, event: int, *rest: Any) -> None:
        written.append(event)
        add_update(self, event, *rest)

    monkeypatch.setattr(EventRows, "add_update", counted)
    report = tmp_path / "report.json"
    result = CliRunner().invoke(
        app, ["replay", str(path), "--save", str(tmp_path / "run.rrd"), "--report", str(report)]
    )
    assert result.exit_code == 0, result.output
    assert len(written) > 250  # all but the records (the correlation's, the checks')
    nis = json.loads(report.read_text())["consistency"]["nis"]
    assert (nis["count"], nis["below"], nis["inside"], nis["above"]) == (
        alone.nis.total,
        alone.nis.below,
        alone.nis.inside,
        alone.nis.above,
    )
    assert alone.nis.total == 300


def test_a_signal_in_a_send_among_rows_leaves_the_stop_line_last(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C raises anywhere: where it raises in a send that falls due among the rows
    held, the line saying why the run stopped still comes at the newest event held
    (after every line of the events sent), not at the record before the rows."""
    from ekfviz.viz import style

    monkeypatch.setattr(pending, "FLUSH_EVERY", 2)  # a send due at the last row, at times
    path = tmp_path / "stopped.rrd"
    stream = rr.RecordingStream("test_update_rows")
    stream.save(str(path))
    recorder = Recorder(stream, blueprint=False)
    rows = recorder.pending.event_rows()
    rows.takes_updates = True
    send = Recorder._send_pending
    raised: list[bool] = []

    def interrupted(self: Recorder, series: bool = False) -> None:
        rows_held = self.pending.rows
        # a send among rows, at the last of them
        last = (
            rows_held is not None
            and self.pending.rows_held == len(rows_held) > 0
            and rows_held.events[-1] > 30
        )
        send(self, series)
        if not raised and last and sys._getframe(1).f_code.co_name == "hold_rows":
            raised.append(True)
            raise KeyboardInterrupt

    monkeypatch.setattr(Recorder, "_send_pending", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(events(200), FilterParams(), [recorder.log_record], event_rows=rows)
    monkeypatch.setattr(Recorder, "_send_pending", send)
    recorder.note("stopped here", level=rr.TextLogLevel.ERROR)
    recorder.finish()
    stream.flush()
    lines = entity_rows(path, f"/{style.LOG}")
    assert raised and len(lines) > 10
    assert "stopped here" in str(lines[-1]["TextLog:text"])
    assert lines[-1]["event"] == max(int(str(line["event"])) for line in lines)
