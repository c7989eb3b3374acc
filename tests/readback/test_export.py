"""``ekfviz export``: a replay's recording back as TUM trajectories (read by evo itself),
CSV poses and a CSV map; the true path of a replay with true poses."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from commands import run_ekfviz
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.params import FilterParams
from ekfviz.core.records import EventKind, EventRecord
from ekfviz.io.extended import read_log
from ekfviz.io.truth import read_truth
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.viz import style

runner = CliRunner()
DATA = Path(__file__).parents[2] / "data"


@dataclass(frozen=True, slots=True)
class Exported:
    folder: Path
    rrd: Path
    log: Path
    truth: Path


def invoke(*args: str) -> str:
    result = runner.invoke(app, list(args))
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def loop_run(tmp_path_factory: pytest.TempPathFactory) -> Exported:
    """A simulated loop replayed with the true noise and prior, and its truth."""
    folder = tmp_path_factory.mktemp("export")
    log, truth, rrd = folder / "loop.txt", folder / "truth.json", folder / "loop.rrd"
    invoke(
        "simulate", "--scenario", "loop", "--steps", "200", "--landmarks", "80", "--seed", "3",
        "-o", str(log), "--truth-out", str(truth),
    )  # fmt: skip
    document = json.loads(truth.read_text())
    noise = document["noise"]
    invoke(
        "replay", str(log), "--truth", str(truth), "--save", str(rrd),
        *(a for key, value in noise.items() for a in (f"--{key.replace('_', '-')}", str(value))),
        "--init-pose-sigma", *(str(v) for v in document["init_pose_sigma"]),
    )  # fmt: skip
    return Exported(folder, rrd, log, truth)


def replayed(run: Exported) -> list[EventRecord]:
    """The records of the replay, with the parameters it was recorded with."""
    document = json.loads(run.truth.read_text())
    params = FilterParams(**document["noise"], init_pose_sigma=tuple(document["init_pose_sigma"]))
    return every_event(replay(read_log(run.log), params))


def read_tum(path: Path) -> np.ndarray:
    table: np.ndarray = np.loadtxt(path, ndmin=2)
    return table


def test_the_true_path_is_recorded_at_every_step(loop_run: Exported) -> None:
    truth = read_truth(loop_run.truth)
    assert truth.poses_xytheta is not None
    rows = entity_rows(loop_run.rrd, f"/{style.TRUTH_ROBOT}")  # the frame: on the point
    points = rows
    assert [row["step"] for row in rows] == list(range(len(truth.poses_xytheta)))
    assert [row["step"] for row in points] == list(range(len(truth.poses_xytheta)))
    for row, point, pose in zip(rows, points, truth.poses_xytheta, strict=True):
        translation = np.asarray(row["Transform3D:translation"], dtype=np.float64)
        np.testing.assert_allclose(translation[0, :2], pose[:2], atol=1e-4)
        xy = np.asarray(point["Points2D:positions"], dtype=np.float64)
        np.testing.assert_allclose(xy[0], pose[:2], atol=1e-4)
    path = entity_rows(loop_run.rrd, f"/{style.TRUTH_TRAJECTORY}")
    assert len(path) == len(truth.poses_xytheta)
    last = np.asarray(path[-1]["LineStrips2D:strips"], dtype=np.float64)
    np.testing.assert_allclose(last[0, 1], truth.poses_xytheta[-1, :2], atol=1e-4)


def test_export_gives_back_the_estimate_and_the_truth_of_every_step(loop_run: Exported) -> None:
    est, true, poses, landmarks = (
        loop_run.folder / n for n in ("e.tum", "t.tum", "p.csv", "l.csv")
    )
    invoke(
        "export", str(loop_run.rrd), "--tum", str(est), "--truth-tum", str(true),
        "--csv", str(poses), "--landmarks", str(landmarks),
    )  # fmt: skip
    records = replayed(loop_run)
    corrected = {r.step: r for r in records if r.kind is not EventKind.PREDICT}
    table = read_tum(est)
    assert table[:, 0].tolist() == sorted(corrected)  # no time stamps in the log: steps
    expected = np.array([corrected[int(step)].pose for step in table[:, 0]])
    np.testing.assert_allclose(table[:, 1:3], expected[:, :2], atol=1e-4)
    theta = 2 * np.arctan2(table[:, 6], table[:, 7])
    np.testing.assert_allclose(np.angle(np.exp(1j * (theta - expected[:, 2]))), 0.0, atol=1e-5)
    assert np.all(table[:, [3, 4, 5]] == 0.0)
    truth = read_truth(loop_run.truth)
    assert truth.poses_xytheta is not None
    np.testing.assert_allclose(read_tum(true)[:, 1:3], truth.poses_xytheta[:, :2], atol=1e-4)
    csv = np.genfromtxt(poses, delimiter=",", names=True)
    assert csv.dtype.names == ("step", "x", "y", "theta", "sigma_x", "sigma_y", "sigma_theta")
    np.testing.assert_allclose(csv["theta"], expected[:, 2], atol=1e-5)
    sigmas = np.sqrt([np.diag(corrected[int(s)].pose_cov) for s in table[:, 0]])
    np.testing.assert_allclose(csv["sigma_x"], sigmas[:, 0], rtol=1e-6)
    last = records[-1]
    lm = np.genfromtxt(landmarks, delimiter=",", names=True)
    assert lm["id"].astype(int).tolist() == last.landmark_ids.tolist()
    np.testing.assert_allclose(np.column_stack([lm["x"], lm["y"]]), last.landmarks_xy, atol=1e-4)


def test_evo_ape_on_the_export_matches_ekfviz_position_errors(loop_run: Exported) -> None:
    """evo itself reads both files; its RMSE (no alignment) is that of the position
    errors ekfviz computes from the same poses, and below 1 m for a matched filter."""
    est, true = loop_run.folder / "evo_est.tum", loop_run.folder / "evo_truth.tum"
    invoke("export", str(loop_run.rrd), "--tum", str(est), "--truth-tum", str(true))
    home = loop_run.folder / "home"  # evo writes its settings under ~/.evo
    home.mkdir(exist_ok=True)
    results = loop_run.folder / "ape.zip"
    evo = subprocess.run(
        [str(Path(sys.executable).parent / "evo_ape"), "tum", str(true), str(est),
         "--save_results", str(results), "--no_warnings"],
        capture_output=True, text=True, timeout=300,
        env={**os.environ, "HOME": str(home), "MPLBACKEND": "Agg"},
    )  # fmt: skip
    assert evo.returncode == 0, evo.stdout + evo.stderr
    import zipfile

    with zipfile.ZipFile(results) as archive:
        stats = json.loads(archive.read("stats.json"))
    records = replayed(loop_run)
    truth = read_truth(loop_run.truth)
    assert truth.poses_xytheta is not None
    corrected = {r.step: r for r in records if r.kind is not EventKind.PREDICT}
    errors = [
        np.linalg.norm(corrected[step].pose[:2] - truth.poses_xytheta[step, :2])
        for step in sorted(corrected)
    ]
    rmse = float(np.sqrt(np.mean(np.square(errors))))
    assert np.isfinite(stats["rmse"]) and stats["rmse"] < 1.0
    assert stats["rmse"] == pytest.approx(rmse, rel=1e-4, abs=1e-5)
    assert stats["max"] == pytest.approx(max(errors), rel=1e-4, abs=1e-5)


def test_truth_tum_without_true_poses_is_a_one_line_error(tmp_path: Path) -> None:
    rrd = tmp_path / "classic.rrd"
    data = Path(__file__).parents[2] / "data"
    invoke("replay", str(data / "classic.txt"), "--save", str(rrd))
    est, true = tmp_path / "e.tum", tmp_path / "t.tum"
    result = runner.invoke(app, ["export", str(rrd), "--tum", str(est), "--truth-tum", str(true)])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and "holds no true poses" in result.output
    assert not est.exists() and not true.exists()  # nothing half-written


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: p, "no such file"),
        (lambda p: (p.write_text("not a recording\n"), p)[1], "not a Rerun recording"),
    ],
)
def test_export_of_what_is_not_a_recording_is_a_one_line_error(
    tmp_path: Path, make: object, message: str
) -> None:
    target = make(tmp_path / "x.rrd")  # type: ignore[operator]
    result = runner.invoke(app, ["export", str(target), "--tum", str(tmp_path / "e.tum")])
    assert result.exit_code == 2 and message in result.output
    assert result.output.count("\n") == 1


def test_export_needs_something_to_write(tmp_path: Path) -> None:
    result = runner.invoke(app, ["export", str(tmp_path / "x.rrd")])
    assert result.exit_code == 2 and "nothing to export" in result.output


def test_time_stamps_come_from_the_time_timeline_where_the_recording_has_one(
    tmp_path: Path,
) -> None:
    """A log with time stamps records a ``time`` timeline (seconds; a timestamp for Unix
    times): the export's stamps, to the microsecond."""
    import rerun as rr

    from ekfviz import readback

    rrd = tmp_path / "timed.rrd"
    rec = rr.RecordingStream("ekfviz")
    rec.save(rrd)
    steps, events = np.array([0, 1, 1, 2, 2]), np.arange(5)
    seconds = 1_248_444_000.0 + np.array([0.0, 0.5, 0.5, 1.257, 1.257])  # Unix times
    rec.send_columns(
        f"/{style.ROBOT_FRAME}",
        indexes=[
            rr.TimeColumn("step", sequence=steps),
            rr.TimeColumn("event", sequence=events),
            rr.TimeColumn("time", timestamp=seconds),
        ],
        columns=rr.Transform3D.columns(
            translation=np.column_stack([events, -events, np.zeros(5)]).astype(np.float32),
            quaternion=np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)).astype(np.float32),
        ),
    )
    rec.disconnect()
    run = readback.read_recorded_run(rrd)
    assert run.estimate.steps.tolist() == [0, 1, 2]
    assert run.estimate.seconds is not None
    np.testing.assert_allclose(run.estimate.stamps - 1_248_444_000.0, [0.0, 0.5, 1.257])
    np.testing.assert_allclose(run.estimate.poses_xytheta[:, 0], [0, 2, 4])  # each step's last
    out = tmp_path / "timed.tum"
    invoke("export", str(rrd), "--tum", str(out), "--csv", str(tmp_path / "timed.csv"))
    # to the microsecond, which a float's %g would round to 1.248444e+09
    assert [line.split()[0] for line in out.read_text().splitlines()] == [
        "1248444000",
        "1248444000.5",
        "1248444001.257",
    ]
    assert (tmp_path / "timed.csv").read_text().splitlines()[0].startswith("step,time,x,y")


