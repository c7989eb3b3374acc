"""Chi-square bounds, NEES and NIS, their verdicts, and their series in a recording."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
from simulated import classic_run, classic_truth

from ekfviz import viz
from ekfviz.core.params import FilterParams
from ekfviz.core.records import EventKind, EventRecord
from ekfviz.core.stats import chi2_cdf, chi2_quantile
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import (
    BoundCount,
    Consistency,
    Verdict,
    chi2_bounds,
    pose_nees,
    update_nis,
)
from ekfviz.evaluation.errors import evaluate
from ekfviz.io.classic import format_classic
from ekfviz.io.truth import truth_json
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import classic
from ekfviz.sim.simulate import Noise
from ekfviz.viz import style


@pytest.mark.parametrize(
    ("p", "dof", "expected"),
    [  # from printed chi-square tables (Abramowitz and Stegun, table 26.8)
        (0.025, 1, 0.000982069),
        (0.975, 1, 5.02389),
        (0.025, 2, 0.0506356),
        (0.975, 2, 7.37776),
        (0.025, 3, 0.215795),
        (0.975, 3, 9.34840),
        (0.95, 10, 18.3070),
        (0.05, 30, 18.4927),
        (0.975, 100, 129.561),
    ],
)
def test_chi2_quantiles_match_the_tables(p: float, dof: int, expected: float) -> None:
    assert chi2_quantile(p, dof) == pytest.approx(expected, rel=2e-5)
    assert chi2_cdf(expected, dof) == pytest.approx(p, abs=2e-6)


def test_bounds_of_a_mean_narrow_with_the_number_of_runs() -> None:
    lo1, hi1 = chi2_bounds(3)
    lo50, hi50 = chi2_bounds(3, runs=50)
    assert lo1 < lo50 < 3 < hi50 < hi1
    assert (lo50, hi50) == pytest.approx((2.3597, 3.7160), abs=1e-4)


def test_verdicts() -> None:
    bounds = (1.0, 2.0)
    count = BoundCount()
    for value in [1.5] * 19 + [3.0]:
        count.add(value, bounds)
    assert count.verdict is Verdict.CONSISTENT and count.fraction_inside == 0.95
    over, cautious = BoundCount(), BoundCount()
    for value in [1.5] * 5 + [3.0] * 5:
        over.add(value, bounds)
        cautious.add(0.5 if value > 2 else value, bounds)
    assert over.verdict is Verdict.OVER_CONFIDENT
    assert cautious.verdict is Verdict.TOO_CAUTIOUS
    assert BoundCount().verdict is None


# values against the bounds (1, 2) that read as each verdict, and as none
READINGS = {
    None: [],
    Verdict.CONSISTENT: [1.5] * 20,
    Verdict.BORDERLINE: [1.5] * 17 + [3.0] * 3,
    Verdict.OVER_CONFIDENT: [1.5] * 5 + [3.0] * 5,
    Verdict.TOO_CAUTIOUS: [1.5] * 5 + [0.5] * 5,
}


@pytest.mark.parametrize("nees", list(READINGS), ids=str)
@pytest.mark.parametrize("nis", list(READINGS), ids=str)
def test_the_verdict_is_said_once_and_the_counts_without_it(
    nees: Verdict | None, nis: Verdict | None
) -> None:
    """Whatever the NEES and the NIS read, the summary says the combined verdict in one
    line naming what it rests on, and no other line says a verdict."""
    consistency = Consistency()
    for count, reading in ((consistency.nees, nees), (consistency.nis, nis)):
        for value in READINGS[reading]:
            count.add(value, (1.0, 2.0))
        assert count.verdict is reading
    lines = consistency.summary()
    words = [v.value for v in Verdict] + ["looks"]
    said = [line for line in lines if any(word in line for word in words)]
    if nees is None and nis is None:
        assert lines == [] and consistency.verdict_line() is None
        return
    (line,) = said
    combined = consistency.combined()
    assert combined is not None and line == lines[-1] == consistency.verdict_line()
    basis = {(True, True): "NEES and NIS", (True, False): "NEES alone", (False, True): "NIS alone"}
    assert line.startswith(f"Verdict from the {basis[(nees is not None, nis is not None)]}: ")
    assert line.count(combined[0].value) == 1 or combined[0].value in combined[1]
    assert len(lines) == (nees is not None) + (nis is not None) + 1


def run_nees_fraction(filter_scale: float, seed: int) -> float:
    """The share of steps whose NEES is inside its bounds, with tight prior and a filter
    told ``filter_scale`` times the true noise."""
    prior = (0.001, 0.001, 0.001)
    run = classic().run(seed=seed, init_pose_sigma=prior)
    noise = Noise()
    params = FilterParams(
        sigma_x=filter_scale * noise.sigma_x,
        sigma_y=filter_scale * noise.sigma_y,
        sigma_alpha=filter_scale * noise.sigma_alpha,
        sigma_bearing=filter_scale * noise.sigma_bearing,
        sigma_range=filter_scale * noise.sigma_range,
        init_pose_sigma=prior,
    )
    consistency = Consistency(GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta))
    for batch in replay(run.events, params):
        consistency.add(batch)
    assert consistency.nees.total == 30 and consistency.nis.total == 29
    return consistency.nees.fraction_inside


def test_nees_tells_matched_from_mismatched_filters() -> None:
    matched = np.mean([run_nees_fraction(1.0, seed) for seed in range(10)])
    too_small = np.mean([run_nees_fraction(0.1, seed) for seed in range(10)])
    too_large = np.mean([run_nees_fraction(10.0, seed) for seed in range(10)])
    assert matched > 0.85
    assert too_small < 0.3 and too_large < 0.3


def test_nees_and_nis_with_bounds_are_in_the_recording(tmp_path: Path) -> None:
    run = classic().run(seed=1)
    truth = GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta)
    log = tmp_path / "run.txt"
    log.write_text(format_classic(run.events))
    batches = list(replay(run.events))
    records = every_event(batches)
    rrd = tmp_path / "run.rrd"
    with viz.open_run(viz.run_info("run", "", {}, log, truth=truth), viz.Sinks(save=rrd)) as out:
        for batch in batches:
            out.log(batch)
        out.finish(evaluate(records[-1], truth))
    nees = entity_rows(rrd, f"/{style.NEES}")
    expected = [(r.event, pose_nees(r, truth)) for r in records if r.kind.value != "predict"]
    assert [row["event"] for row in nees] == [event for event, _ in expected]
    for row, (_, value) in zip(nees, expected, strict=True):
        assert row["Scalars:scalars"] == [pytest.approx(value)]
    # a constant bound is a flat line from the first update to the last: two points
    upper = entity_rows(rrd, f"/{style.NEES}/{style.UPPER}")
    assert [row["event"] for row in upper] == [expected[0][0], expected[-1][0]]
    assert all(row["Scalars:scalars"] == [pytest.approx(chi2_bounds(3)[1])] for row in upper)
    lower = entity_rows(rrd, f"/{style.NIS}/{style.LOWER}")
    assert [row["event"] for row in lower] == [2, 58]  # the first and the last update with NIS
    assert [row["Scalars:scalars"] for row in lower] == [[pytest.approx(chi2_bounds(12)[0])]] * 2


def consistency_report(tmp_path: Path, *args: str) -> dict[str, object]:
    from typer.testing import CliRunner

    from ekfviz.cli import app

    report = tmp_path / "mc.json"
    result = CliRunner().invoke(app, ["consistency", *args, "--report", str(report)])
    assert result.exit_code == 0, result.output
    document: dict[str, object] = json.loads(report.read_text())
    return document


TIGHT = ["--init-pose-sigma", "0.001", "0.001", "0.001", "--runs", "12", "--workers", "1"]
SMALL = ["--sigma-x", "0.025", "--sigma-y", "0.01", "--sigma-alpha", "0.01",
         "--sigma-bearing", "0.001", "--sigma-range", "0.008"]  # fmt: skip
LARGE = ["--sigma-x", "2.5", "--sigma-y", "1", "--sigma-alpha", "1",
         "--sigma-bearing", "0.1", "--sigma-range", "0.8"]  # fmt: skip


@pytest.mark.parametrize(
    ("args", "verdict"),
    [
        (TIGHT, "consistent"),
        (TIGHT + SMALL, "over-confident"),
        (TIGHT + LARGE, "too cautious"),
        (["--runs", "12", "--workers", "1"], "over-confident"),  # the classic 0.1 rad prior
    ],
)
def test_monte_carlo_verdicts(tmp_path: Path, args: list[str], verdict: str) -> None:
    document = consistency_report(tmp_path, *args)
    assert document["verdict"] == verdict
    assert document["runs"] == 12
    mean_nees = document["mean_nees"]
    assert isinstance(mean_nees, list) and len(mean_nees) == 30
    lo, hi = chi2_bounds(3, runs=12)
    assert document["nees_bounds"] == [pytest.approx(lo), pytest.approx(hi)]
    inside = np.mean([lo <= v <= hi for v in mean_nees])
    assert document["fraction_inside"] == pytest.approx(inside)


def test_monte_carlo_is_the_same_on_one_or_two_workers(tmp_path: Path) -> None:
    from ekfviz.studies.montecarlo import Trials, monte_carlo

    world = classic()
    trials = Trials(world, world.noise, world.init_pose_sigma, FilterParams())
    one, two = monte_carlo(trials, 4, seed=3, workers=1), monte_carlo(trials, 4, seed=3, workers=2)
    np.testing.assert_array_equal(one.mean_nees, two.mean_nees)
    np.testing.assert_array_equal(one.mean_nis, two.mean_nis)


def test_monte_carlo_recording_holds_the_averaged_curves(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from ekfviz.cli import app

    rrd, report = tmp_path / "mc.rrd", tmp_path / "mc.json"
    result = CliRunner().invoke(
        app, ["consistency", *TIGHT, "--save", str(rrd), "--report", str(report)]
    )
    assert result.exit_code == 0, result.output
    mean_nees = json.loads(report.read_text())["mean_nees"]
    rows = entity_rows(rrd, f"/{style.NEES}")
    assert [row["step"] for row in rows] == list(range(30))
    assert [row["Scalars:scalars"][0] for row in rows] == pytest.approx(mean_nees)  # type: ignore[index]


def test_a_start_known_exactly_leaves_the_first_nees_undefined(tmp_path: Path) -> None:
    """--init-pose-sigma 0 0 0 with true poses: the first pose covariance is singular, so
    its NEES is not judged (and said so), never a crash; every later step is judged."""
    from typer.testing import CliRunner

    from ekfviz.cli import app

    world = classic()
    run = world.run(world.noise, seed=5, init_pose_sigma=(0.0, 0.0, 0.0))
    log = tmp_path / "exact.txt"
    log.write_text(format_classic(run.events))
    truth = tmp_path / "truth.json"
    truth.write_text(truth_json(GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta)))
    rrd, report = tmp_path / "r.rrd", tmp_path / "r.json"
    result = CliRunner().invoke(
        app,
        ["replay", str(log), "--truth", str(truth), "--init-pose-sigma", "0", "0", "0",
         "--save", str(rrd), "--report", str(report)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "1 corrected state(s) with a singular pose covariance" in result.output
    nees = json.loads(report.read_text())["consistency"]["nees"]
    assert nees["inside"] + nees["above"] + nees["below"] == len(run.poses_xytheta) - 1
    assert [row["step"] for row in entity_rows(rrd, f"/{style.NEES}")] == list(
        range(1, len(run.poses_xytheta))
    )


def one_event_at_a_time(records: list[EventRecord], truth: GroundTruth) -> Consistency:
    """The run's NEES and NIS counted event by event, by the definitions of one event
    (:func:`pose_nees`, :func:`update_nis`)."""
    counted = Consistency(truth)
    for record in records:
        counted.last_step = max(counted.last_step, record.step)
        nis = update_nis(record)
        if nis is not None:
            counted.nis.add(nis[0], chi2_bounds(nis[1]))
        if record.kind is EventKind.PREDICT:
            continue
        nees = pose_nees(record, truth)
        if nees is not None:
            counted.nees.add(nees, chi2_bounds(3))
        elif truth.pose_of(record.step, record.time) is None:
            counted.without_true_pose += truth.poses_xytheta is not None
        else:
            counted.singular_pose += 1
    return counted


@pytest.mark.parametrize(
    ("cut", "truth_steps"),
    [(None, 200), (150, 200), (None, 260)],
    ids=["every-pose", "poses-end-early", "poses-past-the-end"],
)
def test_the_counts_see_every_update_in_batches_of_any_size(
    cut: int | None, truth_steps: int
) -> None:
    """The NIS and NEES counts of a run's batches are those of its events one at a time,
    whatever the batches; the updates past the truth's last pose are counted as such,
    and so are the true poses past the run's last step (a truth of a longer run: its
    NEES is said to be suspect)."""
    log = classic_run(200, seed=5, zero_range_at=50)
    truth = classic_truth(truth_steps, seed=5, cut=cut)
    expected = one_event_at_a_time(every_event(replay(log, FilterParams())), truth)
    for size in (1, 7, 4096):
        counted = Consistency(truth)
        for batch in replay(log, FilterParams(), batch_events=size):
            counted.add(batch)
        assert counted.to_json() == expected.to_json(), size
        assert counted.summary() == expected.summary(), size
    assert counted.nis.total == 200
    assert counted.nees.total == (201 if cut is None else 151)
    assert counted.without_true_pose == (0 if cut is None else 50)
    assert counted.unused_true_poses == truth_steps - 200
    said = [line for line in counted.summary() if "past the run's last step (200)" in line]
    assert len(said) == (truth_steps > 200)


@pytest.mark.parametrize("extended", [False, True], ids=["classic", "extended"])
def test_the_command_reports_the_nis_of_every_update(tmp_path: Path, extended: bool) -> None:
    """``ekfviz replay`` of a log without truth reports the NIS of every update, as the
    events counted one at a time give it. An extended log could hold scans, so the
    replay sets up the association for it: its updates by ids count all the same."""
    from typer.testing import CliRunner

    from ekfviz.cli import app
    from ekfviz.io.extended import format_extended, read_log

    log = classic_run(300, seed=5)
    path = tmp_path / "run.txt"
    path.write_text(format_extended(log, None) if extended else format_classic(log, None))
    alone = Consistency()
    for record in every_event(replay(read_log(path), FilterParams())):
        nis = update_nis(record)
        if nis is not None:
            alone.nis.add(nis[0], chi2_bounds(nis[1]))
    report = tmp_path / "report.json"
    result = CliRunner().invoke(
        app, ["replay", str(path), "--save", str(tmp_path / "run.rrd"), "--report", str(report)]
    )
    assert result.exit_code == 0, result.output
    nis = json.loads(report.read_text())["consistency"]["nis"]
    assert (nis["count"], nis["below"], nis["inside"], nis["above"]) == (
        alone.nis.total, alone.nis.below, alone.nis.inside, alone.nis.above,
    )  # fmt: skip
    assert alone.nis.total == 300
