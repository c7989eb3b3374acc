"""A Victoria Park run end to end, on a park generated here in the dataset's layout.

A car with the Ackermann geometry of the real run drives circles among trees; the
laser (3.78 m ahead of the rear axle, 0.50 m left) sees trunks within 30 m in its front
half-plane; the GPS antenna sits above the laser and reports in a frame of its own.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
from parks import make_park
from typer.testing import CliRunner

from ekfviz.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def park(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray], Path]:
    folder = tmp_path_factory.mktemp("park") / "VictoriaPark"
    folder.mkdir()
    truth = make_park(folder)
    out = folder.parent / "out"
    out.mkdir()
    done = runner.invoke(
        app, ["replay", str(folder), "--save", str(out / "run.rrd"), "--report",
              str(out / "run.json")],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    return folder, truth, out


def test_the_recorded_path_is_the_lasers_and_fits_gps(
    park: tuple[Path, dict[str, np.ndarray], Path],
) -> None:
    """/world/robot holds the laser's position at every event (the filter starts at the
    true pose, so the truth's frame is the estimate's); GPS fitted to it is centimetres
    off, and the report says so."""
    _, truth, out = park
    rows = entity_rows(out / "run.rrd", "/world/robot")
    xy = np.array([row["Points2D:positions"][0] for row in rows[1:]])  # type: ignore[index]
    times = truth["laser"][:, 0]
    # the recorded poses at the scans, against where the laser and the axle truly were
    scan_rows = [k for k, row in enumerate(rows[1:]) if int(str(row["event"])) % 2 == 0]
    laser_error = []
    axle_error = []
    stamps = np.array([row["time"].total_seconds() for row in rows[1:]])  # type: ignore[attr-defined]
    for k in scan_rows:
        at = int(np.argmin(np.abs(times - stamps[k])))
        laser_error.append(np.hypot(*(xy[k] - truth["laser"][at, 1:])))
        axle_error.append(np.hypot(*(xy[k] - truth["axle"][at, 1:])))
    assert np.mean(laser_error) < 0.5
    assert np.mean(axle_error) > 3.0
    gps = json.loads((out / "run.json").read_text())["gps"]
    assert gps["points"] == 90 and gps["jumps"] == 1
    assert gps["rmse_without_jumps_m"] < 0.5 < 10.0 < gps["rmse_m"]  # the jump counts in it
    # the track is drawn without its jump, which is a point of its own
    (track,) = [r for r in entity_rows(out / "run.rrd", "/world/reference/gps", static=True)
                if "LineStrips2D:strips" in r]  # fmt: skip
    assert len(track["LineStrips2D:strips"][0]) == 89  # type: ignore[index]
    (jump,) = entity_rows(out / "run.rrd", "/world/reference/gps_jumps", static=True)
    assert len(jump["Points2D:positions"]) == 1  # type: ignore[arg-type]


def test_every_tree_seen_is_mapped_once_near_where_it_stands(
    park: tuple[Path, dict[str, np.ndarray], Path],
) -> None:
    _, truth, out = park
    report = json.loads((out / "run.json").read_text())
    estimates = np.array([lm["estimate"] for lm in report["landmarks"]])
    trees = truth["trees"]
    distance = np.linalg.norm(estimates[:, None, :] - trees[None, :, :], axis=2)
    assert (distance.min(axis=1) < 1.0).all()  # nothing spurious
    nearest = distance.argmin(axis=1)
    assert len(set(nearest.tolist())) == len(nearest)  # no tree twice
    assert len(estimates) >= 40
    assert report["association"]["removed"] >= 0 and report["association"]["landmarks"] == len(
        estimates
    )


def test_the_rigid_fit_recovers_a_known_transform_and_finds_jumps() -> None:
    from ekfviz.evaluation.reference import fit_reference, jumps

    t = np.linspace(0.0, 60.0, 61)
    estimate = np.column_stack([10 * np.cos(t / 10), 5 * np.sin(t / 7)])
    angle = 1.1
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    gps = estimate @ rotation.T + (300.0, -50.0)  # the same path in a frame of its own
    fit = fit_reference(t, estimate, t[::3], gps[::3])
    assert fit.errors.max() < 1e-9 and not fit.jumps.any()
    gps[30] += (60.0, 0.0)
    found = jumps(t, gps)
    assert found.tolist() == [k == 30 for k in range(61)]
    fit = fit_reference(t, estimate, t, gps)
    assert fit.jumps.sum() == 1 and fit.rmse > 5.0 > 1.0 > fit.rmse_without_jumps


def test_the_map_frames_the_gps_track_and_its_jumps_label(
    park: tuple[Path, dict[str, np.ndarray], Path],
) -> None:
    """The reference is drawn after the run; the layout sent after it frames the track and
    the jump with room for its label (centred on the point) on either side."""
    from blueprints import read_layout

    _, _, out = park
    rrd = out / "run.rrd"
    (jump,) = entity_rows(rrd, "/world/reference/gps_jumps", static=True)
    jx, jy = np.asarray(jump["Points2D:positions"], dtype=np.float64)[0]
    (track,) = [r for r in entity_rows(rrd, "/world/reference/gps", static=True)
                if "LineStrips2D:strips" in r]  # fmt: skip
    gps = np.asarray(track["LineStrips2D:strips"][0], dtype=np.float64)  # type: ignore[index]
    (bounds,) = [
        value["VisualBounds2D:range"][0]
        for view in read_layout(rrd).views
        if view.name == "Map"
        for value in view.properties.values()
        if "VisualBounds2D:range" in value
    ]
    x_min, x_max = bounds["x_range"]
    y_min, y_max = bounds["y_range"]  # mirrored: the view draws y down
    width = x_max - x_min
    assert x_min + 0.1 * width <= jx <= x_max - 0.1 * width  # its label fits beside it
    assert x_min <= gps[:, 0].min() and gps[:, 0].max() <= x_max
    assert y_min <= -max(jy, gps[:, 1].max()) and -min(jy, gps[:, 1].min()) <= y_max


@pytest.mark.parametrize(
    "option",
    [["--sigma-x", "0.3"], ["--odometry-scale", "1.1", "1"], ["--motion-noise", "per-step"]],
)
def test_an_option_of_the_d_alpha_model_is_refused_not_ignored(
    tmp_path: Path, option: list[str]
) -> None:
    """The car's model takes speed and steering: these changed nothing, yet the recording
    said the run used them."""
    (tmp_path / "park").mkdir()
    make_park(tmp_path / "park", seconds=5.0)
    rrd = tmp_path / "x.rrd"
    result = runner.invoke(app, ["replay", str(tmp_path / "park"), *option, "--save", str(rrd)])
    assert result.exit_code == 2, result.output
    assert result.output.strip() == (
        f"error: {tmp_path / 'park'}: {option[0]} is for logs of (d, alpha) controls, not a"
        " Victoria Park directory: its vehicle takes speed and steering (--sigma-speed,"
        " --sigma-steering)"
    )
    assert not rrd.exists()


@pytest.mark.parametrize("name", ["gps.dat", "inputs.dat", "measurements.dat"])
def test_a_file_that_is_there_but_does_not_read_is_named(tmp_path: Path, name: str) -> None:
    """A link to itself: a gps.dat was taken for none (a warning, no GPS fit), inputs.dat
    and measurements.dat for no dataset at all (the folder named, not the file)."""
    park = tmp_path / "park"
    park.mkdir()
    make_park(park, seconds=5.0)
    (park / name).unlink()
    (park / name).symlink_to(park / name)
    result = runner.invoke(app, ["replay", str(park), "--save", str(tmp_path / "x.rrd")])
    assert result.exit_code == 2, result.output
    assert result.output.strip() == (
        f"error: {park / name}: cannot be read (Too many levels of symbolic links)"
    )