def test_a_timestamped_dataset_exports_its_track_as_the_truth(tmp_path: Path) -> None:
    """A MRCLAM-layout dataset: the truth is a motion-capture track, the true pose of an
    update is the track's at its time; both files carry the log's Unix times."""
    folder, rrd = tmp_path / "mrclam", tmp_path / "mrclam.rrd"
    invoke("simulate", "--layout", "mrclam", "-o", str(folder))
    invoke("replay", str(folder), "--robot", "1", "--save", str(rrd))
    est, true = tmp_path / "e.tum", tmp_path / "t.tum"
    invoke("export", str(rrd), "--tum", str(est), "--truth-tum", str(true))
    estimate, truth = read_tum(est), read_tum(true)
    assert len(truth) > 0.9 * len(estimate)
    assert np.all(estimate[:, 0] > 1e9) and np.all(np.diff(estimate[:, 0]) > 0)
    assert set(truth[:, 0].tolist()) <= set(estimate[:, 0].tolist())
    by_time = {row[0]: row for row in estimate}
    errors = [np.linalg.norm(by_time[row[0]][1:3] - row[1:3]) for row in truth]
    assert 0.0 < float(np.sqrt(np.mean(np.square(errors)))) < 1.0


# -- recordings written by plain rerun-sdk code, as ekfviz's look-alikes -----------------------

