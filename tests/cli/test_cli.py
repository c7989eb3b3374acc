"""The command line through a subprocess-free CliRunner and a real subprocess."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ekfviz import __version__
from ekfviz.cli import app
from ekfviz.filters.ekf import HAVE_KERNEL
from ekfviz.io.classic import read_classic
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event

DATA = Path(__file__).parents[2] / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
runner = CliRunner()


def test_version() -> None:
    result = runner.invoke(app, ["--version"])
    kernel = "compiled" if HAVE_KERNEL else "numpy (the compiled kernel was not built)"
    assert result.exit_code == 0
    assert result.output.strip() == f"ekfviz {__version__}, filter kernel for small maps: {kernel}"


def test_replay_help_lists_every_option() -> None:
    result = runner.invoke(app, ["replay", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    for option in (
        "--truth",
        "--report",
        "--sigma-x",
        "--sigma-y",
        "--sigma-alpha",
        "--sigma-bearing",
        "--sigma-range",
        "--init-pose-sigma",
        "--landmark-init",
        "--update",
        "--save",
        "--spawn",
        "--serve",
        "--connect",
    ):
        assert option in result.output


def test_replay_saves_reports_and_prints_the_table(tmp_path: Path) -> None:
    rrd, report = tmp_path / "run.rrd", tmp_path / "report.json"
    result = runner.invoke(
        app,
        ["replay", str(SAMPLE), "--truth", str(TRUTH), "--save", str(rrd), "--report", str(report)],
        env={"COLUMNS": "200"},
    )
    assert result.exit_code == 0, result.output
    assert rrd.stat().st_size > 0
    document = json.loads(report.read_text())
    last = every_event(replay(read_classic(SAMPLE)))[-1]
    np.testing.assert_allclose(document["final_pose"], last.pose, atol=1e-12)
    assert -math.pi < document["final_pose"][2] <= math.pi
    np.testing.assert_allclose(document["final_pose_cov"], last.pose_cov, atol=1e-15)
    assert [lm["id"] for lm in document["landmarks"]] == [1, 2, 3, 4, 5, 6]
    for entry in document["landmarks"]:
        assert set(entry) >= {"id", "estimate", "cov", "euclidean", "mahalanobis", "inside_3sigma"}
        assert entry["inside_3sigma"] == (entry["mahalanobis"] < 3)
    assert document["parameters"] == {
        "sigma_x": 0.25,
        "sigma_y": 0.1,
        "sigma_alpha": 0.1,
        "sigma_bearing": 0.01,
        "sigma_range": 0.08,
        "init_pose": [0.0, 0.0, 0.0],
        "init_pose_sigma": [0.02, 0.02, 0.1],
        "landmark_init": "correlated",
        "update": "sequential",
        "motion_noise": "per-step",
        "gate": None,
        "odometry_scale": [1.0, 1.0],
        "odometry_bias": 0.0,
    }
    assert "Mahalanobis" in result.output and "Final pose" in result.output
    assert "6 of 6 landmarks inside their 3-sigma ellipse" in result.output
    # the summary: errors beside the ellipses' size, and after the rigid alignment
    summary = document["summary"]
    errors = [lm["euclidean"] for lm in document["landmarks"]]
    assert summary["mean_error"] == pytest.approx(np.mean(errors))
    assert summary["worst_error"] == pytest.approx(max(errors))
    axes = [
        3 * math.sqrt(max(np.linalg.eigvalsh(np.array(lm["cov"])))) for lm in document["landmarks"]
    ]
    assert summary["mean_semi_major_3sigma"] == pytest.approx(np.mean(axes))
    assert summary["aligned_mean_error"] <= summary["mean_error"] + 1e-12
    aligned = [lm["aligned_error"] for lm in document["landmarks"]]
    assert summary["aligned_mean_error"] == pytest.approx(np.mean(aligned))
    assert "mean 3σ semi-major axis" in result.output and "best rigid alignment" in result.output


def test_options_reach_the_filter(tmp_path: Path) -> None:
    report = tmp_path / "report.json"
    result = runner.invoke(
        app,
        [
            "replay",
            str(SAMPLE),
            "--save",
            str(tmp_path / "r.rrd"),
            "--report",
            str(report),
            "--sigma-range",
            "0.2",
            "--update",
            "joint",
            "--landmark-init",
            "independent",
            "--init-pose-sigma",
            "0.1",
            "0.1",
            "0.2",
        ],
    )
    assert result.exit_code == 0, result.output
    document = json.loads(report.read_text())
    assert document["parameters"]["sigma_range"] == 0.2
    assert document["parameters"]["update"] == "joint"
    assert document["parameters"]["landmark_init"] == "independent"
    assert document["parameters"]["init_pose_sigma"] == [0.1, 0.1, 0.2]
    assert "euclidean" not in document["landmarks"][0]  # no truth given


def test_without_truth_the_table_shows_estimates_and_sigmas(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["replay", str(SAMPLE), "--save", str(tmp_path / "r.rrd")], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 0
    assert "σ x" in result.output and "Mahalanobis" not in result.output


@pytest.mark.parametrize(
    ("content", "expected", "kept"),
    [
        ("1 2 3\n", "log.txt:1: found 3 numbers on the first line", False),
        ("0.1 5 0.2 6\n3 0\n1 2 3\n", "log.txt:3: found 3 numbers, expected 2", True),
        ("0.1 5 0.2 6\n3 nan\n", "log.txt:2: found 'nan', expected a finite number", True),
        # a number no filter arithmetic survives is refused where it is read
        ("0.1 5 0.2 6\n1e308 0\n", "log.txt:2: found '1e308', expected a number within", True),
    ],
)
def test_bad_input_is_one_line_exit_2_and_keeps_what_came_before(
    tmp_path: Path, content: str, expected: str, kept: bool
) -> None:
    from conftest import entity_rows

    log = tmp_path / "log.txt"
    log.write_text(content)
    rrd = tmp_path / "old.rrd"
    rrd.write_bytes(b"previous recording")
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(log), "--save", str(rrd)],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert expected in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr
    assert rrd.read_bytes() == b"previous recording"  # never replaced by a partial run
    if not kept:  # nothing was replayed: nothing beside it either
        assert sorted(p.name for p in tmp_path.iterdir()) == ["log.txt", "old.rrd"]
        return
    partial = tmp_path / "old.partial.rrd"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.txt", partial.name, "old.rrd"]
    assert f"the recording of everything before it is saved in {partial}" in result.stderr
    log_lines = [row["TextLog:text"] for row in entity_rows(partial, "/log")]
    assert log_lines[0] == ["step 0 init line 1: 2 landmarks (2 new)"]
    assert expected in str(log_lines[-1][0])  # type: ignore[index]


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
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", *args, "--save", str(tmp_path / "x.rrd")]
        if args[0] == "replay"
        else [sys.executable, "-m", "ekfviz", *args],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert result.returncode == 2, result.stderr
    assert expected in result.stderr and "Traceback" not in result.stderr


def test_info_on_a_file_that_is_not_a_recording(tmp_path: Path) -> None:
    bogus = tmp_path / "bogus.rrd"
    bogus.write_text("not a recording")
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "info", str(bogus)], capture_output=True, text=True
    )
    assert result.returncode == 2
    assert str(bogus) in result.stderr and "Traceback" not in result.stderr


@pytest.fixture(scope="module")
def long_enough_for_a_bar(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A log over the progress bar's threshold (1 MiB), replayed in about a second."""
    from ekfviz.app.replay import PROGRESS_MIN_BYTES

    log = tmp_path_factory.mktemp("bar") / "long.txt"
    made = runner.invoke(
        app, ["simulate", "--scenario", "loop", "--steps", "20000", "--landmarks", "40",
              "-o", str(log), "--truth-out", str(log.with_suffix(".json"))],
    )  # fmt: skip
    assert made.exit_code == 0, made.output
    assert log.stat().st_size > PROGRESS_MIN_BYTES
    return log


