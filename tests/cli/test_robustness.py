"""Every kind of bad input: one line naming file and line, exit code 2, no traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ekfviz.cli import app

runner = CliRunner()
DATA = Path(__file__).parents[2] / "data"
OBS = "0.1 5.0 0.2 6.0"

# name -> (log content, truth content or None, expected message)
CASES: dict[str, tuple[str | bytes | None, str | None, str]] = {
    "missing file": (None, None, "log.txt: no such file"),
    "empty file": ("", None, "log.txt:1: found no data"),
    "blank lines only": ("\n\n   \n\t\n", None, "log.txt:1: found no data"),
    "binary": (b"\x00\x01\x02\xff\xfe", None, "log.txt:1: found bytes that are not UTF-8"),
    "latin-1 text": ("0.1 5 0.2 6 # caf\xe9\n".encode("latin-1"), None, "not UTF-8"),
    "non-numeric token": (f"{OBS}\n3.0 x\n", None, "log.txt:2: found 'x', expected a decimal"),
    "nan": (f"{OBS}\n3.0 NaN\n", None, "log.txt:2: found 'NaN', expected a finite number"),
    "infinity": (f"{OBS}\ninf 0\n", None, "log.txt:2: found 'inf', expected a finite number"),
    "count fits no event": (f"{OBS}\n1 2 3\n", None, "log.txt:2: found 3 numbers, expected 2"),
    "other landmark count": (
        f"{OBS}\n3 0\n{OBS} 0.3 7\n",
        None,
        "log.txt:3: found 6 numbers, expected 2 (a control",
    ),
    "first line a control": (
        "3.0 0.0\n" + OBS + "\n",
        None,
        "log.txt:1: found 2 numbers on the first line",
    ),
    "unknown keyword": (
        "control 1 0\ndrive 1 0\n",
        None,
        "log.txt:2: found 'drive', expected a keyword",
    ),
    "negative range": (
        f"{OBS}\n3 0\n0.1 -5 0.2 6\n",
        None,
        "log.txt:3: found range -5 for landmark 1",
    ),
    "zero range": ("observe 3 0.1 0\n", None, "log.txt:1: found range 0 for landmark 3"),
    "id beyond int64": (
        "observe 99999999999999999999 0.1 5\n",
        None,
        "log.txt:1: found landmark id 99999999999999999999, expected an integer up to",
    ),
    "long line": ("1 " * 600_000 + "\n", None, "log.txt:1: found a line longer than 1 MiB"),
    "truth count": (f"{OBS}\n", "3 6\n3 12\n5 5\n", "truth.txt: found 3 landmarks, expected the 2"),
    "truth ids": ("observe 7 0.1 5\n", "3 6\n", "truth.txt: has no landmark 7, which line 1"),
    "truth bad line": (f"{OBS}\n", "3 6 1\n", "truth.txt:1: found 3 numbers, expected 2"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input(tmp_path: Path, case: str) -> None:
    content, truth, expected = CASES[case]
    log = tmp_path / "log.txt"
    if content is not None:
        log.write_bytes(content.encode() if isinstance(content, str) else content)
    args = ["replay", str(log), "--save", str(tmp_path / "run.rrd")]
    if truth is not None:
        (tmp_path / "truth.txt").write_text(truth)
        args += ["--truth", str(tmp_path / "truth.txt")]
    result = runner.invoke(app, args, env={"COLUMNS": "400"})
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    assert lines[0].startswith("error: ") and expected in lines[0], lines[0]
    assert "Traceback" not in result.output


def test_a_directory_is_refused(tmp_path: Path) -> None:
    result = runner.invoke(app, ["replay", str(tmp_path), "--save", str(tmp_path / "r.rrd")])
    assert result.exit_code == 2 and "is a directory" in result.output


def test_bearings_outside_pi_are_wrapped_with_one_warning(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text("0.1 5 4.0 6\n3 0\n0.1 5 -4.0 6\n3 0\n0.1 5 7 6\n")
    result = runner.invoke(app, ["replay", str(log), "--save", str(tmp_path / "r.rrd")])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1
    assert f"{log}:1: found bearing 4 outside (-pi, pi]" in warnings[0]


def test_debug_shows_the_traceback(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "ekfviz", "replay", str(tmp_path / "nope.txt"), "--save",
               str(tmp_path / "r.rrd")]  # fmt: skip
    plain = subprocess.run(command, capture_output=True, text=True)
    debug = subprocess.run([*command[:3], "--debug", *command[3:]], capture_output=True, text=True)
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert debug.returncode != 0 and "Traceback" in debug.stderr and "InputError" in debug.stderr


@pytest.mark.parametrize(("signum", "code", "word"), [(2, 130, "SIGINT"), (15, 143, "SIGTERM")])
def test_a_signal_leaves_a_complete_recording(
    tmp_path: Path, slow_log: Path, signum: int, code: int, word: str
) -> None:
    import os
    import time

    from conftest import entity_rows, recording_started, rrd_verify

    rrd = tmp_path / "run.rrd"
    process = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", "replay", str(slow_log), "--save", str(rrd)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    recording_started(tmp_path, rrd.name)
    time.sleep(1.0)  # well into the replay, seconds before its end
    os.kill(process.pid, signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == code, stderr
    assert f"interrupted ({word})" in stderr or f"terminated ({word})" in stderr
    assert "Traceback" not in stderr
    rrd_verify(rrd)
    last = entity_rows(rrd, "/log")[-1]
    assert word in str(last["TextLog:text"]) and "after input line" in str(last["TextLog:text"])
    assert not list(tmp_path.glob("*.part"))


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


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize(("signum", "code", "word"), [(2, 130, "SIGINT"), (15, 143, "SIGTERM")])
def test_a_signal_during_start_up_still_leaves_a_recording(
    tmp_path: Path, signum: int, code: int, word: str
) -> None:
    """Even while rerun is still being imported, and with SIGINT ignored by the parent
    (as ``ekfviz ... &`` in a script has it)."""
    import os
    import signal
    import time

    from conftest import catches_signal, entity_rows, rrd_verify

    log = tmp_path / "log.txt"
    log.write_text(f"{OBS}\n" + "1 0.1\n0.1 5 0.2 6\n" * 50)
    rrd = tmp_path / "run.rrd"
    process = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", "replay", str(log), "--save", str(rrd)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    deadline = time.monotonic() + 30
    while not catches_signal(process.pid, signum) and time.monotonic() < deadline:
        time.sleep(0.005)
    os.kill(process.pid, signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == code, stderr
    assert f"({word}) after input line 1;" in stderr and "Traceback" not in stderr
    rrd_verify(rrd)
    assert word in str(entity_rows(rrd, "/log")[-1]["TextLog:text"])


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
    import numpy as np

    from ekfviz.core.params import FilterParams, LandmarkInit, UpdateMode

    params = FilterParams(update="joint", landmark_init="independent",  # type: ignore[arg-type]
                          init_pose=[1, 2, np.float32(0.5)])  # type: ignore[arg-type]  # fmt: skip
    assert params.update is UpdateMode.JOINT and params.landmark_init is LandmarkInit.INDEPENDENT
    assert params.init_pose == (1.0, 2.0, 0.5)


def test_the_readers_and_the_replay_take_paths_as_text_or_say_what_they_take() -> None:
    from ekfviz.io.truth import read_truth
    from ekfviz.runner.replay import replay
    from ekfviz.sources import read_log

    log, truth = str(DATA / "classic.txt"), str(DATA / "classic_truth.json")
    events = list(read_log(log))
    assert len(events) == 59 and read_truth(truth).ids.size == 6
    with pytest.raises(TypeError, match=r"replay takes events, not a path: replay\(read_log"):
        list(replay(log))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"params: expected FilterParams\(\.\.\.\), got dict"):
        list(replay(events, {"sigma_x": 0.1}))  # type: ignore[arg-type]


def test_a_non_ascii_file_name_in_an_ascii_locale_is_one_line_and_recorded(
    tmp_path: Path,
) -> None:
    """With LC_ALL=C and Python's UTF-8 mode off, ``bäd.txt`` reaches Python as lone
    surrogates: Rerun refused them with two warnings before the error, the recording lost
    why the run stopped, and the error named ``b\\udcc3\\udca4d.txt``."""
    import json
    import os

    log = tmp_path / "bäd.txt"
    log.write_text((DATA / "classic.txt").read_text() + "1.0 abc\n")
    env = {**os.environ, "LC_ALL": "C", "PYTHONUTF8": "0", "XDG_CONFIG_HOME": str(tmp_path),
           "XDG_DATA_HOME": str(tmp_path)}  # fmt: skip
    run = [sys.executable, "-m", "ekfviz"]
    done = subprocess.run([*run, "replay", "bäd.txt", "--save", "o.rrd"], capture_output=True,
                          env=env, cwd=tmp_path, timeout=120)  # fmt: skip
    assert done.returncode == 2
    (line,) = done.stderr.decode("ascii", "replace").strip().splitlines()
    assert line.startswith("error: b?d.txt:60: found 'abc'"), line  # (ä in ASCII: ?)
    shown = subprocess.run([*run, "info", "o.rrd", "--json"], capture_output=True, env=env,
                           cwd=tmp_path, timeout=120)  # fmt: skip
    assert shown.returncode == 0 and not shown.stderr, shown.stderr
    info = json.loads(shown.stdout)
    assert info["status"]["reason"].startswith("bäd.txt:60: found 'abc'"), info
    assert info["name"] == "bäd"
