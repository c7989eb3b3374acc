"""The simulator, its scenarios, `ekfviz simulate` and `ekfviz convert`."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from commands import run_ekfviz
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.records import Sighting
from ekfviz.io.classic import read_classic
from ekfviz.io.extended import read_extended, read_log
from ekfviz.io.truth import read_truth
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import classic, loop
from ekfviz.sim.simulate import Noise

runner = CliRunner()
SAMPLE = Path(__file__).parents[2] / "data" / "classic.txt"


def simulate(tmp_path: Path, *args: str, stem: str = "run") -> tuple[Path, Path]:
    log, truth = tmp_path / f"{stem}.txt", tmp_path / f"{stem}.json"
    result = runner.invoke(app, ["simulate", *args, "-o", str(log), "--truth-out", str(truth)])
    assert result.exit_code == 0, result.output
    return log, truth


def test_simulate_is_deterministic_in_its_seed(tmp_path: Path) -> None:
    for scenario in ("classic", "loop"):
        a = simulate(tmp_path, "--scenario", scenario, "--seed", "3", stem=f"{scenario}-a")
        b = simulate(tmp_path, "--scenario", scenario, "--seed", "3", stem=f"{scenario}-b")
        c = simulate(tmp_path, "--scenario", scenario, "--seed", "4", stem=f"{scenario}-c")
        assert a[0].read_bytes() == b[0].read_bytes() and a[1].read_bytes() == b[1].read_bytes()
        assert a[0].read_bytes() != c[0].read_bytes()


def test_classic_scenario_is_the_reference_run(tmp_path: Path) -> None:
    log, truth_path = simulate(tmp_path, "--scenario", "classic")
    events = list(read_classic(log))
    assert len(events) == 59
    assert sum(isinstance(e, Sighting) for e in events) == 30
    truth = read_truth(truth_path)
    np.testing.assert_array_equal(
        truth.landmarks_xy, [[3, 6], [3, 12], [7, 8], [7, 14], [11, 6], [11, 12]]
    )
    assert truth.poses_xytheta is not None and truth.poses_xytheta.shape == (30, 3)
    assert truth.simulated_with is not None and truth.simulated_with["sigma_x"] == 0.25


def test_loop_closes_and_landmarks_come_and_go() -> None:
    world = loop()
    assert len(world.controls) >= 1000 and len(world.landmarks_xy) == 200
    run = world.run(Noise.none(), init_pose_sigma=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(run.poses_xytheta[-1], run.poses_xytheta[0], atol=1e-9)
    sightings = [e for e in run.events if isinstance(e, Sighting)]
    counts = [len(s.ids) for s in sightings]
    assert max(counts) < 40 and min(counts) >= 0
    first_seen: dict[int, int] = {}
    for k, sighting in enumerate(sightings):
        for landmark_id in sighting.ids.tolist():
            first_seen.setdefault(landmark_id, k)
    assert len(first_seen) > 150
    assert sum(k > 0 for k in first_seen.values()) > 100  # most are first seen mid-run
    # the start area is seen again at the end: the loop closes
    assert set(sightings[0].ids.tolist()) & set(sightings[-1].ids.tolist())
    ranges = np.concatenate([s.z[:, 1] for s in sightings if len(s.ids)])
    bearings = np.concatenate([s.z[:, 0] for s in sightings if len(s.ids)])
    assert ranges.max() <= 15.0 and np.abs(bearings).max() <= math.pi / 2


def test_noise_free_loop_with_partial_observations_recovers_the_map() -> None:
    run = loop(steps=300, landmarks=60).run(Noise.none(), init_pose_sigma=(0.0, 0.0, 0.0))
    last = every_event(replay(run.events))[-1]
    truth = dict(zip(run.landmark_ids.tolist(), run.landmarks_xy, strict=True))
    for landmark_id, xy in zip(last.landmark_ids.tolist(), last.landmarks_xy, strict=True):
        np.testing.assert_allclose(xy, truth[landmark_id], atol=1e-9)
    np.testing.assert_allclose(last.pose, run.poses_xytheta[-1], atol=1e-9)


@pytest.mark.slow
def test_loop_matched_filter_keeps_most_landmarks_inside_3_sigma(tmp_path: Path) -> None:
    log, truth = simulate(tmp_path, "--scenario", "loop", "--seed", "2", "--steps", "1000")
    report = tmp_path / "r.json"
    args = [
        "replay",
        str(log),
        "--truth",
        str(truth),
        "--save",
        str(tmp_path / "r.rrd"),
        "--report",
        str(report),
    ]
    simulated_with = read_truth(truth).simulated_with
    assert simulated_with is not None
    for name in ("sigma_x", "sigma_y", "sigma_alpha"):
        args += [f"--{name.replace('_', '-')}", str(simulated_with[name])]
    args += ["--init-pose-sigma", "0.01", "0.01", "0.005"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    landmarks = json.loads(report.read_text())["landmarks"]
    inside = np.mean([entry["inside_3sigma"] for entry in landmarks])
    assert inside >= 0.9, inside


def test_loop_cannot_be_written_in_the_classic_format(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["simulate", "--scenario", "loop", "--format", "classic", "-o",
              str(tmp_path / "l.txt"), "--truth-out", str(tmp_path / "t.json")],
    )  # fmt: skip
    assert result.exit_code == 2
    assert "does not fit the classic format" in result.output
    assert not (tmp_path / "l.txt").exists()


def test_loop_options_are_refused_for_classic(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["simulate", "--steps", "10", "-o", str(tmp_path / "l.txt"),
              "--truth-out", str(tmp_path / "t.json")],
    )  # fmt: skip
    assert result.exit_code == 2 and "only for --scenario loop" in result.output


def test_convert_keeps_every_number_exactly(tmp_path: Path) -> None:
    log, _ = simulate(tmp_path, "--scenario", "classic", "--precision", "17")
    target = tmp_path / "extended.txt"
    result = runner.invoke(app, ["convert", str(log), str(target)])
    assert result.exit_code == 0, result.output
    for a, b in zip(read_classic(log), read_extended(target), strict=True):
        assert type(a) is type(b)
        if isinstance(a, Sighting) and isinstance(b, Sighting):
            np.testing.assert_array_equal(a.z, b.z)
            np.testing.assert_array_equal(a.ids, b.ids)
    assert [r.pose.tolist() for r in every_event(replay(read_log(log)))] == [
        r.pose.tolist() for r in every_event(replay(read_log(target)))
    ]


def test_scenario_prior_draws_the_true_start() -> None:
    starts = np.array([classic().run(seed=s).poses_xytheta[0] for s in range(200)])
    np.testing.assert_allclose(starts.std(axis=0), [0.02, 0.02, 0.1], rtol=0.2)


@pytest.mark.parametrize(
    ("options", "said"),
    [
        (["simulate", "--true-sigma-x", "nan"], "'--true-sigma-x': found nan, expected a number"),
        (["simulate", "--true-sigma-bearing", "inf"], "'--true-sigma-bearing': inf is not in"),
        (["simulate", "--init-pose-sigma", "-1", "0", "0"], "'--init-pose-sigma': -1.0 is not"),
        (["simulate", "--seed", "-1"], "'--seed': -1 is not in the range x>=0"),
        (["simulate", "--unknown-ids", "--clutter", "inf"], "'--clutter': inf is not in"),
        (["simulate", "--scenario", "loop", "--steps", "1000000000000"], "'--steps':"),
        (["simulate", "--scenario", "loop", "--max-range", "nan"], "'--max-range': found nan"),
        (["simulate", "--layout", "mrclam", "--duration", "nan"], "'--duration': found nan"),
        (["simulate", "--scenario", "loop", "--steps", "10000000", "--laps", "100"],
         "--laps 100 of 10,000,000 controls make 1,000,000,000, more than a simulated run"),
        (["consistency", "--runs", "2", "--true-sigma-x", "nan"], "'--true-sigma-x': found nan"),
        (["consistency", "--runs", "2", "--seed", "-1"], "'--seed': -1 is not in the range"),
        (["calibrate", "LOG", "--fit-share", "nan"], "'--fit-share': found nan"),
    ],
)  # fmt: skip
def test_an_option_value_no_simulation_can_take_is_one_line(
    tmp_path: Path, options: list[str], said: str
) -> None:
    """NaN passes a range (every comparison with it is false): a NaN sigma wrote a log of
    NaN, ``consistency`` read "consistent"; an infinite clutter, a negative seed, 10^12
    steps and a NaN duration ended in tracebacks (numpy's Poisson, its seed, its memory)."""
    name, *rest = options
    rest = [str(SAMPLE) if part == "LOG" else part for part in rest]
    if name == "simulate":
        rest += ["-o", str(tmp_path / "run"), "--truth-out", str(tmp_path / "t.json")]
    result = runner.invoke(app, [name, *rest])
    assert result.exit_code == 2, result.output
    assert said in result.output and len(result.output.strip().splitlines()) == 1, result.output
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("options", "said"),
    [
        (["--layout", "mrclam", "--scenario", "loop"], "--scenario: not for --layout mrclam"),
        (["--layout", "mrclam", "--steps", "50"], "--steps: not for --layout mrclam"),
        (["--layout", "mrclam", "--unknown-ids"], "--unknown-ids: not for --layout mrclam"),
        (["--layout", "mrclam", "--precision", "2"], "--precision: not for --layout mrclam"),
        (["--duration", "5", "--truth-out", "TRUTH"], "--duration: not for --layout file"),
    ],
)
def test_an_option_the_layout_does_not_use_is_refused(
    tmp_path: Path, options: list[str], said: str
) -> None:
    """``--layout mrclam`` wrote its fixed dataset whatever the scenario, steps, scans or
    precision asked for; the file layout ignored ``--duration``."""
    options = [str(tmp_path / "t.json") if part == "TRUTH" else part for part in options]
    result = runner.invoke(app, ["simulate", "-o", str(tmp_path / "out"), *options])
    assert result.exit_code == 2, result.output
    assert result.output.strip() == f"error: {said}"
    assert not (tmp_path / "out").exists()