def test_a_long_replay_writes_nothing_to_a_standard_error_that_is_no_terminal(
    long_enough_for_a_bar: Path, tmp_path: Path
) -> None:
    """No progress bar on a pipe or a file: not even the blank line a bar ends with."""
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(long_enough_for_a_bar),
         "--save", str(tmp_path / "run.rrd")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert result.returncode == 0 and result.stderr == ""


def test_a_long_replay_shows_its_progress_on_a_terminal_and_its_results_where_asked(
    long_enough_for_a_bar: Path, tmp_path: Path
) -> None:
    """The bar on a terminal, the JSON document where standard output goes (a file
    here): rich's bar, left to itself, sent standard output to its terminal too, and
    ``replay BIG --json > out.json`` wrote an empty file."""
    import os
    import pty

    leader, follower = pty.openpty()
    document = tmp_path / "out.json"
    with document.open("w") as stdout:
        process = subprocess.Popen(
            [sys.executable, "-m", "ekfviz", "replay", str(long_enough_for_a_bar), "--json",
             "--save", str(tmp_path / "run.rrd")],
            stdout=stdout, stderr=follower,
            env={**os.environ, "TERM": "xterm", "COLUMNS": "120"},
        )  # fmt: skip
        os.close(follower)
        shown = b""
        while True:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # the terminal's other end closed: the run is over
                break
            if not chunk:
                break
            shown += chunk
        os.close(leader)
        assert process.wait(timeout=60) == 0
    assert f"replaying {long_enough_for_a_bar.name}".encode() in shown
    assert b"Landmarks at the end of the run" in shown  # --json: the tables on stderr
    assert b"error" not in shown and b"Traceback" not in shown
    assert b'"final_pose"' not in shown
    assert "final_pose" in json.loads(document.read_text())


@pytest.mark.parametrize("encoding", ["ascii", "latin-1"])
def test_a_terminal_that_cannot_show_unicode_gets_the_results_not_a_traceback(
    tmp_path: Path, encoding: str
) -> None:
    """sigma, plus-minus and the tables' lines on an ASCII or Latin-1 standard output
    (``LC_ALL=C`` with ``PYTHONUTF8=0``, ``PYTHONIOENCODING``): replaced, not fatal."""
    import os

    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(SAMPLE), "--save",
         str(tmp_path / "run.rrd")],
        capture_output=True, env={**os.environ, "PYTHONIOENCODING": encoding},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr.decode(encoding, "replace")
    assert result.stderr == b""
    text = result.stdout.decode(encoding)
    assert "Landmarks at the end of the run" in text and "Final pose: x " in text
    assert "+----" in text  # the table drawn in ASCII
