"""A replay saved through ekfviz.viz, read back from the .rrd and checked against the core."""

from __future__ import annotations

import itertools
import json
import socket
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun.blueprint as rrb
from commands import run_ekfviz
from conftest import entity_rows, rrd_verify

from ekfviz import __version__, readback, viz
from ekfviz.core.params import FilterParams
from ekfviz.core.records import EventKind, EventRecord, LogEvent, Sighting
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.errors import evaluate
from ekfviz.filters.ekf import HAVE_KERNEL
from ekfviz.io.classic import format_classic
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, classic_controls, simulate
from ekfviz.viz import provenance, style
from ekfviz.viz.blueprint import map_view

F32 = float(np.finfo(np.float32).eps)


@dataclass(frozen=True, slots=True)
class Run:
    rrd: Path
    log: Path
    records: tuple[EventRecord, ...]
    truth: GroundTruth


def write_log(path: Path, events: tuple[LogEvent, ...]) -> Path:
    """A classic log with CRLF line ends and tabs, the awkward case for a byte round trip."""
    text = format_classic(list(events)).replace(" ", "\t").replace("\n", "\r\n")
    path.write_bytes(text.encode("utf-8"))
    return path


def save_run(
    folder: Path, events: tuple[LogEvent, ...], truth: GroundTruth | None, name: str = "run"
) -> tuple[Path, tuple[EventRecord, ...]]:
    log = write_log(folder / f"{name}.txt", events)
    params = FilterParams()
    info = viz.run_info(name, f"ekfviz replay {log}", params.as_dict(), log, truth=truth)
    rrd = folder / f"{name}.rrd"
    batches = list(replay(events, params))
    records = tuple(every_event(batches))
    with viz.open_run(info, viz.Sinks(save=rrd)) as logger:
        for batch in batches:
            logger.log(batch)
        logger.finish(evaluate(records[-1], truth))
    return rrd, records


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    folder = tmp_path_factory.mktemp("run")
    sim = simulate(classic_controls(), CLASSIC_LANDMARKS_XY, seed=3)
    truth = GroundTruth(np.arange(1, 7, dtype=np.int64), CLASSIC_LANDMARKS_XY)
    rrd, records = save_run(folder, sim.events, truth)
    return Run(rrd=rrd, log=folder / "run.txt", records=records, truth=truth)


def points(row: dict[str, object], column: str) -> np.ndarray:
    return np.asarray(row[column], dtype=np.float64)


