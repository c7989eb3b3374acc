"""Your own filter in ekfviz: the protocol, --filter, check, compare, the course skeleton."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from blueprints import read_layout
from commands import run_ekfviz
from conftest import entity_rows, few_by_default, rrd_verify
from typer.testing import CliRunner

from ekfviz.check.lockstep import Quantity, lockstep, numbered
from ekfviz.cli import app
from ekfviz.core.params import FilterParams, LandmarkInit, UpdateMode
from ekfviz.core.records import Control, EventKind, LogEvent, with_ids
from ekfviz.filters.spec import FilterSpecError, load_filter, load_in_process
from ekfviz.io.extended import read_log
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.viz import style

ROOT = Path(__file__).parents[2]
DATA = ROOT / "data"
CLASSIC, TRUTH, LOOP = DATA / "classic.txt", DATA / "classic_truth.json", DATA / "loop.txt"
PLUGINS = Path(__file__).parents[1] / "plugins" / "textbook.py"
SKELETON = ROOT / "examples" / "course_skeleton"
runner = CliRunner()

# a landmark straight behind the robot: its bearing innovation needs the wrap
BEHIND = """\
observe 1 3.1400 5.0 2 0.8 4.0
control 0.5 0.0
observe 1 -3.1410 5.5 2 0.85 3.7
control 0.5 0.0
observe 1 3.1405 6.0 2 0.9 3.4
"""


def plugin(name: str) -> str:
    return f"{PLUGINS}:{name}"


def head(path: Path, lines: int, tmp_path: Path) -> Path:
    """The first ``lines`` lines of a log, as a log of their own."""
    short = tmp_path / f"{path.stem}-{lines}.txt"
    short.write_text("".join(path.read_text().splitlines(keepends=True)[:lines]))
    return short


@pytest.mark.parametrize("lines", [None, 300], ids=["classic", "loop-head"])
def test_a_dense_textbook_plugin_ends_on_the_builtin_pose(
    tmp_path: Path, lines: int | None
) -> None:
    # the whole classic log, and the first 150 steps of the loop (landmarks enter and
    # leave view, the map grows to dozens): the dense filter is O(n^3) per event
    log = CLASSIC if lines is None else head(LOOP, lines, tmp_path)
    builtin = every_event(replay(read_log(log), FilterParams()))
    plugged = list(
        every_event(
            replay(read_log(log), FilterParams(), make_filter=load_in_process(plugin("Textbook")))
        )
    )
    assert len(plugged) == len(builtin)
    assert [r.kind for r in plugged] == [r.kind for r in builtin]
    assert np.abs(plugged[-1].pose - builtin[-1].pose).max() < 1e-9
    assert list(plugged[-1].landmark_ids) == list(builtin[-1].landmark_ids)
    assert np.abs(plugged[-1].landmarks_xy - builtin[-1].landmarks_xy).max() < 1e-9
    assert np.abs(plugged[-1].landmark_covs - builtin[-1].landmark_covs).max() < 1e-9
    if lines is not None:
        assert builtin[-1].n_landmarks > 10


@pytest.mark.parametrize("mode", [UpdateMode.SEQUENTIAL, UpdateMode.JOINT])
def test_a_correct_plugin_gets_the_builtin_observations(mode: UpdateMode) -> None:
    # what a protocol filter saw is ekfviz's own update from its prior state: a correct
    # filter gets the very predictions, S and NIS the built-in reports
    params = FilterParams(update=mode)
    builtin = every_event(replay(read_log(CLASSIC), params))
    plugin_cls = load_in_process(plugin("Textbook" if mode is UpdateMode.SEQUENTIAL else "Joint"))
    plugged = every_event(replay(read_log(CLASSIC), params, make_filter=plugin_cls))
    updates = 0
    for a, b in zip(builtin, plugged, strict=True):
        if a.kind is EventKind.UPDATE:
            assert a.observations is not None and b.observations is not None
            np.testing.assert_allclose(b.observations.z_pred, a.observations.z_pred, atol=1e-9)
            np.testing.assert_allclose(b.observations.S, a.observations.S, rtol=1e-6)
            np.testing.assert_allclose(b.observations.nis, a.observations.nis, rtol=1e-5)
            updates += 1
    assert updates == 29


def test_replay_with_a_plugin_makes_the_same_recording_entities(tmp_path: Path) -> None:
    save = tmp_path / "plugged.rrd"
    result = runner.invoke(
        app, ["replay", str(CLASSIC), "--truth", str(TRUTH), "--filter", plugin("Textbook"),
              "--save", str(save)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert len(entity_rows(save, "/world/robot")) == 59
    assert len(entity_rows(save, "/metrics/nis")) == 29
    assert "6 of 6 landmarks inside" in result.output


def test_an_offline_filter_is_recorded_after_finish() -> None:
    online = list(
        every_event(
            replay(
                read_log(CLASSIC), FilterParams(), make_filter=load_in_process(plugin("Textbook"))
            )
        )
    )
    offline = list(
        every_event(
            replay(
                read_log(CLASSIC), FilterParams(), make_filter=load_in_process(plugin("Offline"))
            )
        )
    )
    assert [r.kind for r in offline] == [EventKind.INIT, EventKind.UPDATE]
    assert offline[-1].step == online[-1].step and offline[-1].event == online[-1].event + 1
    assert offline[-1].observations is None
    np.testing.assert_allclose(offline[-1].pose, online[-1].pose, atol=1e-12)
    assert offline[-1].path_xytheta is None  # it gives no path


def test_an_offline_filters_path_is_drawn_whole(tmp_path: Path) -> None:
    """poses_xytheta after finish(): the final record holds it and the map draws it as
    the trajectory (not a straight line from the start), the true path likewise."""
    online = list(
        every_event(
            replay(
                read_log(CLASSIC), FilterParams(), make_filter=load_in_process(plugin("Textbook"))
            )
        )
    )
    save = tmp_path / "offline.rrd"
    done = runner.invoke(
        app, ["replay", str(CLASSIC), "--truth", str(TRUTH), "--filter",
              plugin("OfflineWithPath"), "--save", str(save)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    predicted = [r.pose for r in online if r.kind in (EventKind.INIT, EventKind.PREDICT)]
    (drawn,) = [
        np.asarray(row["LineStrips2D:strips"], dtype=np.float64)[0]
        for row in entity_rows(save, "/world/trajectory")
        if row.get("LineStrips2D:strips")
    ]
    assert drawn.shape == (len(predicted), 2)
    np.testing.assert_allclose(drawn[:-1], np.array(predicted)[:-1, :2], atol=1e-5)
    np.testing.assert_allclose(drawn[-1], online[-1].pose[:2], atol=1e-5)
    true_paths = [
        len(row["LineStrips2D:strips"][0])  # type: ignore[index]
        for row in entity_rows(save, "/world/truth/trajectory")
        if row.get("LineStrips2D:strips")
    ]
    assert true_paths[-1] == online[-1].step + 1  # every true pose up to the last step
    bad = runner.invoke(app, ["replay", str(CLASSIC), "--filter", plugin("BadPath"), "--save",
                              str(tmp_path / "bad.rrd")])  # fmt: skip
    assert bad.exit_code == 2
    (line,) = bad.output.strip().splitlines()
    assert "poses_xytheta has shape (3, 2), expected (K, 3)" in line


# -- check ---------------------------------------------------------------------------------


def independent_first_divergence(
    events: list[LogEvent], buggy: str, tolerance: float = 1e-6
) -> tuple[int, EventKind] | None:
    """The first divergent event found with the dense textbook filter as the reference:
    before every event, a deep copy of the buggy filter's state in a correct filter."""
    correct_cls = load_in_process(plugin("Textbook"))
    buggy_filter: Any = load_in_process(plugin(buggy))(FilterParams())
    reference: Any = correct_cls(FilterParams())
    if np.abs(np.asarray(reference.P) - buggy_filter.P).max() > tolerance:
        return 0, EventKind.INIT
    for event, _, kind, log_event in numbered(events):
        reference = correct_cls(FilterParams())
        reference.x, reference.P = buggy_filter.x.copy(), buggy_filter.P.copy()
        reference.landmark_ids = list(buggy_filter.landmark_ids)
        for slam in (reference, buggy_filter):
            if isinstance(log_event, Control):
                slam.predict(log_event.d, log_event.alpha)
            else:
                slam.update(log_event.ids, log_event.z)
        dx = reference.x - buggy_filter.x
        dx[2] = (dx[2] + np.pi) % (2 * np.pi) - np.pi  # a heading lives on the circle
        dx = np.abs(dx) / np.maximum(1, np.abs(reference.x))
        dP = np.abs(reference.P - buggy_filter.P) / np.maximum(1, np.abs(reference.P))
        if max(dx.max(), dP.max()) > tolerance:
            return event, kind
    return None