_PROPERTIES = {"version": "0.1.0", "kind": "replay", "command": "ekfviz replay x",
               "parameters": "{}", "input_name": "x.txt", "input_size": 10,
               "input_sha256": "ab" * 32, "input_embedded": False}  # fmt: skip


def _look_alike(path: Path, extra: dict[str, dict[str, object]], landmarks: Any = None) -> None:
    """A recording with ekfviz's properties (and ``extra`` ones), three robot poses and,
    if given, a map (``rr.Points2D``)."""
    import rerun as rr

    def values(items: dict[str, object]) -> rr.AnyValues:
        bundle = rr.AnyValues()
        for key, value in items.items():
            bundle.with_component_from_data(key, value)
        return bundle

    rec = rr.RecordingStream("ekfviz")
    rec.save(path)
    rec.send_property("ekfviz", values(_PROPERTIES))
    for name, items in extra.items():
        rec.send_property(name, values(items))
    for k in range(3):
        rec.set_time("step", sequence=k)
        rec.set_time("event", sequence=k)
        rec.log(
            f"/{style.ROBOT}",
            rr.Transform3D(
                translation=[float(k), 0.0, 0.0], quaternion=rr.Quaternion(xyzw=[0, 0, 0, 1])
            ),
        )
    if landmarks is not None:
        rec.log(f"/{style.LANDMARKS}", landmarks)
    rec.flush()
    rec.disconnect()