def mahalanobis(outline: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    e = outline - mean
    d: np.ndarray = np.sqrt(np.einsum("ni,ni->n", e, np.linalg.solve(cov, e.T).T))
    return d


def robot_frames(rrd: Path) -> dict[int, np.ndarray]:
    """The robot frame of every event: {event: (x, y, theta)}, from the transform logged
    on the robot's point (it places what is under ``world/robot``)."""
    frames = {}
    for row in entity_rows(rrd, f"/{style.ROBOT}"):
        (x, y, z) = row["Transform3D:translation"][0]  # type: ignore[index]
        (qx, qy, qz, qw) = row["Transform3D:quaternion"][0]  # type: ignore[index]
        assert z == qx == qy == 0.0
        frames[int(str(row["event"]))] = np.array([x, y, 2 * np.arctan2(qz, qw)])
    return frames


def in_world(frame: np.ndarray, points_xy: np.ndarray) -> np.ndarray:
    """Points of the robot frame ``frame`` (x, y, theta) in world coordinates."""
    c, s = np.cos(frame[2]), np.sin(frame[2])
    out: np.ndarray = points_xy @ np.array([[c, s], [-s, c]]) + frame[:2]
    return out


def pose_outline(rrd: Path, path: str, row: dict[str, object]) -> np.ndarray:
    """A pose ellipse as drawn: the static unit circle through the row's matrix, in the
    robot frame of the row's event."""
    (circle,) = [  # with the styling, in the first row (see test_styling_...)
        r["LineStrips2D:strips"][0]  # type: ignore[index]
        for r in entity_rows(rrd, f"/{path}")
        if r.get("LineStrips2D:strips") is not None
    ]
    flat = np.asarray(row["Transform3D:mat3x3"], dtype=np.float64)[0]
    matrix = flat.reshape(3, 3).T  # Rerun stores it by columns
    assert matrix[2].tolist() == [0, 0, 1] and matrix[:2, 2].tolist() == [0, 0]
    local = np.asarray(circle, dtype=np.float64) @ matrix[:2, :2].T
    return in_world(robot_frames(rrd)[int(str(row["event"]))], local)


def float32_tolerance(mean: np.ndarray, cov: np.ndarray) -> float:
    """How far from 3 a float32-rounded outline point may be: rounding / smallest sigma."""
    scale = float(np.abs(mean).max() + 3 * np.sqrt(cov.max()))
    return 10 * F32 * scale / float(np.sqrt(np.linalg.eigvalsh(cov).min())) + 1e-6


def test_robot_frame_at_every_event_is_the_cores_pose(run: Run) -> None:
    rows = entity_rows(run.rrd, f"/{style.ROBOT}")
    assert [(row["event"], row["step"]) for row in rows] == [(r.event, r.step) for r in run.records]
    # the point is in the world's frame; its transform places only what is under it
    assert rows[0]["CoordinateFrame:frame"] == ["tf#/world"]
    assert all(row["CoordinateFrame:frame"] is None for row in rows[1:])
    assert entity_rows(run.rrd, f"/{style.ROBOT_FRAME}") == []
    frames = robot_frames(run.rrd)
    # the robot's point: its position in the world at every event, as the frame's origin
    points = entity_rows(run.rrd, f"/{style.ROBOT}")
    assert [row["event"] for row in points] == [r.event for r in run.records]
    for record, point in zip(run.records, points, strict=True):
        frame = frames[record.event]
        np.testing.assert_allclose(frame[:2], record.pose[:2], rtol=F32, atol=1e-6)
        assert abs(np.angle(np.exp(1j * (frame[2] - record.pose[2])))) < 1e-6
        xy = np.asarray(point["Points2D:positions"], dtype=np.float64)
        np.testing.assert_allclose(xy[0], record.pose[:2], rtol=F32, atol=1e-6)
    static = entity_rows(run.rrd, f"/{style.ROBOT}", static=True)
    assert not [r for r in static if "Points2D:positions" in r]  # static would hide them
    # the heading is static in the robot frame
    static = entity_rows(run.rrd, f"/{style.HEADING}", static=True)
    (heading,) = [r for r in static if "Arrows2D:vectors" in r]
    assert heading["Arrows2D:vectors"] == [[1.0, 0.0]]


def test_pose_ellipses_sit_at_mahalanobis_3(run: Run) -> None:
    for path, kinds in (
        (style.POSE_PREDICTED, {EventKind.PREDICT}),
        (style.POSE_UPDATED, {EventKind.UPDATE, EventKind.INIT}),
    ):
        rows = entity_rows(run.rrd, f"/{path}")
        records = [r for r in run.records if r.kind in kinds]
        assert [row["event"] for row in rows] == [r.event for r in records]
        for row, record in zip(rows, records, strict=True):
            outline = pose_outline(run.rrd, path, row)
            cov = record.pose_cov[:2, :2]
            np.testing.assert_allclose(outline[0], outline[-1], atol=1e-9)
            d = mahalanobis(outline, record.pose[:2], cov)
            np.testing.assert_allclose(d, 3.0, atol=float32_tolerance(record.pose[:2], cov))


def test_landmark_ellipses_sit_at_mahalanobis_3(run: Run) -> None:
    rows = entity_rows(run.rrd, f"/{style.LANDMARK_ELLIPSES}")
    records = {r.event: r for r in run.records if r.kind is not EventKind.PREDICT}
    assert rows[0]["event"] == 0 and rows[-1]["event"] == max(records)
    for row in rows:
        record = records[int(str(row["event"]))]
        outlines = points(row, "LineStrips2D:strips")
        assert outlines.shape[0] == record.n_landmarks
        assert row["LineStrips2D:class_ids"] == record.landmark_ids.tolist()
        for outline, mean, cov in zip(
            outlines, record.landmarks_xy, record.landmark_covs, strict=True
        ):
            d = mahalanobis(outline, mean, cov)
            np.testing.assert_allclose(d, 3.0, atol=float32_tolerance(mean, cov))


def test_the_map_shown_at_every_update_is_within_the_tolerance(run: Run) -> None:
    """Between two rows the viewer shows the latest: at every update, each landmark's
    point and outline as shown lie within MAP_TOLERANCE of its ellipse's semi-major axis
    of the true ones (a point moved by delta changes the Mahalanobis distance by at most
    delta / sigma_min)."""
    from ekfviz.viz.recorder import MAP_TOLERANCE

    ellipses = entity_rows(run.rrd, f"/{style.LANDMARK_ELLIPSES}")
    landmarks = entity_rows(run.rrd, f"/{style.LANDMARKS}")
    assert [row["event"] for row in landmarks] == [row["event"] for row in ellipses]
    shown_at = [int(str(row["event"])) for row in ellipses]
    for record in (r for r in run.records if r.kind is not EventKind.PREDICT):
        k = int(np.searchsorted(shown_at, record.event, side="right")) - 1
        outlines = points(ellipses[k], "LineStrips2D:strips")
        shown_xy = points(landmarks[k], "Points2D:positions")
        for outline, shown, mean, cov in zip(
            outlines, shown_xy, record.landmarks_xy, record.landmark_covs, strict=True
        ):
            sigmas = np.sqrt(np.linalg.eigvalsh(cov))
            slack = MAP_TOLERANCE * 3 * sigmas[1]
            assert np.linalg.norm(shown - mean) <= slack + 1e-5
            d = mahalanobis(outline, mean, cov)
            bound = slack / sigmas[0] + float32_tolerance(mean, cov)
            assert np.all(np.abs(d - 3.0) <= bound)


def test_landmarks_are_one_batch_with_their_ids_as_classes(run: Run) -> None:
    rows = entity_rows(run.rrd, f"/{style.LANDMARKS}")
    updates = {r.event: r for r in run.records if r.kind is not EventKind.PREDICT}
    assert rows[-1]["event"] == max(updates)  # the end exactly
    for row in rows:
        record = updates[int(str(row["event"]))]
        np.testing.assert_allclose(points(row, "Points2D:positions"), record.landmarks_xy, rtol=F32)
        assert row["Points2D:class_ids"] == record.landmark_ids.tolist()
    contexts = [
        row["AnnotationContext:context"]
        for row in entity_rows(run.rrd, f"/{style.WORLD}", static=True)
        if "AnnotationContext:context" in row
    ]
    classes: list[dict[str, Any]] = contexts[-1][0]  # type: ignore[index]
    labels = {c["class_id"]: c["class_description"]["info"]["label"] for c in classes}
    assert all(labels[i] == f"L{i}" for i in range(1, 7))


def test_initial_ellipses_only_at_first_sighting(run: Run) -> None:
    rows = entity_rows(run.rrd, f"/{style.LANDMARK_INITIAL}")
    assert [row["event"] for row in rows] == [0]  # the classic log sees all at once
    assert rows[0]["LineStrips2D:class_ids"] == [1, 2, 3, 4, 5, 6]


def trajectory_points(rrd: Path) -> tuple[list[int], np.ndarray]:
    """The events of the trajectory's rows, and its strips joined into one path."""
    rows = entity_rows(rrd, f"/{style.TRAJECTORY}")
    strips = [points(row, "LineStrips2D:strips")[0] for row in rows]
    for before, after in itertools.pairwise(strips):  # each goes on from the last
        np.testing.assert_array_equal(before[-1], after[0])
    path = np.concatenate([strips[0], *(strip[1:] for strip in strips[1:])])
    return [int(str(row["event"])) for row in rows], path


def test_trajectory_grows_at_every_update_through_the_predicted_position(run: Run) -> None:
    events, path = trajectory_points(run.rrd)
    assert events == [r.event for r in run.records if r.kind is EventKind.UPDATE]
    np.testing.assert_allclose(path, [r.pose[:2] for r in run.records], rtol=F32, atol=1e-6)


def test_observation_rays_at_updates_shown_at_the_cursor_only(run: Run) -> None:
    """Rays only at the updates; the layout shows them at the cursor's own step or event
    (nothing at a predict) instead of clearing them with an empty row at each predict."""
    rows = entity_rows(run.rrd, f"/{style.OBSERVATIONS}")
    observed = [r for r in run.records if r.observations is not None and len(r.observations.ids)]
    assert [row["event"] for row in rows] == [r.event for r in observed]
    overrides = map_view().visualizer_overrides
    assert overrides is not None and f"/{style.OBSERVATIONS}" in overrides
    override = overrides[f"/{style.OBSERVATIONS}"]
    assert isinstance(override, rrb.VisibleTimeRanges)
    (ranges,) = [batch.as_arrow_array() for batch in override.as_component_batches()]
    assert sorted(ranges.field("timeline").to_pylist()) == [style.EVENT, style.STEP]
    for side in ("start", "end"):  # from the cursor to the cursor, on both
        union = ranges.field("range").field(side)
        kinds = [union.type[union.type.type_codes.index(code)].name
                 for code in union.type_codes.to_pylist()]  # fmt: skip
        assert kinds == ["CursorRelative"] * 2 and union.to_pylist() == [0, 0]
    static = entity_rows(run.rrd, f"/{style.OBSERVATIONS}", static=True)
    assert [r for r in static if r["Arrows2D:colors"] is not None]  # a range starts at it
    frames = robot_frames(run.rrd)
    for row, record in zip(rows, observed, strict=True):
        rays = points(row, "Arrows2D:vectors")
        assert record.observations is not None
        z = record.observations.z
        assert rays.shape == (len(record.observations.ids), 2)
        np.testing.assert_allclose(np.linalg.norm(rays, axis=1), z[:, 1], rtol=1e-5)
        # in the world: where the measurement puts each landmark from the pose
        bearing = record.pose[2] + z[:, 0]
        seen = record.pose[:2] + z[:, 1:2] * np.column_stack([np.cos(bearing), np.sin(bearing)])
        np.testing.assert_allclose(in_world(frames[record.event], rays), seen, atol=1e-4)


def test_both_timelines_on_every_temporal_chunk(run: Run) -> None:
    from rerun.chunk import RrdReader

    for chunk in RrdReader(run.rrd).stream().filter(is_static=False):
        assert sorted(chunk.timeline_names) == ["event", "step"], chunk.entity_path


def styled(row: dict[str, object]) -> bool:
    return any(key.endswith((":colors", ":radii")) and row[key] is not None for key in row)


def test_styling_is_logged_once_in_the_first_row(run: Run) -> None:
    """An entity's styling shares its first row's chunk (a static chunk of its own would
    cost more than its data); an entity that never gets data has it static."""
    for path in (style.LANDMARKS, style.LANDMARK_ELLIPSES, style.TRAJECTORY, style.NIS):
        temporal = entity_rows(run.rrd, f"/{path}")
        assert [styled(row) for row in temporal] == [True] + [False] * (len(temporal) - 1)
        assert entity_rows(run.rrd, f"/{path}", static=True) == []
    (static,) = entity_rows(run.rrd, f"/{style.LANDMARK_ELLIPSES_OBSERVED}", static=True)
    assert styled(static) and entity_rows(run.rrd, f"/{style.LANDMARK_ELLIPSES_OBSERVED}") == []


def test_metric_series(run: Run) -> None:
    updates = [r for r in run.records if r.kind is EventKind.UPDATE]
    nis = entity_rows(run.rrd, f"/{style.NIS}")
    assert [row["event"] for row in nis] == [r.event for r in updates]
    for row, record in zip(nis, updates, strict=True):
        assert record.observations is not None
        assert row["Scalars:scalars"] == [pytest.approx(float(record.observations.nis.sum()))]
    sigma = entity_rows(run.rrd, f"/{style.POSE_SIGMA}")  # x, y, theta at every update
    corrected = [r for r in run.records if r.kind is not EventKind.PREDICT]
    assert [row["event"] for row in sigma] == [r.event for r in corrected]
    for row, record in zip(sigma, corrected, strict=True):
        expected = np.sqrt(np.diag(record.pose_cov))
        np.testing.assert_allclose(points(row, "Scalars:scalars"), expected, rtol=1e-12)
    final = evaluate(run.records[-1], run.truth)
    for landmark in final.landmarks:
        error = entity_rows(run.rrd, f"/{style.LANDMARK_ERROR}/{landmark.id}")
        distance = entity_rows(run.rrd, f"/{style.MAHALANOBIS}/{landmark.id}")
        assert error[-1]["Scalars:scalars"] == [pytest.approx(landmark.euclidean)]
        assert distance[-1]["Scalars:scalars"] == [pytest.approx(landmark.mahalanobis)]


def test_text_log_line_per_step(run: Run) -> None:
    rows = entity_rows(run.rrd, f"/{style.LOG}")
    assert [row["event"] for row in rows] == [
        r.event for r in run.records if r.kind is not EventKind.PREDICT
    ]
    d, alpha = run.records[1].control.tolist()  # type: ignore[union-attr]
    assert rows[1]["TextLog:text"] == [
        f"step 1 predict line 2: d {d:.3f}, alpha {alpha:.4f}; update line 3: 6 landmarks,"
        f" NIS {run.records[2].observations.nis.sum():.2f}"  # type: ignore[union-attr]
    ]


def test_blueprint_and_properties_are_in_the_file(run: Run) -> None:
    from rerun.chunk import RrdReader

    reader = RrdReader(run.rrd)
    (recording,) = reader.recordings()
    assert recording.application_id == "ekfviz"
    # saved to a file only: the layout once, at the end, framing the whole run
    blueprints = reader.blueprints()
    assert len(blueprints) == 1
    for blueprint in blueprints:
        chunks = list(reader.stream(store=blueprint))
        names = {
            c.to_record_batch().column("ViewBlueprint:display_name")[0][0].as_py()
            for c in chunks
            if "ViewBlueprint:display_name" in c.to_record_batch().schema.names
        }
        assert {
            "Map",
            "NIS (blue) and 95% bounds",
            "Pose sigma x, y [m]",
            "Pose sigma theta [rad]",
            "Log",
            "Run",
            "Evaluation",
            "Input",
        } <= names
        ranged = {
            c.entity_path.split("/overrides/")[1].removesuffix("/visualizers")
            for c in chunks
            if "VisibleTimeRanges:ranges" in c.to_record_batch().schema.names
        }
        accumulated = {style.TRAJECTORY, style.LANDMARK_INITIAL, style.TRUTH_TRAJECTORY}
        assert ranged == accumulated | {style.OBSERVATIONS}  # those at the cursor only
    (name,) = entity_rows(run.rrd, "/__properties", static=True)
    assert name["RecordingInfo:name"] == ["run"]
    (properties,) = entity_rows(run.rrd, "/__properties/ekfviz", static=True)
    assert properties["version"] == [__version__]
    assert properties["compiled_kernel"] == [HAVE_KERNEL]
    assert json.loads(str(properties["parameters"][0])) == FilterParams().as_dict()  # type: ignore[index]
    assert properties["input_sha256"][0] == viz.run_info("x", "", {}, run.log).input_sha256  # type: ignore[index]


def test_info_round_trips_the_input_byte_for_byte(run: Run) -> None:
    found = readback.read_recording_info(run.rrd)
    assert found.input_text is not None
    assert found.input_text.encode("utf-8") == run.log.read_bytes()
    assert "\r\n" in found.input_text and "\t" in found.input_text
    assert found.parameters == FilterParams().as_dict()
    assert found.command == f"ekfviz replay {run.log}"
    assert found.input_name == "run.txt" and found.input_size == run.log.stat().st_size
    assert found.evaluation_markdown == evaluate(run.records[-1], run.truth).to_markdown()
    assert dict(found.summary())["input embedded"] == "yes"
    assert found.compiled_kernel is HAVE_KERNEL
    assert dict(found.summary())["filter kernel"] == ("compiled" if HAVE_KERNEL else "numpy")


def test_info_rejects_what_is_not_a_recording(tmp_path: Path, run: Run) -> None:
    with pytest.raises(readback.NotARecordingError, match="not a Rerun recording"):
        readback.read_recording_info(run.log)
    with pytest.raises(readback.NotARecordingError, match="no such file"):
        readback.read_recording_info(tmp_path / "missing.rrd")


def test_input_over_the_cap_is_not_embedded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(provenance, "INPUT_TEXT_CAP", 100)
    sim = simulate(classic_controls()[:2], CLASSIC_LANDMARKS_XY, seed=1)
    rrd, _ = save_run(tmp_path, sim.events, None)
    found = readback.read_recording_info(rrd)
    assert found.input_text is None and found.input_size > 100
    (note,) = entity_rows(rrd, f"/{style.RUN_INPUT}", static=True)
    assert "cap" in str(note["TextDocument:text"])


def test_recording_id_is_fixed_by_the_inputs(tmp_path: Path, run: Run) -> None:
    params = FilterParams().as_dict()
    a = viz.run_info("a", "one command", params, run.log)
    b = viz.run_info("b", "another command", params, run.log)
    c = viz.run_info("a", "one command", {**params, "sigma_x": 0.3}, run.log)
    assert a.recording_id == b.recording_id != c.recording_id
    assert (
        readback.read_recording_info(run.rrd).recording_id
        == viz.run_info("run", "", params, run.log, truth=run.truth).recording_id
    )


def test_rerun_rrd_verify_accepts_the_recording(run: Run) -> None:
    rrd_verify(run.rrd)


def test_save_is_atomic_when_logging_fails_midway(tmp_path: Path) -> None:
    sim = simulate(classic_controls()[:4], CLASSIC_LANDMARKS_XY, seed=2)
    log = write_log(tmp_path / "in.txt", sim.events)
    target = tmp_path / "out.rrd"
    target.write_bytes(b"the previous recording")
    info = viz.run_info("in", "ekfviz replay in.txt", {}, log)
    with (
        pytest.raises(RuntimeError, match="midway"),
        viz.open_run(info, viz.Sinks(save=target)) as logger,
    ):
        for batch in replay(sim.events):
            logger.log(batch)
            if 3 in batch.events:
                raise RuntimeError("midway")
    assert target.read_bytes() == b"the previous recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.txt", "out.rrd"]


