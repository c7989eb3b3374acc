"""What a run warns of, once and in words (wrapped bearings, skipped observations, a
study's and a check's log), never as a Python warning; and an error after warnings is
still the one line on stderr.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from commands import run_ekfviz
from typer.testing import CliRunner

from ekfviz.cli import app

runner = CliRunner()


def test_bearings_outside_pi_are_wrapped_with_one_warning(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text("0.1 5 4.0 6\n3 0\n0.1 5 -4.0 6\n3 0\n0.1 5 7 6\n")
    result = runner.invoke(app, ["replay", str(log), "--save", str(tmp_path / "r.rrd")])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1
    assert f"{log}:1: found bearing 4 outside (-pi, pi]" in warnings[0]


def test_a_skipped_observation_is_a_warning_in_the_terminal_and_the_recording(
    tmp_path: Path,
) -> None:
    from conftest import entity_rows

    log = tmp_path / "log.txt"
    # landmark 1 mapped at (1, 0); the robot drives onto it and sees it at 0.5 m
    log.write_text("observe 1 0 1\ncontrol 1 0\nobserve 1 0 0.5\ncontrol 1 0\nobserve 1 3.1 0.9\n")
    rrd = tmp_path / "r.rrd"
    result = runner.invoke(app, ["replay", str(log), "--save", str(rrd)], env={"COLUMNS": "400"})
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1
    assert f"{log}:3: landmark 1: predicted 0 m from the robot" in warnings[0]
    log_rows = entity_rows(rrd, "/log")
    warned = [row for row in log_rows if row["TextLog:level"] == ["WARN"]]
    assert len(warned) == 1 and warned[0]["event"] == 2
    assert "observation skipped" in str(warned[0]["TextLog:text"])
    skipped = {
        row["event"]: row["Scalars:scalars"]
        for row in entity_rows(rrd, "/metrics/health/skipped_observations")
    }
    assert skipped == {0: [0.0], 2: [1.0], 4: [0.0]}
    pose_health = entity_rows(rrd, "/metrics/health/pose_min_eigenvalue")
    assert [row["event"] for row in pose_health] == [0, 2, 4]  # at the updates
    checked = entity_rows(rrd, "/metrics/health/P_min_eigenvalue")
    assert [row["event"] for row in checked] == [0, 2, 4]  # first, skip, last
    assert all(value > 0 for row in checked for value in row["Scalars:scalars"])  # type: ignore[attr-defined]


def test_extreme_values_in_range_replay_without_a_python_warning(tmp_path: Path) -> None:
    """Numbers near the limit make a nonsense run, told by the filter's own checks, never
    by numpy's RuntimeWarnings (a source line on stderr)."""
    log = tmp_path / "big.txt"
    log.write_text("0.1 1e17 0.2 1e18\n1e18 0.1\n0.1 1e17 0.2 1e18\n1e18 3\n0.3 1e18 0.2 1e17\n")
    result = run_ekfviz("replay", log, "--save", tmp_path / "r.rrd")
    assert result.returncode in (0, 2), result.stderr
    assert "RuntimeWarning" not in result.stderr and "Traceback" not in result.stderr
    assert all(line.startswith(("warning: ", "error: ")) for line in result.stderr.splitlines())


@pytest.mark.parametrize(
    ("text", "args"),
    [  # a warning of line 1 (a bearing wrapped), then the error of line 3
        ("0.1 5 4.0 6\n1 0\n0.1 abc\n", ()),
        ("observe 1 0.1 5 2 4.0 6\ncontrol 1 0\nobserve 1 0.1 abc\n", ("--json",)),
        # --json: what is printed for people goes to stderr (the header's noise), held too
        ("# noise: sigma_x=0.1\nobserve 1 0.1 5 2 0.2 6\nobserve 1.5 0.1 5\n", ("--json",)),
    ],
)
def test_an_error_is_the_one_line_on_stderr_whatever_was_said_before_it(
    tmp_path: Path, text: str, args: tuple[str, ...]
) -> None:
    log = tmp_path / "log.txt"
    log.write_text(text)
    done = run_ekfviz("replay", log, *args, "--save", tmp_path / "x.rrd")
    assert done.returncode == 2
    assert len(done.stderr.splitlines()) == 1 and done.stderr.startswith(f"error: {log}:3: ")


def test_the_warnings_of_a_run_that_ends_well_are_all_said(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text("0.1 5 4.0 6\n1 0\n0.1 5 0.3 6\n")
    done = run_ekfviz("replay", log, "--json", "--save", tmp_path / "x.rrd")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["consistency"]
    said = done.stderr.splitlines()
    assert said[0] == (
        f"warning: {log}:1: found bearing 4 outside (-pi, pi], wrapped it and any later ones"
        " into range"
    )
    assert "Landmarks at the end of the run" in said  # the results after it


@pytest.mark.parametrize(
    "command",
    [["sweep", "--vary", "sigma_range=x1,x2", "--workers", "1"], ["check", "--filter", "ekf"]],
)
def test_a_study_and_a_check_say_the_warnings_of_their_log(
    tmp_path: Path, command: list[str]
) -> None:
    log = tmp_path / "log.txt"
    log.write_text("0.1 5 4.0 6\n1 0\n0.1 5 0.3 6\n")
    name, *rest = command
    done = run_ekfviz(name, log, *rest, "--save", tmp_path / "x.rrd")
    assert done.returncode == 0, done.stderr
    assert f"warning: {log}:1: found bearing 4 outside (-pi, pi]" in done.stderr