def test_a_log_and_its_truth_are_replaced_together_or_not_at_all(tmp_path: Path) -> None:
    """With ``--force`` the new log replaced the old one, then the truth's write failed
    (a file-size limit): a log and a truth that no longer belonged together, under
    "nothing was replaced"."""
    import resource
    import subprocess
    import sys

    log, truth = tmp_path / "run.txt", tmp_path / "run.json"
    # a loop seeing nothing (--max-range 0): a short log, a long truth (the landmarks)
    run = ["simulate", "-o", str(log), "--truth-out", str(truth), "--scenario", "loop",
           "--steps", "200", "--max-range", "0"]  # fmt: skip
    result = runner.invoke(app, run)
    assert result.exit_code == 0, result.output
    before = (log.read_bytes(), truth.read_bytes())
    assert len(before[0]) < 16 << 10 < len(before[1])  # the log fits the limit, the truth not

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (16 << 10, 16 << 10))

    done = subprocess.run(
        [sys.executable, "-m", "ekfviz", *run, "--seed", "9", "--force"],
        capture_output=True, text=True, preexec_fn=limited, timeout=120,
        env={**os.environ, "XDG_CONFIG_HOME": str(tmp_path), "XDG_DATA_HOME": str(tmp_path)},
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().endswith("cannot write (File too large); nothing was replaced")
    assert (log.read_bytes(), truth.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".tmp") == []


def test_the_commands_it_prints_are_quoted_for_the_shell(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``ekfviz replay sim space.txt --truth tru'th.json`` was printed as it is: pasted,
    two arguments and an open quote."""
    import shlex

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)

    def run(*args: str) -> str:
        done = run_ekfviz(*args, cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        return done.stdout + done.stderr

    said = run("simulate", "-o", "sim space.txt", "--truth-out", "tru'th.json")
    command = shlex.split(said.strip().splitlines()[-1])
    assert command[1:5] == ["replay", "sim space.txt", "--truth", "tru'th.json"], said
    said = run("replay", "sim space.txt")
    line = next(line for line in said.splitlines() if "open it with: " in line)
    opened = line.split("open it with: ", 1)[1]
    assert shlex.split(opened)[1] == "recordings/sim space.rrd", said