def test_default_sinks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    given = viz.Sinks(save=tmp_path / "x.rrd")
    assert viz.resolve_default_sinks(given, Path("in.txt"), tmp_path) == (given, None)
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    sinks, note = viz.resolve_default_sinks(viz.Sinks(), Path("data/classic.txt"), tmp_path)
    assert sinks == viz.Sinks(save=tmp_path / "classic.rrd") and note and "no display" in note
    # a display server answers (a socket of WAYLAND_DISPLAY's): the viewer
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as server:
        server.bind(str(tmp_path / "wayland-7"))
        server.listen()
        monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
        monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-7")
        sinks, note = viz.resolve_default_sinks(viz.Sinks(), Path("data/classic.txt"), tmp_path)
        assert sinks == viz.Sinks(spawn=True) and note
    # a DISPLAY left from a session that ended names no server: a file, at once (a viewer
    # spawned for it failed to open, and the run waited for it for two minutes)
    monkeypatch.setenv("DISPLAY", ":4711")
    sinks, note = viz.resolve_default_sinks(viz.Sinks(), Path("data/classic.txt"), tmp_path)
    assert sinks == viz.Sinks(save=tmp_path / "classic.rrd") and note
    assert "no display server answers at WAYLAND_DISPLAY=wayland-7 or DISPLAY=:4711" in note
    # a default name too long for the file system: one line that says to name the file
    too_long = Path("x" * 300 + ".txt")
    with pytest.raises(viz.SinkError, match=r"^cannot save the recording as .*--save$"):
        viz.resolve_default_sinks(viz.Sinks(), too_long, tmp_path)


