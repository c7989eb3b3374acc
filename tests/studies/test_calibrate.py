"""Calibration on simulated data with known answers: odometry errors, noise, held-out
candidates; the readings that see an inflated covariance; the rigid alignment."""

from __future__ import annotations

import json
import math
import shlex
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ekfviz.calibrate.fit import _fit_motion, calibrate, fit_odometry
from ekfviz.calibrate.recommend import (
    TRUSTED_READINGS,
    estimated_params,
    judge,
    recommend,
    run_stats,
)
from ekfviz.cli import app
from ekfviz.core.params import FilterParams, MotionNoise
from ekfviz.core.records import Control, LogEvent, with_ids
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import Consistency, Verdict, reading
from ekfviz.evaluation.errors import evaluate, rigid_alignment, semi_major_3sigma, summarise_map
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.mrclam import MrclamNoise, MrclamWorld, simulate_mrclam
from ekfviz.sources import open_source

runner = CliRunner()

# a robot whose odometry reads 8 % too far and 12 % too little turn, and drifts left
ODOMETRY_ERRORS = MrclamNoise(odometry_scale=(0.92, 1.12), turn_bias=0.05)


def write_dataset(directory: Path, files: dict[str, str]) -> Path:
    directory.mkdir(parents=True)
    for name, text in files.items():
        (directory / name).write_text(text)
    return directory


