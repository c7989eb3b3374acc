"""The default layout of every kind of recording, read back from the file: every entity
with data is in some view, no view is empty, a check opens on its divergence."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from blueprints import Layout, read_layout
from conftest import entity_rows
from parks import make_park
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.viz import check as check_viz
from ekfviz.viz import style
from ekfviz.viz.blueprint import FIRST_SIGHTING_EVENTS, FIRST_SIGHTING_S

DATA = Path(__file__).resolve().parents[2] / "data"
CLASSIC, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
LOOP, LOOP_TRUTH = DATA / "loop.txt", DATA / "loop_truth.json"
SCANS, SCANS_TRUTH = DATA / "scans.txt", DATA / "scans_truth.json"
PLUGINS = Path(__file__).resolve().parents[1] / "plugins" / "textbook.py"
runner = CliRunner()


def plugin(name: str) -> str:
    return f"{PLUGINS}:{name}"


def made(args: list[str], save: Path, code: int = 0) -> Layout:
    result = runner.invoke(app, [*args, "--save", str(save)])
    assert result.exit_code == code, result.output
    return read_layout(save)


@pytest.fixture(scope="module")
def mrclam(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("sim") / "MRCLAM_Sim"
    result = runner.invoke(
        app, ["simulate", "--layout", "mrclam", "-o", str(directory), "--seed", "3",
              "--duration", "40"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return directory


@pytest.fixture(scope="module")
def park(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("park") / "VictoriaPark"
    folder.mkdir()
    make_park(folder, seconds=40.0)
    return folder


KINDS = {
    "classic": ["replay", str(CLASSIC), "--truth", str(TRUTH)],
    "classic-history": ["replay", str(CLASSIC), "--truth", str(TRUTH), "--history"],
    "classic-no-truth": ["replay", str(CLASSIC)],
    "loop": ["replay", str(LOOP), "--truth", str(LOOP_TRUTH)],
    "short-loop": ["replay", "SHORT_LOOP", "--truth", "SHORT_LOOP_TRUTH"],
    "scans": ["replay", str(SCANS), "--truth", str(SCANS_TRUTH)],
    "scans-no-truth": ["replay", "SCANS_HEAD", "--association", "nn"],
    "compare-2": ["compare", str(CLASSIC), "--truth", str(TRUTH), "--filter", "ekf",
                  "--filter", plugin("Textbook"), "--workers", "1"],
    "compare-3": ["compare", str(CLASSIC), "--truth", str(TRUTH), "--filter", "ekf",
                  "--filter", plugin("Textbook"), "--filter", plugin("Offline"), "--workers", "1"],
    # (a short loop: the dense textbook filter takes 13 s over the bundled one's 2,000 lines)
    "compare-4": ["compare", "SHORT_LOOP", "--filter", "ekf", "--filter", plugin("Textbook"),
                  "--filter", plugin("Offline"), "--filter", plugin("OfflineWithPath"),
                  "--workers", "1"],
    "sweep": ["sweep", str(CLASSIC), "--truth", str(TRUTH), "--preset", "tuning",
              "--workers", "1"],
    "check-match": ["check", str(CLASSIC), "--filter", plugin("Textbook")],
    "check-all": ["check", str(CLASSIC), "--filter", plugin("NoRInS"), "--all"],
    "check-at-init": ["check", str(CLASSIC), "--filter", plugin("NoCrossCovariances")],
    "rosbag": ["replay", "BAG"],
    "consistency": ["consistency", "--runs", "3", "--workers", "1"],
}  # fmt: skip
# under make test-all: the bundled loop's 2,000 lines record what the short one's 150 steps
# do; scans-no-truth, compare-2, check-match and classic stand for the others by default
SLOW_KINDS = {"loop", "scans", "compare-3", "compare-4", "check-at-init", "classic-history"}


@pytest.fixture(scope="module")
def short_loop(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A loop in the extended format, as the bundled one, of 150 steps and 40 landmarks
    (the dense textbook filter of a compare is cubic in the map); its truth beside it."""
    log = tmp_path_factory.mktemp("loop") / "loop.txt"
    result = runner.invoke(
        app, ["simulate", "--scenario", "loop", "--steps", "150", "--landmarks", "40",
              "-o", str(log), "--truth-out", str(log.with_suffix(".json"))],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return log


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ROS 2 bag of a simulated run of the classic scenario (as the bag reader's tests
    write one)."""
    from sources.test_rosbag import write_bag

    from ekfviz.sim.scenarios import classic

    return write_bag(tmp_path_factory.mktemp("bag") / "run_bag", classic().run(seed=4))


@pytest.fixture(scope="module")
def scans_head(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 500 lines of the bundled log of scans (its header with them)."""
    head = tmp_path_factory.mktemp("scans") / "scans.txt"
    head.write_text("".join(SCANS.read_text().splitlines(keepends=True)[:500]))
    return head


def stand_ins(args: list[str], request: pytest.FixtureRequest) -> list[str]:
    """``args`` with the names of the fixtures' files in them made their paths."""
    found = {
        "SHORT_LOOP": lambda: str(request.getfixturevalue("short_loop")),
        "SHORT_LOOP_TRUTH": lambda: str(request.getfixturevalue("short_loop").with_suffix(".json")),
        "BAG": lambda: str(request.getfixturevalue("bag")),
        "SCANS_HEAD": lambda: str(request.getfixturevalue("scans_head")),
    }
    return [found[arg]() if arg in found else arg for arg in args]


@pytest.fixture(scope="module")
def recorded(
    tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> Callable[[str], tuple[Path, Layout]]:
    """The recording of a kind of :data:`KINDS` and its layout, made once for the module."""
    folder = tmp_path_factory.mktemp("kinds")
    made_once: dict[str, tuple[Path, Layout]] = {}

    def record(kind: str) -> tuple[Path, Layout]:
        if kind not in made_once:
            args = stand_ins(KINDS[kind], request)
            save = folder / f"{kind}.rrd"
            made_once[kind] = save, made(args, save, code=1 if kind.startswith("check-a") else 0)
        return made_once[kind]

    return record


@pytest.mark.parametrize(
    "kind", [pytest.param(k, marks=pytest.mark.slow) if k in SLOW_KINDS else k for k in KINDS]
)
def test_every_entity_with_data_is_in_a_view_and_no_view_is_empty(
    kind: str, recorded: Callable[[str], tuple[Path, Layout]]
) -> None:
    _, layout = recorded(kind)
    assert layout.views and layout.data
    assert layout.unshown() == []
    assert layout.empty() == []


@pytest.mark.parametrize("source", ["mrclam", "park"])
def test_real_formats_show_everything_they_record(
    source: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    directory: Path = request.getfixturevalue(source)
    args = ["replay", str(directory)] + (["--robot", "1"] if source == "mrclam" else [])
    layout = made(args, tmp_path / "run.rrd")
    assert layout.unshown() == []
    assert layout.empty() == []
    # a timestamped run opens on the step timeline: a sequence axis is labelled at round
    # numbers of steps at any length, where a time axis of minutes gets one label
    assert layout.time_panel["TimePanelBlueprint:timeline"] == ["step"]
    if source == "park":  # the GPS error and the association counts are plotted
        assert layout.showing("/metrics/reference/gps_rmse")
        assert layout.showing("/metrics/association/matched")


def test_a_recording_without_landmark_errors_has_no_landmark_error_plot(
    recorded: Callable[[str], tuple[Path, Layout]],
) -> None:
    # id-less scans with truth: the landmark errors are not logged (the pairing is the
    # association's), so neither are their plots
    _, layout = recorded("scans")
    names = {view.name for view in layout.views}
    assert "Landmark error [m]" not in names and "Mahalanobis distance" not in names
    assert "Association per scan (counts)" in names
    _, with_truth = recorded("classic")
    assert {"Landmark error [m]", "Mahalanobis distance"} <= {v.name for v in with_truth.views}


def test_pose_sigma_shows_lengths_and_the_angle_apart(
    recorded: Callable[[str], tuple[Path, Layout]],
) -> None:
    _, layout = recorded("classic")
    lengths, angle = layout.view("Pose sigma x, y [m]"), layout.view("Pose sigma theta [rad]")
    assert lengths.shown == angle.shown == {f"/{style.POSE_SIGMA}"}
    visible = {
        view.name: [
            value
            for key, fields in view.properties.items()
            if key.endswith(f"{style.POSE_SIGMA}/visualizers") or "pose_sigma" in key
            for name, value in fields.items()
            if name.endswith("visible_series")
        ]
        for view in (lengths, angle)
    }
    assert visible == {
        "Pose sigma x, y [m]": [[True, True, False]],
        "Pose sigma theta [rad]": [[False, False, True]],
    }


def test_a_check_recording_opens_on_the_divergence(tmp_path: Path) -> None:
    save = tmp_path / "check.rrd"
    layout = made(["check", str(CLASSIC), "--filter", plugin("NoRInS")], save, code=1)
    assert layout.unshown() == [] and layout.empty() == []
    maps = [view for view in layout.views if view.kind == "2D" and "correlation" not in view.origin]
    assert len(maps) == 3  # the reference, the filter, the filter at the divergence
    for view in maps:  # the divergence is marked on every map
        assert any(entity.endswith(f"/{check_viz.DIVERGENCE}") for entity in view.shown), view.name
    zoom = maps[-1]
    assert {
        f"/filters/NoRInS/{check_viz.EXPECTED}",
        f"/filters/NoRInS/{check_viz.GOT}",
    } <= zoom.shown
    assert f"/filters/NoRInS/{check_viz.EXPECTED}" not in maps[1].shown  # not over the map
    # the ERROR line is in the log view, at the divergent event
    (log,) = [view for view in layout.views if f"/{check_viz.LOG}" in view.shown]
    assert log.kind == "TextLog"
    lines = entity_rows(save, f"/{check_viz.LOG}")
    errors = [row for row in lines if row["TextLog:level"] == ["ERROR"]]
    assert [row["event"] for row in errors] == [2]
    assert "landmark mean x[L2.x]" in str(errors[0]["TextLog:text"])
    # then its values and cause, on lines of their own (no level) that the view shows whole
    rest = [str(row["TextLog:text"]) for row in lines if row["TextLog:level"] == [""]]
    assert {row["event"] for row in lines} == {2} and len(rest) == len(lines) - 1
    assert "expected 2.74994, got 2.16497" in rest[0]
    assert any("likely cause" in line for line in rest)
    assert all(len(line) <= style.LOG_WIDTH + 8 for line in rest)  # 8: the list's quoting
    # the time cursor: the event timeline, following to the end, which is the divergence
    assert layout.time_panel["TimePanelBlueprint:timeline"] == ["event"]
    assert [row["event"] for row in entity_rows(save, "/filters/NoRInS/world/robot")][-1] == 2
    # a plot with data at every event up to the divergence, the divergent one marked
    differences = entity_rows(save, f"/{check_viz.DIFFERENCE}")
    assert [row["event"] for row in differences] == [0, 1, 2]
    assert differences[-1]["Scalars:scalars"][0] > -6 > differences[0]["Scalars:scalars"][0]  # type: ignore[index]
    (divergent,) = entity_rows(save, f"/{check_viz.DIVERGENT}")
    assert divergent["event"] == 2
    assert layout.showing(f"/{check_viz.DIFFERENCE}") and layout.showing(f"/{check_viz.DIVERGENT}")
    assert layout.showing(f"/{check_viz.TABLE}")


def test_gps_dropouts_are_gaps_not_chords() -> None:
    import numpy as np

    from ekfviz.viz.reference import gps_pieces

    times = np.array([0.0, 1.0, 2.0, 3.0, 30.0, 31.0, 32.5, 33.0])
    xy = np.column_stack([times, np.zeros(8)])
    pieces = gps_pieces(xy, times)
    assert [piece[:, 0].tolist() for piece in pieces] == [[0, 1, 2, 3], [30, 31, 32.5, 33]]
    assert len(gps_pieces(xy[:1], times[:1])) == 1
    assert len(gps_pieces(xy[:4], times[:4])) == 1  # a steady track stays one piece


def test_real_data_maps_draw_first_sightings_for_a_while(tmp_path: Path, mrclam: Path) -> None:
    def first_sightings(layout: Layout) -> dict[str, dict[str, int | None]]:
        (world,) = [view for view in layout.views if view.name == "Map"]
        key = f"ViewContents/overrides/{style.LANDMARK_INITIAL}/visualizers"
        ranges = world.properties[key]["VisibleTimeRanges:ranges"]
        return {r["timeline"]: r["range"] for r in ranges}

    layout = made(["replay", str(mrclam), "--robot", "1"], tmp_path / "run.rrd")
    recent = first_sightings(layout)
    assert recent["time"] == {"start": -int(FIRST_SIGHTING_S * 1e9), "end": 0}
    assert recent["event"] == {"start": -FIRST_SIGHTING_EVENTS, "end": 0}
    history = made(["replay", str(mrclam), "--robot", "1", "--history"], tmp_path / "h.rrd")
    assert first_sightings(history)["time"]["start"] is None  # from the start: accumulated


def test_info_shows_a_runs_results_and_only_the_parameters_that_applied(
    recorded: Callable[[str], tuple[Path, Layout]],
) -> None:
    scans, _ = recorded("scans")
    shown = runner.invoke(app, ["info", str(scans)])
    assert shown.exit_code == 0, shown.output
    (line,) = [line for line in shown.output.splitlines() if line.startswith("association ")]
    assert "matched" in line and "precision" in line
    assert '"jcbb"' in shown.output  # its association's parameters: they applied
    classic, _ = recorded("classic")
    shown = runner.invoke(app, ["info", str(classic)])
    # no association parameter among the parameters (the command line shown may name
    # anything: under pytest it is pytest's own)
    parameters = [line.split()[0] for line in shown.output.splitlines() if line.startswith("  ")]
    assert "sigma_x" in parameters
    assert not {"association", "jcbb_budget", "confirm_window"} & set(parameters)
    assert not any(line.startswith("association ") for line in shown.output.splitlines())


def test_victoria_park_info_has_its_gps_rmse(tmp_path: Path, park: Path) -> None:
    save = tmp_path / "park.rrd"
    made(["replay", str(park)], save)
    shown = runner.invoke(app, ["info", str(save), "--json"])
    assert shown.exit_code == 0, shown.output
    import json

    results = json.loads(shown.stdout)["results"]
    assert results["gps"]["rmse_m"] > 0 and results["association"]["matched"] > 0


def test_close_labels_are_stacked_not_overprinted() -> None:
    import numpy as np

    from ekfviz.viz.recorder import unclutter

    # three labels within one label's box of each other (MRCLAM's L6, L7, L8) and one apart;
    # 0.05 and 0.6 make a round-off that once kept a label in place forever
    anchors = np.array([[0.0, 0.0], [0.1, 0.05], [0.2, -0.02], [5.0, 5.0]])
    placed = unclutter(anchors, 1.0, 0.6)
    assert placed[3].tolist() == [5.0, 5.0]  # alone: where it was
    assert (placed[:, 0] == anchors[:, 0]).all()  # moved down only
    for i in range(4):
        for j in range(i):
            dx, dy = abs(placed[i] - placed[j])
            assert dx >= 1.0 or dy >= 0.6, (i, j)
    assert placed[1].tolist() == [0.1, 0.05]  # the highest stays
    apart = np.array([[0.0, 0.0], [3.0, 0.0]])
    assert unclutter(apart, 1.0, 0.6) is apart


def test_labels_too_far_out_to_be_stacked_are_left_and_the_loop_ends() -> None:
    """A filter that gives its landmarks a variance of 1e40 hangs their 3-sigma labels
    3e20 m out, where a label's height is below the spacing of floats: moving one down
    made no progress, and ``replay`` spun there for ever (past SIGTERM: it was in the
    recording's finish)."""
    import numpy as np

    from ekfviz.viz.recorder import unclutter

    anchors = np.array([[0.0, 3e20], [0.1, 3e20], [0.2, 3e20 + 1e5]])
    placed = unclutter(anchors, 1.0, 0.6)  # returns (it did not)
    assert np.isfinite(placed).all() and (placed[:, 0] == anchors[:, 0]).all()


def test_grade_recordings_show_everything_and_the_reference_its_own(tmp_path: Path) -> None:
    import students

    students.write(tmp_path / "class" / "bob", "transposed_and_missing_pose_term")
    result = runner.invoke(
        app, ["grade", str(tmp_path / "class"), "--save-dir", str(tmp_path / "rec"),
              "--workers", "1", "--log", str(CLASSIC)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    (rrd,) = sorted((tmp_path / "rec").glob("*.rrd"))
    layout = read_layout(rrd)
    assert layout.unshown() == [] and layout.empty() == []
    maps = [view.name for view in layout.views if view.kind == "2D" and view.name != "Correlation"]
    # the student diverges at the initialisation: the reference's map is still its own,
    # the built-in filter alone over the whole log (as ``replay`` draws it)
    assert maps[0] == "reference (ekf)" and maps[-1] == "At event 0"
    alone = tmp_path / "alone.rrd"
    assert runner.invoke(app, ["replay", str(CLASSIC), "--save", str(alone)]).exit_code == 0
    for entity in ("world/robot", "world/landmarks"):
        drawn = entity_rows(rrd, f"/filters/reference/{entity}")
        replayed = entity_rows(alone, f"/{entity}")
        assert len(drawn) == len(replayed) > 1
        for got, expected in zip(drawn, replayed, strict=True):
            assert got["event"] == expected["event"]
            np.testing.assert_allclose(
                np.asarray(got["Points2D:positions"]),
                np.asarray(expected["Points2D:positions"]),
                rtol=0.0,
                atol=1e-9,
            )


EXPANDED, COLLAPSED = 3, 2  # Rerun's panel states


def panel_states(layout: Layout) -> dict[str, int]:
    return {name: fields["PanelBlueprint:state"][0] for name, fields in layout.panels.items()}


def test_a_watch_run_shows_the_list_of_runs_and_a_check_keeps_its_panels_collapsed(
    tmp_path: Path,
) -> None:
    from ekfviz import viz
    from ekfviz.app.check import Recorded, check_log, check_recording
    from ekfviz.core.params import FilterParams
    from ekfviz.filters.spec import FilterSpec
    from ekfviz.viz.check import record_check
    from ekfviz.viz.ghost import record_failure

    spec = FilterSpec(plugin("NoRInS"))
    params = FilterParams()
    checked = tmp_path / "check.rrd"
    result, _ = check_log(CLASSIC, None, spec, params, tolerance=1e-6, save=checked)
    assert panel_states(read_layout(checked)) == {
        "blueprint_panel": COLLAPSED, "selection_panel": COLLAPSED,
    }  # fmt: skip
    # a run of ``ekfviz watch`` is drawn as the watch draws it: a recording of its own
    shown = check_recording(Recorded(CLASSIC, None, [], [CLASSIC], "ekfviz watch"), spec,
                            params, result)  # fmt: skip
    watched = tmp_path / "watched.rrd"
    with viz.open_recording(shown.info, viz.Sinks(save=watched)) as recording:
        record_check(recording, shown.result, shown.runs, None, shown.summary, runs_list=True)
    failed = tmp_path / "failed.rrd"
    with viz.open_recording(shown.info, viz.Sinks(save=failed)) as recording:
        record_failure(recording, "filters/NoRInS", spec.label, None, ["it failed"])
    for rrd in (watched, failed):
        layout = read_layout(rrd)
        assert panel_states(layout) == {
            "blueprint_panel": EXPANDED, "selection_panel": COLLAPSED,
        }, rrd  # fmt: skip
        assert layout.time_panel["TimePanelBlueprint:state"] == [COLLAPSED]