def test_spawn_without_display_is_a_one_line_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, run: Run
) -> None:
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    info = viz.run_info("run", "", {}, run.log)
    with (
        pytest.raises(viz.SinkError, match=r"^--spawn needs a display.*--save") as error,
        viz.open_run(info, viz.Sinks(spawn=True)),
    ):
        pass
    assert "\n" not in str(error.value)
    monkeypatch.setenv("DISPLAY", "localhost:4711.0")  # (TCP port 10711: nobody there)
    with (
        pytest.raises(viz.SinkError, match=r"no display server answers at DISPLAY=localhost"),
        viz.open_run(info, viz.Sinks(spawn=True)),
    ):
        pass


@pytest.mark.slow
def test_200_landmarks_are_one_batch(tmp_path: Path) -> None:
    rng = np.random.default_rng(200)
    landmarks = rng.uniform([-4.0, -4.0], [16.0, 20.0], size=(200, 2))
    sim = simulate(classic_controls(), landmarks, seed=200)
    batches = list(replay(sim.events))
    records = every_event(batches)
    log = write_log(tmp_path / "in.txt", sim.events)
    info = viz.run_info("in", "", {}, log, truth=GroundTruth(np.arange(1, 201), landmarks))
    with viz.open_run(info, viz.Sinks(save=tmp_path / "out.rrd")) as logger:
        for batch in batches:
            logger.log(batch)
        logger.finish(evaluate(records[-1], info.truth))
    (row,) = entity_rows(tmp_path / "out.rrd", f"/{style.LANDMARKS}")[-1:]
    assert len(points(row, "Points2D:positions")) == 200