def test_look_alike_recordings_are_one_line_not_a_traceback(tmp_path: Path) -> None:
    """Properties of the wrong shape (a list of results, a NaN or a 1e300 time span) were
    tracebacks when ``info`` showed them; a map of three points and one id was one when
    ``export`` wrote it, and NaN went into the CSV."""
    import rerun as rr

    cases: dict[str, tuple[dict[str, dict[str, object]], Any, str]] = {
        "results.rrd": ({"results": {"json": "[1, 2, 3]"}}, None, "info"),
        "nan_time.rrd": (
            {"time": {"start": float("nan"), "end": float("inf"), "kind": "timestamp"}},
            None,
            "info",
        ),
        "huge_time.rrd": (
            {"time": {"start": 1e300, "end": 1e300, "kind": "timestamp"}},
            None,
            "info",
        ),
        "ids.rrd": ({}, rr.Points2D([[1, 2], [3, 4], [5, 6]], class_ids=[7]), "export"),
        "nan_map.rrd": (
            {},
            rr.Points2D(np.array([[np.nan, 1.0], [3.0, 4.0]]), class_ids=[1, 2]),
            "export",
        ),
    }
    for name, (extra, landmarks, command) in cases.items():
        _look_alike(tmp_path / name, extra, landmarks)
        args = [command, str(tmp_path / name)]
        if command == "export":
            args += ["--landmarks", str(tmp_path / "map.csv")]
        done = run_ekfviz(*args)
        assert done.returncode == 2, (name, done.stdout, done.stderr)
        (line,) = done.stderr.strip().splitlines()
        assert line.startswith(f"error: {tmp_path / name}: "), line
        assert "another program wrote" in line, line
        assert not (tmp_path / "map.csv").exists()


def test_a_recording_whose_name_is_not_utf8_is_read(tmp_path: Path) -> None:
    """``replay --save $'r\\xfe.rrd'`` saved it; ``info`` and ``export`` refused it: Rerun's
    reader takes UTF-8 names only ("'utf-8' codec can't encode character '\\udcfe'")."""
    name = os.fsdecode(b"r\xfe.rrd")

    def ekfviz(*args: str) -> subprocess.CompletedProcess[str]:
        return run_ekfviz(*args, cwd=tmp_path)

    assert ekfviz("replay", str(DATA / "classic.txt"), "--save", name).returncode == 0
    shown = ekfviz("info", name)
    assert shown.returncode == 0 and "recording          r\ufffd.rrd" in shown.stdout, shown
    exported = ekfviz("export", name, "--tum", "e.tum")
    assert exported.returncode == 0, exported.stderr
    assert len((tmp_path / "e.tum").read_text().splitlines()) == 30  # steps 0..29