@pytest.fixture(scope="module")
def skewed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Ten simulated minutes of a robot with systematic odometry errors."""
    files = simulate_mrclam(seed=3, world=MrclamWorld(duration_s=600.0), noise=ODOMETRY_ERRORS)
    return write_dataset(tmp_path_factory.mktemp("skewed") / "sim", files)


@pytest.fixture(scope="module")
def skewed_run(skewed: Path) -> tuple[list[LogEvent], GroundTruth]:
    """The events and the truth of :func:`skewed`, read once (the tests change neither)."""
    return events_and_truth(skewed)


def events_and_truth(directory: Path) -> tuple[list[LogEvent], GroundTruth]:
    source = open_source(directory)  # robot 1
    own = source.own_truth(lambda _: None)
    assert own is not None and own.truth.track_xytheta is not None
    truth = own.truth
    return list(with_ids(source.events(None, None))), truth


def start_of(truth: GroundTruth) -> tuple[float, float, float]:
    assert truth.track_xytheta is not None
    x, y, theta = truth.track_xytheta[0].tolist()
    return x, y, theta


def test_calibrate_recovers_a_known_odometry_scale_error_and_the_noise(
    skewed_run: tuple[list[LogEvent], GroundTruth],
) -> None:
    events, truth = skewed_run
    result = calibrate(events, truth)
    odometry = result.odometry
    assert odometry is not None
    # the truth: distance x 0.92, turn x 1.12 + 0.05 rad per metre
    assert odometry.scale_d == pytest.approx(0.92, abs=0.01)
    assert odometry.scale_alpha == pytest.approx(1.12, abs=0.02)
    assert odometry.bias == pytest.approx(0.05, abs=0.02)
    assert odometry.applied[0] == odometry.scale_d and odometry.applied[1] == odometry.scale_alpha
    # the motion noise of the corrected odometry is the simulator's
    assert result.motion is not None
    np.testing.assert_allclose(
        result.motion.sigmas,
        (ODOMETRY_ERRORS.sigma_x, ODOMETRY_ERRORS.sigma_y, ODOMETRY_ERRORS.sigma_alpha),
        rtol=0.15,
    )
    assert result.range.sigma == pytest.approx(ODOMETRY_ERRORS.sigma_range, rel=0.1)


def test_an_odometry_without_errors_is_left_alone() -> None:
    """No term is applied where the fit cannot tell it from no error."""
    rng = np.random.default_rng(0)
    k = 400
    sum_d = rng.uniform(0.05, 0.2, k)
    sum_alpha = rng.uniform(-0.3, 0.3, k)
    theta = rng.uniform(-math.pi, math.pi, k)
    start = np.column_stack([np.zeros(k), np.zeros(k), theta])
    u = sum_d[:, None] * np.column_stack([np.cos(theta), np.sin(theta)])
    end = np.column_stack([u + rng.normal(0, 0.005, (k, 2)), theta + sum_alpha + rng.normal(
        0, 0.01, k)])  # fmt: skip
    fit = fit_odometry(np.column_stack([start, end, sum_d, sum_alpha, u]))
    assert fit.applied == (1.0, 1.0, 0.0)
    assert abs(fit.scale_d - 1) < 3 * fit.se_d + 1e-12


@pytest.mark.slow
def test_replay_takes_the_odometry_errors_out(
    skewed_run: tuple[list[LogEvent], GroundTruth],
) -> None:
    """The correction of the replay is the one the simulator put in: applied, the final
    map is far closer to the truth than without it."""
    events, truth = skewed_run
    base = FilterParams(
        ODOMETRY_ERRORS.sigma_x, ODOMETRY_ERRORS.sigma_y, ODOMETRY_ERRORS.sigma_alpha,
        ODOMETRY_ERRORS.sigma_bearing, ODOMETRY_ERRORS.sigma_range,
        motion_noise=MotionNoise.PER_SQRT_SECOND,
        init_pose=start_of(truth),
    )  # fmt: skip
    corrected = replace(base, odometry_scale=(0.92, 1.12), odometry_bias=0.05)
    errors = {}
    for name, params in (("raw", base), ("corrected", corrected)):
        last = every_event(replay(events, params))[-1]
        summary = evaluate(last, truth).summary
        assert summary is not None
        errors[name] = summary.mean_error
    assert errors["corrected"] < 0.5 * errors["raw"]
    # the controls the filter saw: d x 0.92, alpha x 1.12 + 0.05 d
    first = next(e for e in events if isinstance(e, Control) and e.d != 0.0)
    d, alpha = corrected.corrected(first.d, first.alpha)
    assert (d, alpha) == pytest.approx((0.92 * first.d, 1.12 * first.alpha + 0.05 * first.d))


def test_calibrate_line_applies_the_correction_and_the_report_holds_the_candidates(
    skewed: Path, tmp_path: Path
) -> None:
    report = tmp_path / "calibration.json"
    result = runner.invoke(
        app, ["calibrate", str(skewed), "--report", str(report)], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 0, result.output
    line = next(x for x in result.output.splitlines() if x.startswith("ekfviz replay "))
    words = shlex.split(line)
    at = words.index("--odometry-scale")
    assert float(words[at + 1]) == pytest.approx(0.92, abs=0.01)
    assert float(words[at + 2]) == pytest.approx(1.12, abs=0.02)
    document = json.loads(report.read_text())
    names = [c["name"] for c in document["candidates"]]
    assert names[0] == "defaults" and "estimated" in names and document["recommended"] in names
    assert document["command"] == line
    chosen = next(c for c in document["candidates"] if c["name"] == document["recommended"])
    defaults = document["candidates"][0]
    assert chosen["held_out"]["verdict"] in TRUSTED_READINGS
    # never worse than the defaults on the held-out judgement, where they are trusted too
    if defaults["credible"] and defaults["held_out"]["verdict"] in TRUSTED_READINGS:
        assert chosen["credible"]
        assert chosen["held_out"]["map"]["mean_error"] <= defaults["held_out"]["map"]["mean_error"]
    assert document["estimates"]["odometry"]["scale_distance"] == pytest.approx(0.92, abs=0.01)
    assert document["split_at"] > 0 and document["fit_share"] == 0.6
    # the printed line runs, and its map is right and credible
    replayed = tmp_path / "replayed.json"
    ran = runner.invoke(app, [*words[1:], "--save", str(tmp_path / "r.rrd"), "--report",
                              str(replayed)])  # fmt: skip
    assert ran.exit_code == 0, ran.output
    summary = json.loads(replayed.read_text())["summary"]
    assert summary["mean_error"] < 0.3
    assert summary["inside_3sigma"] >= 0.8 * summary["landmarks"]


def test_a_sigma_at_its_fit_limit_is_said_and_never_printed(
    skewed_run: tuple[list[LogEvent], GroundTruth],
) -> None:
    """A fit that finds 0 for a sigma (MRCLAM's robot 4: 1e-9 sideways): the replay
    is told a tenth of the default instead, with a note, never the degenerate value."""
    events, truth = skewed_run
    fitted = calibrate(events[: len(events) // 4], truth)
    assert fitted.motion is not None
    sx, _, sa = fitted.motion.sigmas
    at_limit = replace(
        fitted, motion=replace(fitted.motion, sigmas=(sx, 1e-9, sa), at_limit=("y",))
    )
    params, notes = estimated_params(at_limit, FilterParams(), gate=None)
    assert params.sigma_y == pytest.approx(0.1 * FilterParams().sigma_y)
    assert params.sigma_x == sx and params.sigma_alpha == sa
    assert any("hit the lower limit of its fit" in note for note in notes)
    # and the fit says so when a component has no noise at all
    rng = np.random.default_rng(1)
    units = np.zeros((300, 3, 6))  # M_x, M_y, M_a: unit noise in x, y, theta alone
    units[:, 0, 0] = units[:, 1, 3] = units[:, 2, 5] = 1.0
    residuals = np.column_stack([rng.normal(0, 0.1, 300), np.zeros(300),
                                 rng.normal(0, 0.05, 300)])  # fmt: skip
    fit = _fit_motion(residuals, units, MotionNoise.PER_STEP, None)
    assert "y" in fit.at_limit


@pytest.mark.slow
def test_the_held_out_judgement_never_prefers_a_setting_worse_than_the_defaults(
    skewed_run: tuple[list[LogEvent], GroundTruth],
) -> None:
    events, truth = skewed_run
    defaults = FilterParams(motion_noise=MotionNoise.PER_SQRT_SECOND, init_pose=start_of(truth))
    result = recommend(events, truth, defaults, defaults)
    assert result.candidates[0].name == "defaults" and result.best is not None
    best, plain = result.best.held_out, result.candidates[0].held_out
    assert best.verdict in TRUSTED_READINGS  # never a setting its own reading distrusts
    if plain.verdict in TRUSTED_READINGS:
        assert (not best.credible, best.error) <= (not plain.credible, plain.error)


def test_an_inflated_covariance_reads_too_cautious(
    skewed_run: tuple[list[LogEvent], GroundTruth],
) -> None:
    """The same run told ten times the noise: its map is inside 3 sigma and its NEES
    passes, but its NIS lies far below its bounds: too cautious, not consistent."""
    events, truth = skewed_run
    start = start_of(truth)
    n = ODOMETRY_ERRORS
    honest = FilterParams(
        n.sigma_x, n.sigma_y, n.sigma_alpha, n.sigma_bearing, n.sigma_range,
        motion_noise=MotionNoise.PER_SQRT_SECOND, init_pose=start,
        odometry_scale=n.odometry_scale, odometry_bias=n.turn_bias,
    )  # fmt: skip
    inflated = FilterParams(
        10 * n.sigma_x, 10 * n.sigma_y, 10 * n.sigma_alpha, 10 * n.sigma_bearing,
        10 * n.sigma_range, motion_noise=MotionNoise.PER_SQRT_SECOND, init_pose=start,
        odometry_scale=n.odometry_scale, odometry_bias=n.turn_bias,
    )  # fmt: skip
    readings = {}
    for name, params in (("honest", honest), ("inflated", inflated)):
        consistency = Consistency(truth)
        last = None
        for batch in replay(events, params):
            consistency.add(batch)
            last = batch.last
        assert last is not None
        evaluation = evaluate(last, truth, consistency)
        summary = evaluation.summary
        assert summary is not None
        both = consistency.combined()
        assert both is not None
        readings[name] = (both[0], summary, reading(consistency, summary.inside,
                                                    summary.landmarks))  # fmt: skip
    verdict, summary, text = readings["inflated"]
    assert verdict is Verdict.TOO_CAUTIOUS and text.startswith("too cautious")
    assert summary.inside == summary.landmarks  # inside 3 sigma because the ellipses are huge
    honest_verdict, honest_summary, _ = readings["honest"]
    assert honest_verdict is not Verdict.TOO_CAUTIOUS
    assert summary.mean_semi_major > 5 * honest_summary.mean_semi_major


def test_the_alignment_recovers_a_known_rotation_and_translation_exactly() -> None:
    rng = np.random.default_rng(7)
    true_xy = rng.uniform(-10, 10, (12, 2))
    angle, shift = 0.35, np.array([1.5, -2.25])
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    # the estimate is the truth seen in a frame turned by -angle and shifted
    estimate = (true_xy - shift) @ R  # R^T (truth - shift), row-wise
    found_R, found_t = rigid_alignment(estimate, true_xy)
    np.testing.assert_allclose(found_R, R, atol=1e-12)
    np.testing.assert_allclose(found_t, shift, atol=1e-12)
    covs = np.repeat(np.diag([0.01, 0.04])[None], 12, axis=0)
    summary = summarise_map(estimate, covs, true_xy)
    assert summary is not None
    assert summary.aligned_mean_error == pytest.approx(0.0, abs=1e-12)
    assert summary.rotation_deg == pytest.approx(math.degrees(angle))
    assert summary.translation == pytest.approx(float(np.hypot(*shift)))
    assert summary.mean_error > 1.0  # the absolute error sees the frame
    # 3-sigma semi-major of diag(0.01, 0.04): 3 * 0.2
    np.testing.assert_allclose(semi_major_3sigma(covs), 0.6)
    assert summary.mean_semi_major == pytest.approx(0.6)


def test_alignment_refuses_a_reflection() -> None:
    true_xy = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [3.0, 1.0]])
    mirrored = true_xy * np.array([1.0, -1.0])
    R, _ = rigid_alignment(mirrored, true_xy)
    assert np.linalg.det(R) == pytest.approx(1.0)


@pytest.mark.slow
def test_the_fast_judgement_is_the_replay_s(skewed_run: tuple[list[LogEvent], GroundTruth]) -> None:
    """calibrate judges candidates by driving the filter directly: the same final map,
    NEES and NIS as a replay's, with a gate and an odometry correction."""
    events, truth = skewed_run
    params = FilterParams(
        0.05, 0.02, 0.05, 0.03, 0.1, motion_noise=MotionNoise.PER_SQRT_SECOND,
        init_pose=start_of(truth), gate=13.8, odometry_scale=(0.95, 1.05), odometry_bias=0.02,
    )  # fmt: skip
    after = float(events[len(events) // 2].time or 0.0)
    slow, fast = run_stats(events, truth, params, after=after), judge(events, truth, params,
                                                                       after=after)  # fmt: skip
    assert fast.map is not None and slow.map is not None
    assert fast.map == slow.map
    assert fast.nees == pytest.approx(slow.nees, rel=1e-12)
    assert fast.nis == pytest.approx(slow.nis, rel=1e-12)
    assert fast.verdict == slow.verdict


@pytest.mark.slow
def test_where_no_candidate_is_credible_the_closest_is_widened(
    skewed_run: tuple[list[LogEvent], GroundTruth], monkeypatch: pytest.MonkeyPatch
) -> None:
    """No map can have over 100 % inside: the closest candidate is widened twice, 2 and 4
    times, each judged and listed, and the recommendation is still the lowest error."""
    import ekfviz.calibrate.recommend as calibration

    monkeypatch.setattr(calibration, "MAP_CREDIBLE", 1.01)
    events, truth = skewed_run
    defaults = FilterParams(motion_noise=MotionNoise.PER_SQRT_SECOND, init_pose=start_of(truth))
    result = recommend(events, truth, defaults, defaults)
    wider = [c for c in result.candidates if "times wider" in c.name]
    assert [c.name.rsplit(", ", 1)[1] for c in wider] == ["2 times wider", "4 times wider"]
    closest = min(result.candidates[: -len(wider)], key=lambda c: c.held_out.error)
    assert wider[0].params.sigma_range == pytest.approx(2 * closest.params.sigma_range)
    trusted = [c for c in result.candidates if c.held_out.verdict in calibration.TRUSTED_READINGS]
    assert result.best is not None
    assert result.best.held_out.error == min(c.held_out.error for c in trusted)


@pytest.mark.slow
def test_no_setting_is_recommended_where_every_reading_is_distrusted(
    skewed: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where no candidate's held-out reading is consistent, borderline or too cautious,
    calibrate says so plainly and prints no replay line; its warnings are one line."""
    import ekfviz.calibrate.recommend as calibration

    monkeypatch.setattr(calibration, "TRUSTED_READINGS", ())
    report = tmp_path / "calibration.json"
    result = runner.invoke(
        app, ["calibrate", str(skewed), "--report", str(report)], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 0, result.output
    assert "No setting is recommended: every candidate's held-out reading" in result.output
    assert not any(x.startswith("ekfviz replay ") for x in result.output.splitlines())
    document = json.loads(report.read_text())
    assert document["recommended"] is None and document["command"] is None
    fit = [x for x in result.output.splitlines() if "on the estimates and the choice" in x]
    assert len(fit) <= 1 and all(x.endswith("--verbose shows them") for x in fit)