def large_map_run(
    tmp_path: Path, detail: bool, steps: int = 60
) -> tuple[Path, tuple[EventRecord, ...]]:
    """40 landmarks, 5 of them seen per step in turn, with truth: more than a small map."""
    rng = np.random.default_rng(40)
    landmarks = rng.uniform(-20.0, 20.0, size=(40, 2))
    sim = simulate(np.tile([[1.0, 0.1]], (steps, 1)), landmarks, seed=40)
    events: list[LogEvent] = [sim.events[0]]
    for k, event in enumerate(sim.events[1:]):
        if isinstance(event, Sighting):
            pick = (5 * k + np.arange(5)) % 40
            event = Sighting(event.line, event.ids[pick], event.z[pick])
        events.append(event)
    batches = list(replay(events))
    records = tuple(every_event(batches))
    truth = GroundTruth(np.arange(1, 41), landmarks)
    log = write_log(tmp_path / "large.txt", sim.events)  # the input document only
    info = viz.run_info("large", "", {}, log, truth=truth)
    rrd = tmp_path / f"large_{detail}.rrd"
    with viz.open_run(info, viz.Sinks(save=rrd), detail=detail) as logger:
        for batch in batches:
            logger.log(batch)
        logger.finish(evaluate(records[-1], truth))
    return rrd, records


