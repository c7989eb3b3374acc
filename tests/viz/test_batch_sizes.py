"""What the recorder writes for a run does not depend on how its events come: in
batches of any size from the replay, with sends after any number of events; and where a
run is cut short, its stop line comes after everything it recorded."""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from conftest import entity_rows, every_entity_rows
from simulated import classic_run, classic_truth

from ekfviz.core.params import FilterParams
from ekfviz.core.records import LogEvent
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.runner.replay import replay
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY
from ekfviz.viz import style
from ekfviz.viz.layers import pending
from ekfviz.viz.recorder import Recorder

LARGE_MAP = np.random.default_rng(2).uniform(-5.0, 20.0, (40, 2))


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


def simulated_truth(steps: int, cut: int | None = None) -> GroundTruth:
    """The truth of :func:`events`."""
    return classic_truth(steps, seed=5, cut=cut)


def landmarks_only(xy: FloatArray) -> GroundTruth:
    return GroundTruth(ids=np.arange(1, len(xy) + 1, dtype=np.int64), landmarks_xy=np.array(xy))


# a log, whether every ellipse is drawn (--detail), its truth (None: none)
CASES = {
    "plain": (lambda: events(150), False, lambda: landmarks_only(CLASSIC_LANDMARKS_XY)),
    "with-true-poses": (lambda: events(150), False, lambda: simulated_truth(150)),
    "growing-map": (
        lambda: events(120, first_seen=40),
        False,
        lambda: landmarks_only(CLASSIC_LANDMARKS_XY[:4]),
    ),
    "large-map": (lambda: events(60, LARGE_MAP), False, lambda: landmarks_only(LARGE_MAP)),
    "a-warning": (lambda: events(90, zero_range_at=30), False, lambda: simulated_truth(90, 60)),
    "detail": (lambda: events(80), True, lambda: landmarks_only(CLASSIC_LANDMARKS_XY)),
    "timed-thinned": (lambda: events(90, timed=True), False, lambda: None),
    "predicts-alone": (
        lambda: classic_run(150, seed=3, only_controls_from=40),
        False,
        lambda: None,
    ),
}


def record(
    path: Path, log: list[LogEvent], batch_events: int, detail: bool, truth: GroundTruth | None
) -> Path:
    """Replay ``log`` in batches of ``batch_events`` into a recording."""
    stream = rr.RecordingStream("test_batch_sizes")
    stream.save(str(path))
    recorder = Recorder(stream, blueprint=False, detail=detail, truth=truth)
    for batch in replay(log, FilterParams(), batch_events=batch_events):
        recorder.log(batch)
    recorder.finish()
    stream.flush()
    return path


def every_entity(path: Path) -> dict[str, list[dict[str, object]]]:
    """Every entity's rows, temporal and static (not the recording's start time), each
    without its empty columns (a chunk has a column for a component some other row of
    it holds: how the rows fell into chunks is not what they hold)."""
    temporal, static = every_entity_rows(path), every_entity_rows(path, static=True)
    found: dict[str, list[dict[str, object]]] = defaultdict(list)
    for entity in sorted((temporal.keys() | static.keys()) - {"/__properties"}):
        rows = temporal.get(entity, []) + static.get(entity, [])
        found[entity] = [{k: v for k, v in row.items() if v is not None} for row in rows]
    return found


# a plain run by default; the other kinds under make test-all
FAST_CASES = {"plain"}


@pytest.mark.parametrize(
    "case", [c if c in FAST_CASES else pytest.param(c, marks=pytest.mark.slow) for c in CASES]
)
def test_the_recording_is_the_same_whatever_the_batches(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """Every entity has the same rows, temporal and static, whether the replay hands
    over its events in one batch or a few at a time, with sends that come once or every
    few events, cut anywhere in the replay's batches (the text log joins a predict's
    line to its update's within a send: the send's length is the recording's own)."""
    make_log, detail, make_truth = CASES[case]
    log, truth = make_log(), make_truth()
    for flush_every, sizes in ((4096, (7, 1)), (37, (7, 300)), (13, (1,))):
        monkeypatch.setattr(pending, "FLUSH_EVERY", flush_every)
        whole_path = tmp_path / f"whole-{flush_every}.rrd"
        whole = every_entity(record(whole_path, log, 10**6, detail, truth))
        assert any("landmarks" in entity for entity in whole)
        if truth is not None:
            assert any("landmark_error" in entity for entity in whole)
            nees = [row for row in whole.get("/metrics/nees", []) if "event" in row]
            assert truth.has_poses == bool(nees)  # the NEES, at the updates
        for size in sizes:
            path = tmp_path / f"{size}-{flush_every}.rrd"
            cut = every_entity(record(path, log, size, detail, truth))
            assert cut.keys() == whole.keys()
            for entity in whole:
                assert cut[entity] == whole[entity], (entity, size, flush_every)


def test_a_signal_in_a_send_leaves_the_stop_line_last(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C raises anywhere: where it raises in a send that falls due inside a batch,
    the events after it in that batch are still held and recorded, and the line saying
    why the run stopped comes at the newest event (after every line of the events)."""
    monkeypatch.setattr(pending, "FLUSH_EVERY", 16)  # sends due inside every batch
    path = tmp_path / "stopped.rrd"
    stream = rr.RecordingStream("test_batch_sizes")
    stream.save(str(path))
    recorder = Recorder(stream, blueprint=False)
    send = Recorder._send
    raised: list[int] = []

    def interrupted(self: Recorder, batch: object, series: bool = False) -> None:
        send(self, batch, series)  # type: ignore[arg-type]
        if not raised and self.pending.count and sys._getframe(1).f_code.co_name == "_log_admitted":
            raised.append(self.pending.count)  # events held after it
            raise KeyboardInterrupt

    monkeypatch.setattr(Recorder, "_send", interrupted)
    with pytest.raises(KeyboardInterrupt):
        for batch in replay(events(200), FilterParams(), batch_events=100):
            recorder.log(batch)
    monkeypatch.setattr(Recorder, "_send", send)
    recorder.note("stopped here", level=rr.TextLogLevel.ERROR)
    recorder.finish()
    stream.flush()
    lines = entity_rows(path, f"/{style.LOG}")
    assert raised and raised[0] > 0 and len(lines) > 10
    assert "stopped here" in str(lines[-1]["TextLog:text"])
    newest = max(int(str(line["event"])) for line in lines)
    assert lines[-1]["event"] == newest
    robot = entity_rows(path, f"/{style.ROBOT}")
    assert int(str(robot[-1]["event"])) == newest  # the held events were recorded
