"""Options the command line and the library refuse, each with one line (or a ValueError)
saying what was expected; --debug shows the traceback instead.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from commands import run_ekfviz
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.runner.replay import replay

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
SAMPLE = DATA / "classic.txt"
runner = CliRunner()


# -- the command line ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["replay", "missing.txt"], "missing.txt: no such file"),
        (["replay", str(SAMPLE), "--truth", "nope.json"], "nope.json: no such file"),
        (["replay", str(SAMPLE), "--sigma-range", "0"], "must be positive"),
        (["info", "missing.rrd"], "missing.rrd"),
    ],
)
def test_usage_errors_exit_2_without_traceback(
    tmp_path: Path, args: list[str], expected: str
) -> None:
    result = run_ekfviz(
        *args, *(["--save", tmp_path / "x.rrd"] if args[0] == "replay" else []), cwd=tmp_path
    )
    assert result.returncode == 2, result.stderr
    assert expected in result.stderr and "Traceback" not in result.stderr


def test_debug_shows_the_traceback(tmp_path: Path) -> None:
    command = ["replay", str(tmp_path / "nope.txt"), "--save", str(tmp_path / "r.rrd")]
    plain = run_ekfviz(*command)
    debug = run_ekfviz("--debug", *command)
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert debug.returncode != 0 and "Traceback" in debug.stderr and "InputError" in debug.stderr


def test_debug_is_taken_after_the_command_too(tmp_path: Path) -> None:
    result = run_ekfviz("replay", str(tmp_path / "missing.txt"), "--save", "x.rrd", "--debug",
                        cwd=tmp_path)  # fmt: skip
    assert result.returncode == 1 and "Traceback" in result.stderr


def test_a_multi_value_option_missing_a_number_says_how_many(tmp_path: Path) -> None:
    result = run_ekfviz("replay", SAMPLE, "--init-pose-sigma", "0.1", "0.1", "--save", "x.rrd",
                        cwd=tmp_path)  # fmt: skip
    assert result.returncode == 2 and list(tmp_path.iterdir()) == []
    assert result.stderr.strip() == (
        "error: --init-pose-sigma needs 3 numbers (SX SY STHETA), found '--save'"
    )


def test_a_multi_value_option_given_with_equals_is_read_as_click_reads_it(
    tmp_path: Path,
) -> None:
    """``--init-pose-sigma=0.1 0.1 0.1`` is click's syntax: ekfviz's own check counted the
    first value twice and refused it ("found fewer", "found '-o'")."""
    log, truth = tmp_path / "run.txt", tmp_path / "run.json"
    result = runner.invoke(app, ["simulate", "--init-pose-sigma=0.1", "0.2", "0.3", "-o",
                                 str(log), "--truth-out", str(truth)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads(truth.read_text())["init_pose_sigma"] == [0.1, 0.2, 0.3]


def test_vary_with_a_negative_sigma_says_it_must_be_positive() -> None:
    result = runner.invoke(app, ["sweep", str(SAMPLE), "--vary", "sigma_x=-1"])
    assert result.exit_code == 2 and "must be positive" in result.stderr


def test_two_filters_of_one_label_and_a_run_too_short_to_calibrate(tmp_path: Path) -> None:
    """Two rows named alike could not be told apart in a comparison's table or report; a
    run too short to calibrate on said numpy's "Singular matrix"."""
    result = runner.invoke(app, ["compare", str(SAMPLE), "--filter", "ekf", "--filter", "ekf",
                                 "--label", "A", "--label", "A"])  # fmt: skip
    assert result.exit_code == 2
    assert result.output.strip() == (
        "error: --label A given twice: give each filter a name of its own"
    )
    log, truth, short = tmp_path / "run.txt", tmp_path / "run.json", tmp_path / "short.txt"
    result = runner.invoke(app, ["simulate", "-o", str(log), "--truth-out", str(truth)])
    assert result.exit_code == 0, result.output
    short.write_text("\n".join(log.read_text().splitlines()[:5]) + "\n")
    result = runner.invoke(app, ["calibrate", str(short), "--truth", str(truth)])
    assert result.exit_code == 2, result.output
    assert "too short a run to calibrate on" in result.output


# -- the library, as a notebook calls it ---------------------------------------------------


@pytest.mark.parametrize(
    ("given", "said"),
    [
        ({"update": "bogus"}, "update 'bogus': expected one of 'sequential', 'joint'"),
        ({"landmark_init": "nonsense"}, "landmark_init 'nonsense': expected one of"),
        ({"motion_noise": "per-minute"}, "motion_noise 'per-minute': expected one of"),
        ({"sigma_bearing": 0}, "sigma_bearing 0.0: expected a sigma above 0 (R must be"),
        ({"sigma_range": -0.1}, "sigma_range -0.1: expected a sigma above 0"),
        ({"sigma_x": -1}, "sigma_x -1.0: expected a sigma of 0 or more"),
        ({"sigma_alpha": float("nan")}, "sigma_alpha nan: expected a finite number"),
        ({"sigma_y": "0.1"}, "sigma_y '0.1': expected a number"),
        ({"init_pose": (1.0, 2.0)}, "init_pose (1.0, 2.0): expected 3 finite numbers"),
        ({"init_pose_sigma": (0.1, 0.1, -0.1)}, "init_pose_sigma (0.1, 0.1, -0.1): expected"),
        ({"odometry_scale": 1.0}, "odometry_scale 1.0: expected 2 finite numbers"),
        ({"gate": 0.0}, "gate 0.0: expected a NIS threshold above 0, or None"),
    ],
)
def test_filter_params_refuse_what_no_filter_runs_with(given: dict[str, object], said: str) -> None:
    """``FilterParams(update="joint")`` ran the sequential update, ``"bogus"`` too;
    ``sigma_bearing=0`` a singular R, with landmarks metres off; the command line refused
    them, the library did not."""
    from ekfviz.core.params import FilterParams

    with pytest.raises(ValueError) as error:
        FilterParams(**given)  # type: ignore[arg-type]
    assert str(error.value).startswith(said), str(error.value)


def test_filter_params_take_an_option_as_text_and_a_pose_as_a_list() -> None:

    from ekfviz.core.params import FilterParams, LandmarkInit, UpdateMode

    params = FilterParams(update="joint", landmark_init="independent",  # type: ignore[arg-type]
                          init_pose=[1, 2, np.float32(0.5)])  # type: ignore[arg-type]  # fmt: skip
    assert params.update is UpdateMode.JOINT and params.landmark_init is LandmarkInit.INDEPENDENT
    assert params.init_pose == (1.0, 2.0, 0.5)


def test_the_readers_and_the_replay_take_paths_as_text_or_say_what_they_take() -> None:
    from ekfviz.io.truth import read_truth
    from ekfviz.sources import read_log

    log, truth = str(DATA / "classic.txt"), str(DATA / "classic_truth.json")
    events = list(read_log(log))
    assert len(events) == 59 and read_truth(truth).ids.size == 6
    with pytest.raises(TypeError, match=r"replay takes events, not a path: replay\(read_log"):
        list(replay(log))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"params: expected FilterParams\(\.\.\.\), got dict"):
        list(replay(events, {"sigma_x": 0.1}))  # type: ignore[arg-type]