SEEDED = [
    # (class, log, event, kind, quantity, a word of the hint)
    (
        "WrongJacobianSign",
        "classic",
        1,
        EventKind.PREDICT,
        Quantity.POSE_LANDMARK,
        "the sign of its theta column flipped",
    ),
    ("UnrotatedMotionNoise", "classic", 3, EventKind.PREDICT, Quantity.POSE_COVARIANCE, "rotated"),
    ("NoRInS", "classic", 2, EventKind.UPDATE, Quantity.LANDMARK_MEAN, "R is missing"),
    ("NoCrossCovariances", "classic", 0, EventKind.INIT, Quantity.LANDMARK_LANDMARK, "cross-cov"),
    ("UnwrappedBearing", "behind", 2, EventKind.UPDATE, Quantity.LANDMARK_MEAN, "not wrapped"),
    ("Joint", "classic", 2, EventKind.UPDATE, Quantity.LANDMARK_MEAN, "at once"),
    ("NothingWrapped", "classic", 18, EventKind.UPDATE, Quantity.LANDMARK_MEAN, "not wrapped"),
]


@pytest.fixture
def behind(tmp_path: Path) -> Path:
    path = tmp_path / "behind.txt"
    path.write_text(BEHIND)
    return path


@pytest.mark.parametrize(
    ("name", "log", "event", "kind", "quantity", "hint"), few_by_default(SEEDED, 3, multi=True)
)
def test_check_finds_each_seeded_bug(
    tmp_path: Path, behind: Path, name: str, log: str, event: int, kind: EventKind,
    quantity: Quantity, hint: str,
) -> None:  # fmt: skip
    data = CLASSIC if log == "classic" else behind
    report = tmp_path / "check.json"
    result = runner.invoke(
        app, ["check", str(data), "--filter", plugin(name), "--report", str(report)]
    )
    assert result.exit_code == 1, result.output
    found = json.loads(report.read_text())
    assert found["match"] is False
    first = found["first_divergence"]
    assert (first["event"], first["kind"], first["quantity"]) == (event, kind.value, quantity.value)
    assert hint in first["hint"]
    assert "divergence at event" in result.output
    # the same event as a lockstep that shares no code with ekfviz
    assert independent_first_divergence(list(with_ids(read_log(data))), name) == (event, kind)


