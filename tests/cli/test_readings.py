"""How a run is judged: its consistency reading near the threshold and with its map off, a
truth of fewer poses than steps, the round-off asymmetry of P, a landmark of singular
covariance.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import rerun as rr
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.health import check_covariance
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import (
    INSIDE_BORDERLINE,
    INSIDE_FOR_CONSISTENT,
    BoundCount,
    Consistency,
    Verdict,
    reading,
)
from ekfviz.io.classic import read_classic
from ekfviz.runner.replay import replay

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
runner = CliRunner()


# -- readings ------------------------------------------------------------------------------


def _count(inside: int, above: int, below: int) -> BoundCount:
    return BoundCount(below=below, inside=inside, above=above)


def test_a_run_near_the_threshold_is_borderline_whichever_side_it_misses() -> None:
    assert INSIDE_BORDERLINE < INSIDE_FOR_CONSISTENT
    # one step either way around 90 %: the reading must not flip from one verdict to its
    # opposite
    assert _count(89, 6, 5).verdict is Verdict.BORDERLINE
    assert _count(89, 5, 6).verdict is Verdict.BORDERLINE
    assert _count(90, 5, 5).verdict is Verdict.CONSISTENT
    assert _count(60, 40, 0).verdict is Verdict.OVER_CONFIDENT
    assert _count(60, 0, 40).verdict is Verdict.TOO_CAUTIOUS


def test_a_run_is_never_read_consistent_while_its_map_is_off() -> None:
    consistency = Consistency()
    consistency.nis = _count(97, 2, 1)  # the NIS alone looks fine
    assert reading(consistency, 195, 200) == "consistent"
    off = reading(consistency, 0, 200)
    assert off.startswith("over-confident") and "0/200 landmarks in 3σ" in off
    with_nees = Consistency(nees=_count(40, 60, 0), nis=_count(97, 2, 1))
    assert reading(with_nees, 200, 200) == "over-confident: NEES 60% high"
    # a batch optimum has no per-step statistics: its map is read alone
    assert reading(Consistency(), 6, 6) == "no NEES or NIS; map: 6/6 landmarks in 3σ"
    assert reading(Consistency(), 2, 6).startswith("over-confident")
    assert reading(Consistency(), None, 0) == "no update to judge"


def test_a_truth_with_fewer_poses_than_steps_says_how_many_were_judged() -> None:
    events = list(read_classic(SAMPLE))
    truth_file = json.loads(TRUTH.read_text())
    landmarks = truth_file["landmarks"]
    ids = np.array(sorted(int(k) for k in landmarks))
    xy = np.array([landmarks[str(i)] for i in ids])
    poses = np.array(truth_file["poses"][:11])  # the start and 10 of 29 steps
    consistency = Consistency(GroundTruth(ids, xy, poses))
    for batch in replay(events):
        consistency.add(batch)
    assert consistency.nees.total == 11
    assert any(
        "only 11 of 30 corrected states have a true pose" in s for s in consistency.summary()
    )


# -- symmetry of P -------------------------------------------------------------------------


def test_round_off_asymmetry_is_judged_against_the_size_of_P() -> None:
    P = np.diag([4.0, 4.0, 1.0, 9.0, 9.0])
    P[0, 1], P[1, 0] = 0.5, 0.5 + 4e-16  # a textbook filter's round-off
    check = check_covariance(P)
    assert check.asymmetry > 0 and check.round_off_asymmetry
    assert check.problems() == []
    assert "round-off" in check.problems(round_off=True)[0]
    P[1, 0] = 0.6  # a real fault
    assert "not symmetric" in check_covariance(P).problems()[0]


def test_a_textbook_filter_with_round_off_is_warned_once_a_run(tmp_path: Path) -> None:
    from ekfviz.viz import Recorder, style

    out = tmp_path / "plain.rrd"
    rec = rr.RecordingStream("plain")
    rec.save(out)
    recorder = Recorder(rec, blueprint=False)
    x = np.zeros(3)
    for k in range(6):
        P = np.diag([0.01, 0.02, 0.03]) * (k + 1)
        P[0, 1], P[1, 0] = 0.001, 0.001 * (1 + 1e-15)
        recorder.predict(x, P, control=(1.0, 0.0))
    recorder.finish()
    rec.disconnect()
    warned = [r for r in entity_rows(out, f"/{style.LOG}") if r["TextLog:level"] == ["WARN"]]
    assert len(warned) == 1 and "round-off" in str(warned[0]["TextLog:text"])


# -- a landmark of singular covariance -----------------------------------------------------


def test_a_landmark_of_singular_covariance_has_no_mahalanobis_distance_and_stops_nothing(
    tmp_path: Path,
) -> None:
    """A control of 1e17 (inside the +-1e18 the readers take) drives the covariances
    singular: the run ends and is judged, the singular landmarks' distance NaN."""
    from ekfviz.evaluation.errors import landmark_errors

    covs = np.array([[[2.0, 0.5], [0.5, 1.0]], [[1.0, 1.0], [1.0, 1.0]], [[4.0, 0.0], [0.0, 9.0]]])
    estimates, truth = np.array([[1.0, 2.0], [0.0, 0.0], [3.0, 3.0]]), np.zeros((3, 2))
    euclidean, mahalanobis = landmark_errors(estimates, covs, truth)
    regular = [0, 2]
    alone = landmark_errors(estimates[regular], covs[regular], truth[regular])[1]
    assert np.isnan(mahalanobis[1]) and np.array_equal(mahalanobis[regular], alone)
    assert np.array_equal(euclidean, np.hypot(estimates[:, 0], estimates[:, 1]))
    data = Path(__file__).resolve().parents[2] / "data"
    lines = (data / "loop.txt").read_text().splitlines()[:60]
    assert lines[9].startswith("control ")
    lines[9] = "control 1e17 0"
    log = tmp_path / "huge.txt"
    log.write_text("\n".join(lines) + "\n")
    # the true landmarks alone: the true path is not this log's any more
    landmarks = json.loads((data / "loop_truth.json").read_text())["landmarks"]
    (tmp_path / "truth.json").write_text(json.dumps({"landmarks": landmarks}))
    result = CliRunner().invoke(
        app,
        ["replay", str(log), "--truth", str(tmp_path / "truth.json"), "--save",
         str(tmp_path / "x.rrd")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
