"""The command line through a subprocess-free CliRunner and a real subprocess."""

from __future__ import annotations

import json
import math
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