def test_a_large_map_is_logged_whole_every_k_steps_and_its_observed_ellipses_always(
    tmp_path: Path,
) -> None:
    from ekfviz.viz.recorder import MAP_EVERY_STEPS

    rrd, records = large_map_run(tmp_path, detail=False)
    updates = [r for r in records if r.kind is not EventKind.PREDICT]
    every_k = [r.event for r in updates if r.step % MAP_EVERY_STEPS == 0]
    rows = entity_rows(rrd, f"/{style.LANDMARK_ELLIPSES}")
    assert [row["event"] for row in rows] == [*every_k, updates[-1].event]  # and at the end
    by_event = {r.event: r for r in records}
    for row in rows:
        assert (
            row["LineStrips2D:class_ids"] == by_event[int(str(row["event"]))].landmark_ids.tolist()
        )
    observed = entity_rows(rrd, f"/{style.LANDMARK_ELLIPSES_OBSERVED}")
    assert [row["event"] for row in observed] == [r.event for r in updates]
    for row in observed:
        record = by_event[int(str(row["event"]))]
        assert record.observations is not None
        expected = [] if row["event"] in every_k else sorted(record.observations.ids.tolist())
        assert sorted(np.asarray(row["LineStrips2D:class_ids"]).tolist()) == expected
    # a landmark's error series: at its sightings and the whole map's, and at the end
    error = entity_rows(rrd, f"/{style.LANDMARK_ERROR}/7")
    assert error[-1]["event"] == records[-1].event
    assert len(error) < len(updates) / 2