@pytest.mark.parametrize("log", ["classic", "behind"])
def test_check_passes_a_correct_filter(tmp_path: Path, behind: Path, log: str) -> None:
    data = CLASSIC if log == "classic" else behind
    report = tmp_path / "check.json"
    result = runner.invoke(
        app, ["check", str(data), "--filter", plugin("Textbook"), "--report", str(report)]
    )
    assert result.exit_code == 0, result.output
    found = json.loads(report.read_text())
    assert found["match"] is True and found["first_divergence"] is None
    assert found["events_checked"] == len(list(read_log(data)))
    assert found["max_difference"] < 1e-9


def test_check_uses_the_given_options() -> None:
    # a filter without cross-covariances is what --landmark-init independent asks for
    params = FilterParams(landmark_init=LandmarkInit.INDEPENDENT)
    result = lockstep(
        with_ids(read_log(CLASSIC)), params, load_in_process(plugin("NoCrossCovariances")), name="x"
    )
    assert result.match


def test_check_saves_both_filters_and_marks_the_divergence(tmp_path: Path) -> None:
    save = tmp_path / "check.rrd"
    result = runner.invoke(
        app, ["check", str(CLASSIC), "--filter", plugin("NoRInS"), "--save", str(save)]
    )
    assert result.exit_code == 1, result.output
    # without --all the recording ends at the first divergence, where it opens
    assert len(entity_rows(save, "/filters/reference/world/robot")) == 3  # events 0..2
    assert len(entity_rows(save, "/filters/NoRInS/world/robot")) == 3
    marks = [
        row for row in entity_rows(save, "/log/divergence") if row["TextLog:level"] == ["ERROR"]
    ]
    assert len(marks) == 1 and marks[0]["event"] == 2
    described = runner.invoke(app, ["info", str(save)])
    assert described.exit_code == 0 and "checked against the reference" in described.output
    rrd_verify(save)