def test_a_recording_cut_at_a_chunk_s_end_is_not_exported_as_whole(tmp_path: Path) -> None:
    """Cut between two chunks (every chunk reads), a recording exported with exit 0 and
    half of its poses and landmarks; ``info`` said "finished"."""
    import struct

    def ekfviz(*args: str) -> subprocess.CompletedProcess[str]:
        return run_ekfviz(*args, cwd=tmp_path)

    assert ekfviz("replay", str(DATA / "classic.txt"), "--save", "whole.rrd").returncode == 0
    data = (tmp_path / "whole.rrd").read_bytes()
    starts, at = [], 12  # the file's header, then (kind, length) and the body of each message
    while at + 16 <= len(data):
        starts.append(at)
        at += 16 + struct.unpack_from("<QQ", data, at)[1]
    cut = starts[len(starts) // 2]
    (tmp_path / "cut.rrd").write_bytes(data[:cut])
    done = ekfviz("export", "cut.rrd", "--tum", "e.tum")
    assert done.returncode == 2 and not (tmp_path / "e.tum").exists()
    assert done.stderr == (
        f"error: cut.rrd: the file has no footer: cut short after {cut} bytes, or its writer"
        " did not close it; export reads whole recordings\n"
    )
    shown = ekfviz("info", "cut.rrd")
    assert shown.returncode == 0 and "finished" not in shown.stdout
    assert "the file has no footer: cut short" in " ".join(shown.stdout.split())
    assert ekfviz("export", "whole.rrd", "--tum", "e.tum").returncode == 0


def test_another_program_s_recording_of_ekfviz_s_entities_is_not_taken_for_ekfviz_s(
    tmp_path: Path,
) -> None:
    """A recording of application ``foo_app`` that logs the robot and the text log was
    described as "a filter of your own, made by an older ekfviz"."""
    import rerun as rr

    for application, said in (("foo_app", "error: "), ("ekfviz", "made by an older ekfviz")):
        path = tmp_path / f"{application}.rrd"
        rec = rr.RecordingStream(application)
        rec.save(path)
        rec.set_time("step", sequence=0)
        rec.log(f"/{style.ROBOT}", rr.Points2D([[0.0, 0.0]]))
        rec.log(f"/{style.LOG}", rr.TextLog("hello"))
        rec.flush()
        rec.disconnect()
        done = run_ekfviz("info", path)
        assert said in done.stdout + done.stderr, (application, done.stdout, done.stderr)
        if application == "foo_app":
            assert done.returncode == 2 and done.stderr.endswith(
                "a Rerun recording (application id 'foo_app'), but not one written by ekfviz\n"
            )


def test_a_file_of_two_merged_recordings_is_refused_not_read_as_one(tmp_path: Path) -> None:
    """``rerun rrd merge a.rrd b.rrd -o m.rrd`` of two replays: info and export read the
    one of the lower recording id, without a word."""
    rerun = Path(sys.executable).parent / "rerun"
    for name, log in (("a.rrd", "classic.txt"), ("b.rrd", "edge.txt")):
        assert run_ekfviz("replay", DATA / log, "--save", name, cwd=tmp_path).returncode == 0
    merged = subprocess.run([rerun, "rrd", "merge", "a.rrd", "b.rrd", "-o", "m.rrd"],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120)  # fmt: skip
    assert merged.returncode == 0, merged.stderr
    for command in (["info", "m.rrd"], ["export", "m.rrd", "--tum", "e.tum"]):
        done = run_ekfviz(*command, cwd=tmp_path)
        assert done.returncode == 2
        assert done.stderr == "error: m.rrd: holds 2 recordings, expected one (files merged?)\n"
    assert not (tmp_path / "e.tum").exists()