def test_a_large_maps_points_are_logged_where_they_moved_and_always_within_tolerance(
    tmp_path: Path,
) -> None:
    """Beyond a small map the points go as a small map's do: at the updates where the map
    grew, some point moved by over MAP_TOLERANCE of its ellipse's semi-major axis, or the
    whole map's ellipses are logged; at every update the latest row shown is within that
    tolerance of every landmark; the end exactly."""
    from ekfviz.viz.recorder import MAP_EVERY_STEPS, MAP_TOLERANCE

    rrd, records = large_map_run(tmp_path, detail=False, steps=400)  # it converges
    updates = [r for r in records if r.kind is not EventKind.PREDICT]
    rows = entity_rows(rrd, f"/{style.LANDMARKS}")
    shown_at = [int(str(row["event"])) for row in rows]
    assert len(shown_at) < 0.9 * len(updates)  # not at every update any more
    assert {r.event for r in updates if r.step % MAP_EVERY_STEPS == 0} <= set(shown_at)
    assert shown_at[-1] == updates[-1].event
    for record in updates:
        k = int(np.searchsorted(shown_at, record.event, side="right")) - 1
        assert rows[k]["Points2D:class_ids"] == record.landmark_ids.tolist()
        shown_xy = points(rows[k], "Points2D:positions")
        for shown, mean, cov in zip(
            shown_xy, record.landmarks_xy, record.landmark_covs, strict=True
        ):
            slack = MAP_TOLERANCE * 3 * np.sqrt(np.linalg.eigvalsh(cov))[1]
            assert np.linalg.norm(shown - mean) <= slack + 1e-5
    np.testing.assert_allclose(
        points(rows[-1], "Points2D:positions"), updates[-1].landmarks_xy, rtol=F32
    )


def test_detail_logs_every_ellipse_at_every_update(tmp_path: Path) -> None:
    rrd, records = large_map_run(tmp_path, detail=True)
    updates = [r for r in records if r.kind is not EventKind.PREDICT]
    rows = entity_rows(rrd, f"/{style.LANDMARK_ELLIPSES}")
    assert [row["event"] for row in rows] == [r.event for r in updates]
    assert all(np.asarray(row["LineStrips2D:class_ids"]).shape == (40,) for row in rows)
    assert entity_rows(rrd, f"/{style.LANDMARK_ELLIPSES_OBSERVED}") == []
    assert len(entity_rows(rrd, f"/{style.LANDMARK_ERROR}/7")) == len(updates)