# -- faults of a plugin ------------------------------------------------------------------

FAULTS = [
    ("Raises", ":6: event 5 (predict)", "predict raised ZeroDivisionError", True),
    ("WrongShape", ":1: event 0 (init)", "x has 14 entries, expected 3 + 2N", False),
    ("NotFinite", ":2: event 1 (predict)", "x is not finite", True),
    ("Asymmetric", ":2: event 1 (predict)", "P is not symmetric", True),
    ("LosesIds", ":1: event 0 (init)", "landmark_ids has 5 ids but x holds 6", False),
    ("BadConstructor", "", "construction raised RuntimeError: cannot start", False),
]


@pytest.mark.parametrize(("name", "where", "what", "kept"), few_by_default(FAULTS, 3, multi=True))
def test_a_faulty_plugin_is_one_line_and_keeps_the_recording(
    tmp_path: Path, name: str, where: str, what: str, kept: bool
) -> None:
    save = tmp_path / "run.rrd"
    command = ["replay", str(CLASSIC), "--filter", plugin(name), "--save", str(save)]
    done = run_ekfviz(*command)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert f"{CLASSIC}{where}" in lines[0] and what in lines[0] and name in lines[0]
    assert "Traceback" not in done.stderr
    assert save.exists() is kept
    if kept:
        assert entity_rows(save, "/world/robot")
    debug = run_ekfviz("--debug", *command)
    assert "Traceback" in debug.stderr
    if name == "Raises":  # the user's own frame is in it
        assert "division by zero in my predict" in debug.stderr and "textbook.py" in debug.stderr


def test_a_p_that_drifts_from_symmetric_by_rounding_runs_and_is_said_once(
    tmp_path: Path,
) -> None:
    # a Joseph form never symmetrised drifts a little at every event: not a wrong formula
    save = tmp_path / "run.rrd"
    done = run_ekfviz("replay", CLASSIC, "--filter", plugin("Drifting"), "--save", save)
    assert done.returncode == 0, done.stderr
    said = [line for line in done.stderr.splitlines() if "P drifts from symmetric" in line]
    assert len(said) == 1 and "symmetrise P after each update" in said[0], done.stderr
    checked = run_ekfviz("check", CLASSIC, "--filter", plugin("Drifting"))
    assert checked.returncode == 0 and checked.stdout.startswith("match"), checked.stdout


def test_a_drift_from_symmetric_that_keeps_growing_stops_with_its_own_hint(
    tmp_path: Path,
) -> None:
    done = run_ekfviz("replay", CLASSIC, "--filter", plugin("DriftingFast"), cwd=tmp_path)
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert "P is not symmetric" in line and "at most 1e-06" in line
    assert "its asymmetry has grown event after event" in line and "K made" not in line


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("nope", "expected one of ekf"),
        ("missing.py:Filter", "missing.py: no such file"),
        (f"{PLUGINS}:Nope", "has no class Nope"),
        ("no_such_module_xyz:Filter", "No module named 'no_such_module_xyz'"),
        ("BROKEN:Filter", "importing"),
    ],
)
def test_a_filter_that_cannot_be_loaded_is_one_line(
    tmp_path: Path, spec: str, message: str
) -> None:
    if spec.startswith("BROKEN"):
        broken = tmp_path / "broken.py"
        broken.write_text("import numpy\nraise ImportError('my module is broken')\n")
        spec = f"{broken}:Filter"
    with pytest.raises(FilterSpecError, match=message):
        load_filter(spec)
    result = runner.invoke(app, ["replay", str(CLASSIC), "--filter", spec, "--save",
                                 str(tmp_path / "x.rrd")])  # fmt: skip
    assert result.exit_code == 2
    assert message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "x.rrd").exists()


def test_a_plugin_in_a_package_module() -> None:
    assert load_in_process("ekfviz.filters.ekf:EkfSlam").__name__ == "EkfSlam"
    # through --filter, a module's class runs in a worker like a file's: its top-level
    # package (tests/plugins, on the tests' path) is what its sandbox shows
    remote = load_filter("plugins.textbook:Textbook")(FilterParams())
    assert np.allclose(np.asarray(remote.x), [0.0, 0.0, 0.0])
    # ekfviz's own modules are no user's filter: the built-in runs in process
    with pytest.raises(FilterSpecError, match="one of ekfviz's own modules"):
        load_filter("ekfviz.filters.ekf:EkfSlam")