def test_a_long_run_across_flushes_keeps_every_row_and_small_strip_chunks(
    tmp_path: Path,
) -> None:
    """Past a flush (FLUSH_EVERY events) and several chunks of line strips (SHAPES_EVERY):
    a row per event or update everywhere, the trajectory unbroken between two sends, and
    the map logged again only where it moved visibly."""
    from rerun.chunk import RrdReader

    from ekfviz.viz.recorder import FLUSH_EVERY, SHAPES_EVERY

    steps = FLUSH_EVERY // 2 + SHAPES_EVERY
    controls = np.tile(classic_controls(), (steps // len(classic_controls()) + 1, 1))[:steps]
    sim = simulate(controls, CLASSIC_LANDMARKS_XY, seed=7)
    rrd, records = save_run(tmp_path, sim.events, None, name="long")
    assert len(records) > FLUSH_EVERY + SHAPES_EVERY
    updates = [r for r in records if r.kind is not EventKind.PREDICT]
    assert [row["event"] for row in entity_rows(rrd, f"/{style.ROBOT}")] == [
        r.event for r in records
    ]
    events, path = trajectory_points(rrd)
    assert {r.event for r in updates[1:]} <= set(events)
    np.testing.assert_allclose(path, [r.pose[:2] for r in records], rtol=F32, atol=1e-5)
    rays = entity_rows(rrd, f"/{style.OBSERVATIONS}")
    assert [len(points(row, "Arrows2D:vectors")) for row in rays] == [
        len(r.observations.ids)
        for r in records
        if r.observations is not None and len(r.observations.ids)
    ]
    ellipses = entity_rows(rrd, f"/{style.LANDMARK_ELLIPSES}")
    shown = [row["event"] for row in ellipses]
    assert shown[0] == 0 and shown[-1] == updates[-1].event
    assert len(shown) < len(updates) / 2  # a converged map moves little
    assert all(row["LineStrips2D:class_ids"] == [1, 2, 3, 4, 5, 6] for row in ellipses)
    # a line a step, at its update; a predict that ends a send keeps a line of its own
    logged = [row["event"] for row in entity_rows(rrd, f"/{style.LOG}")]
    assert {r.event for r in updates} <= set(logged)
    assert len(logged) - len(updates) <= len(records) // FLUSH_EVERY
    strips = {f"/{path}" for path in (style.LANDMARK_ELLIPSES, style.LANDMARK_INITIAL)}
    for chunk in RrdReader(rrd).stream().filter(is_static=False):
        if chunk.entity_path in strips:
            assert chunk.to_record_batch().num_rows <= SHAPES_EVERY, chunk.entity_path


def test_first_sighting_outlines_are_smooth_the_maps_light(run: Run) -> None:
    """An outline drawn once per landmark at its first sighting has 32 points (metres wide
    on real data, 16 showed corners); the map's, logged again and again, 16."""
    from ekfviz.viz.layers.landmarks import INITIAL_POINTS, MAP_POINTS

    for entity, points in (
        (style.LANDMARK_INITIAL, INITIAL_POINTS),
        (style.LANDMARK_ELLIPSES, MAP_POINTS),
    ):
        strips = [
            strip
            for row in entity_rows(run.rrd, f"/{entity}")
            for strip in row.get("LineStrips2D:strips") or []  # type: ignore[attr-defined]
        ]
        assert strips and {len(strip) for strip in strips} == {points}, entity


def test_info_shows_a_recording_s_names_and_never_obeys_them(tmp_path: Path) -> None:
    """A log named ``esc<ESC>[31m...[bold]`` put the terminal's escape sequence raw on
    the screen through ``info`` (errors escaped it), and rich read its markup."""

    log = tmp_path / "esc\x1b[31mred[bold]x.txt"
    log.write_text((Path(__file__).parents[2] / "data" / "classic.txt").read_text())

    def ekfviz(*args: str) -> str:
        done = run_ekfviz(*args)
        assert done.returncode == 0, done.stderr
        return done.stdout

    ekfviz("replay", str(log), "--save", str(tmp_path / "run.rrd"))
    shown = ekfviz("info", str(tmp_path / "run.rrd"))
    assert "\x1b" not in shown
    assert "name               esc\\x1b[31mred[bold]x" in shown, shown