# -- compare and sweep ---------------------------------------------------------------------


def test_compare_of_the_builtin_with_itself_is_identical(tmp_path: Path) -> None:
    report, save = tmp_path / "cmp.json", tmp_path / "cmp.rrd"
    result = runner.invoke(
        app, ["compare", str(CLASSIC), "--filter", "ekf", "--filter", "ekf", "--filter",
              plugin("Textbook"), "--truth", str(TRUTH), "--save", str(save), "--report",
              str(report)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    filters = json.loads(report.read_text())["filters"]
    assert [f["label"] for f in filters] == ["ekf", "ekf-2", "Textbook"]
    for entry in filters:
        for volatile in ("seconds", "ms_per_step", "label", "filter"):
            entry.pop(volatile)
    assert filters[0] == filters[1]
    np.testing.assert_allclose(filters[2]["final_pose"], filters[0]["final_pose"], atol=1e-9)
    assert {"landmarks", "final_pose", "consistency"} <= set(filters[0])
    for key in ("ekf", "ekf-2", "Textbook"):
        assert len(entity_rows(save, f"/filters/{key}/world/robot")) == 59


def test_sweep_takes_a_plugin(tmp_path: Path) -> None:
    report = tmp_path / "sweep.json"
    result = runner.invoke(
        app, ["sweep", str(CLASSIC), "--vary", "sigma_x=x2", "--filter", plugin("Textbook"),
              "--save", str(tmp_path / "s.rrd"), "--report", str(report)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert all(
        v["filter"].endswith(":Textbook") for v in json.loads(report.read_text())["variants"]
    )


def test_consistency_takes_a_plugin(tmp_path: Path) -> None:
    reports = []
    for spec in ("ekf", plugin("Textbook")):
        report = tmp_path / "mc.json"
        result = runner.invoke(
            app, ["consistency", "--runs", "4", "--workers", "1", "--filter", spec,
                  "--init-pose-sigma", "0.001", "0.001", "0.001", "--report", str(report)],
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        reports.append(json.loads(report.read_text()))
    np.testing.assert_allclose(reports[1]["mean_nees"], reports[0]["mean_nees"], rtol=1e-6)


# -- the course skeleton --------------------------------------------------------------------


def test_the_course_skeleton_passes_check() -> None:
    result = runner.invoke(app, ["check", str(CLASSIC), "--filter", str(SKELETON / "ekf_slam.py")])
    assert result.exit_code == 0, result.output


BROKEN_SKELETONS = [
    # (what to replace in ekf_slam.py, by what, the kind of the first divergent event)
    ("P[:3, :3] += W @ control_cov @ W.T", "P[:3, :3] += control_cov", "predict"),
    ("G[1, 2] = d * np.cos(theta)", "G[1, 2] = -d * np.cos(theta)", "predict"),
    ("S = H @ P @ H.T + measure_cov", "S = H @ P @ H.T", "update"),
    ("def init_cross_covariance(", "def _unused_init_cross_covariance(", "init"),
]


@pytest.mark.parametrize(
    ("old", "new", "kind"),
    [
        *BROKEN_SKELETONS[::2],
        *(pytest.param(*b, marks=pytest.mark.slow) for b in BROKEN_SKELETONS[1::2]),
    ],
)
def test_check_finds_bugs_in_a_broken_skeleton(
    tmp_path: Path, old: str, new: str, kind: str
) -> None:
    shutil.copy(SKELETON / "ekf_slam.py", tmp_path / "ekf_slam.py")
    source = (tmp_path / "ekf_slam.py").read_text()
    assert old in source
    (tmp_path / "ekf_slam.py").write_text(source.replace(old, new))
    report = tmp_path / "check.json"
    result = runner.invoke(
        app, ["check", str(CLASSIC), "--filter", str(tmp_path / "ekf_slam.py"),
              "--report", str(report)],
    )  # fmt: skip
    assert result.exit_code == 1, result.output
    assert json.loads(report.read_text())["first_divergence"]["kind"] == kind


def test_a_plugin_replays_id_less_scans_as_the_builtin_does(tmp_path: Path) -> None:
    """--association jcbb with a protocol filter: the same pairing, tentative landmarks
    removed through its remove_landmarks, the same final state as the built-in's."""
    log, truth = tmp_path / "scans.txt", tmp_path / "scans.json"
    done = runner.invoke(
        app,
        ["simulate", "--scenario", "loop", "--steps", "150", "--landmarks", "60", "--seed", "3",
         "--unknown-ids", "--clutter", "1", "--detection-probability", "0.9", "-o", str(log),
         "--truth-out", str(truth)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    reports: dict[str, dict[str, Any]] = {}
    for name in ("ekf", plugin("Textbook")):
        report = tmp_path / f"{len(reports)}.json"
        done = runner.invoke(
            app,
            ["replay", str(log), "--truth", str(truth), "--filter", name, "--association",
             "jcbb", "--save", str(tmp_path / "r.rrd"), "--report", str(report)],
        )  # fmt: skip
        assert done.exit_code == 0, done.output
        reports[name] = json.loads(report.read_text())
    builtin, textbook = reports.values()
    assert textbook["association"] == builtin["association"]
    assert builtin["association"]["removed"] > 0  # tentative landmarks went through removal
    np.testing.assert_allclose(textbook["final_pose"], builtin["final_pose"], atol=1e-9)
    assert [lm["id"] for lm in textbook["landmarks"]] == [lm["id"] for lm in builtin["landmarks"]]
    np.testing.assert_allclose(
        [lm["estimate"] for lm in textbook["landmarks"]],
        [lm["estimate"] for lm in builtin["landmarks"]],
        atol=1e-9,
    )


@pytest.mark.slow
def test_a_plugin_without_removal_needs_confirm_one_for_scans(tmp_path: Path) -> None:
    log = tmp_path / "scans.txt"
    log.write_text("scan 0.1 5.0 0.5 7.0\ncontrol 1.0 0.0\nscan 0.1 4.0 0.5 6.2\n")
    save = tmp_path / "r.rrd"
    # a log with ids needs no removal, whatever the association options say
    for options in ([], ["--association", "jcbb"]):
        with_ids = runner.invoke(
            app, ["replay", str(CLASSIC), "--filter", plugin("NoRemoval"), *options, "--save",
                  str(save)],
        )  # fmt: skip
        assert with_ids.exit_code == 0, with_ids.output
    with_ids = runner.invoke(
        app, ["compare", str(CLASSIC), "--filter", "ekf", "--filter", plugin("NoRemoval"),
              "--save", str(save)],
    )  # fmt: skip
    assert with_ids.exit_code == 0, with_ids.output
    save.unlink()
    command = ["replay", str(log), "--filter", plugin("NoRemoval"), "--save", str(save)]
    refused = runner.invoke(app, command)
    assert refused.exit_code == 2
    (line,) = refused.output.strip().splitlines()
    assert "NoRemoval" in line and "remove_landmarks" in line and "--confirm 1" in line
    kept = runner.invoke(app, [*command, "--confirm", "1"])
    assert kept.exit_code == 0, kept.output
    assert len(entity_rows(save, "/world/robot")) == 3  # init, predict, update


def test_a_plugin_failing_in_a_worker_process_is_one_line(tmp_path: Path) -> None:
    """The error crosses the process boundary whole (it pickles): no BrokenProcessPool."""
    save = tmp_path / "s.rrd"
    result = runner.invoke(
        app, ["sweep", str(CLASSIC), "--vary", "sigma_x=x2", "--filter", plugin("Raises"),
              "--workers", "2", "--save", str(save)],
    )  # fmt: skip
    assert result.exit_code == 2
    (line,) = result.output.strip().splitlines()
    assert line.startswith(f"error: {CLASSIC}:6: ") and "division by zero in my predict" in line
    assert not save.exists()


@pytest.mark.slow
def test_compare_and_sweep_pair_id_less_scans(tmp_path: Path) -> None:
    """--association on the studies: each run pairs the scans itself; a plugin with
    remove_landmarks gets the built-in's pairing and map."""
    log, truth = tmp_path / "scans.txt", tmp_path / "scans.json"
    done = runner.invoke(
        app,
        ["simulate", "--scenario", "loop", "--steps", "120", "--landmarks", "50", "--seed", "7",
         "--unknown-ids", "--clutter", "1", "-o", str(log), "--truth-out", str(truth)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    report = tmp_path / "compare.json"
    done = runner.invoke(
        app,
        ["compare", str(log), "--truth", str(truth), "--filter", "ekf", "--filter",
         plugin("Textbook"), "--save", str(tmp_path / "c.rrd"), "--report", str(report)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    builtin, textbook = json.loads(report.read_text())["filters"]
    assert len(builtin["landmarks"]) == len(textbook["landmarks"]) > 10
    np.testing.assert_allclose(builtin["final_pose"], textbook["final_pose"], atol=1e-9)
    np.testing.assert_allclose(
        [lm["estimate"] for lm in builtin["landmarks"]],
        [lm["estimate"] for lm in textbook["landmarks"]],
        atol=1e-9,
    )
    # judged against the truth under the association's pairing: every landmark has one
    assert all(lm["truth"] is not None for lm in builtin["landmarks"])
    assert builtin["inside"] >= 0.9 * len(builtin["landmarks"])
    report = tmp_path / "sweep.json"
    done = runner.invoke(
        app,
        ["sweep", str(log), "--truth", str(truth), "--vary", "sigma_range=0.05,0.12",
         "--association", "nn", "--save", str(tmp_path / "s.rrd"), "--report", str(report)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    assert all(len(v["landmarks"]) > 10 for v in json.loads(report.read_text())["variants"])


@pytest.mark.parametrize("command", ["compare", "sweep", "check", "calibrate"])
def test_scans_where_they_cannot_go_are_one_line(tmp_path: Path, command: str) -> None:
    log = tmp_path / "scans.txt"
    log.write_text("scan 0.1 5.0\ncontrol 1.0 0.0\nscan 0.1 4.0\n")
    truth = tmp_path / "t.json"
    truth.write_text('{"landmarks": {"1": [5.0, 0.5]}, "poses": [[0, 0, 0], [1, 0, 0]]}')
    extra = {
        "compare": ["--filter", "ekf", "--association", "known"],
        "sweep": ["--vary", "sigma_x=x2", "--association", "known"],
        "check": ["--filter", plugin("Textbook")],
        "calibrate": ["--truth", str(truth)],
    }[command]
    result = runner.invoke(app, [command, str(log), *extra])
    assert result.exit_code == 2, result.output
    (line,) = result.output.strip().splitlines()
    assert line.startswith(f"error: {log}:1: ") and "scan" in line


@pytest.mark.parametrize("spec", ["Offline", "OfflineWithPath"])
def test_an_offline_filters_series_are_points_in_replay_and_compare(
    tmp_path: Path, spec: str
) -> None:
    """Its two records (the start, the optimum after finish()) are not joined by a line
    that would look like a value at every step: its series are points, in its own
    recording and in its tab of a comparison, and its pose sigma plots still keep the
    lengths and the angle apart."""
    save = tmp_path / "replay.rrd"
    done = runner.invoke(
        app, ["replay", str(CLASSIC), "--truth", str(TRUTH), "--filter", plugin(spec),
              "--save", str(save)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    compared = tmp_path / "compare.rrd"
    done = runner.invoke(
        app, ["compare", str(CLASSIC), "--truth", str(TRUTH), "--filter", "ekf", "--filter",
              plugin(spec), "--workers", "1", "--save", str(compared)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    for rrd, prefix in ((save, ""), (compared, f"/filters/{spec}")):
        for entity in (style.POSE_SIGMA, style.HEALTH_POSE_MIN_EIG):
            rows = entity_rows(rrd, f"{prefix}/{entity}")
            assert rows, (rrd.name, entity)
            columns = {key for row in rows for key in row if row[key] is not None}
            assert any(key.startswith("SeriesPoints:") for key in columns), (rrd.name, entity)
            assert not any(key.startswith("SeriesLines:") for key in columns), (rrd.name, entity)
    # the online filter beside it keeps its lines
    ekf_rows = entity_rows(compared, f"/filters/ekf/{style.POSE_SIGMA}")
    assert "SeriesLines:colors" in ekf_rows[0]
    layout = read_layout(save)
    sigma = [view for view in layout.views if view.name.startswith("Pose sigma")]
    assert len(sigma) == 2
    for view in sigma:  # the override that keeps the units apart draws points too
        drawn_by = [
            value["VisualizerInstruction:visualizer_type"]
            for value in view.properties.values()
            if "VisualizerInstruction:visualizer_type" in value
        ]
        assert drawn_by == [["SeriesPoints"]], view.name
