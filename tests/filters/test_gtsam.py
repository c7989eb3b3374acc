"""The GTSAM filters (iSAM2, batch): the graph's noise models, known answers, the protocol."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Control, LogEvent, landmark_marginals, with_ids
from ekfviz.evaluation.errors import landmark_errors
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.protocol import SlamFilter, state_of
from ekfviz.io.extended import read_log
from ekfviz.io.truth import read_truth
from ekfviz.sim.scenarios import classic, loop
from ekfviz.sim.simulate import Noise

gtsam = pytest.importorskip("gtsam")

from ekfviz.filters.gtsam import (  # noqa: E402  (after the skip without gtsam)
    INSTALL_HINT,
    BatchSlam,
    Isam2Slam,
    between_jacobian,
    tangent_to_world,
)

DATA = Path(__file__).parents[2] / "data"
GtsamFilter = Isam2Slam | BatchSlam


def run(slam: SlamFilter, events: tuple[LogEvent, ...] | list[LogEvent]) -> None:
    for event in events:
        if isinstance(event, Control):
            slam.predict(event.d, event.alpha)
        else:
            slam.update(event.ids, event.z)


def central_difference(f: object, at: np.ndarray, h: float = 1e-6) -> np.ndarray:
    assert callable(f)
    columns = []
    for i in range(len(at)):
        step = np.zeros(len(at))
        step[i] = h
        columns.append((np.asarray(f(at + step)) - np.asarray(f(at - step))) / (2 * h))
    return np.column_stack(columns)


@pytest.mark.parametrize(("d", "alpha"), [(3.0, 0.0), (1.0, 1.2566), (0.4, -2.9)])
def test_between_noise_jacobian_matches_finite_differences_of_gtsams_error(
    d: float, alpha: float
) -> None:
    """The EKF's robot-frame noise (e_x, e_y, e_a) moves the between factor's error
    Log(measured^-1 relative) by J e, to first order."""
    measured = gtsam.Pose2(d, 0.0, alpha)

    def error(e: np.ndarray) -> np.ndarray:
        relative = gtsam.Pose2(d + e[0], e[1], alpha + e[2])
        return np.asarray(gtsam.Pose2.Logmap(measured.inverse().compose(relative)))

    np.testing.assert_allclose(
        central_difference(error, np.zeros(3)), between_jacobian(alpha), atol=1e-8
    )


def test_tangent_to_world_matches_finite_differences_of_retract() -> None:
    pose = gtsam.Pose2(1.0, -2.0, 2.2)

    def world(xi: np.ndarray) -> np.ndarray:
        moved = pose.retract(xi)
        return np.array([moved.x(), moved.y(), moved.theta()])

    np.testing.assert_allclose(
        central_difference(world, np.zeros(3)), tangent_to_world(2.2), atol=1e-8
    )


@pytest.mark.parametrize("cls", [Isam2Slam, BatchSlam])
def test_noise_free_logs_recover_the_truth(cls: type[GtsamFilter]) -> None:
    """The classic run and a loop where landmarks enter view mid-run (ids out of order)."""
    for sim in (
        classic().run(noise=Noise.none(), init_pose_sigma=(0.0, 0.0, 0.0)),
        loop(steps=120, landmarks=40).run(noise=Noise.none(), init_pose_sigma=(0.0, 0.0, 0.0)),
    ):
        slam = cls(FilterParams())
        run(slam, sim.events)
        if isinstance(slam, BatchSlam):
            slam.finish()
            assert slam.poses_xytheta is not None
            difference = slam.poses_xytheta - sim.poses_xytheta
            difference[:, 2] = np.remainder(difference[:, 2] + math.pi, 2 * math.pi) - math.pi
            np.testing.assert_allclose(difference, 0.0, atol=1e-6)
        x, P, ids = state_of(slam)
        np.testing.assert_allclose(x[:3], sim.poses_xytheta[-1], atol=1e-6)
        row_of = {int(i): row for row, i in enumerate(sim.landmark_ids)}
        order = np.array([row_of[int(i)] for i in ids])
        assert len(ids) > 0
        np.testing.assert_allclose(x[3:].reshape(-1, 2), sim.landmarks_xy[order], atol=1e-6)
        assert P.shape == (len(x), len(x))
        np.testing.assert_array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > 0


def test_isam2_joint_marginals_equal_the_ekf_covariance_on_noise_free_data() -> None:
    """Linearised at the truth, the smoother's marginal of the current pose and the map is
    the Kalman filter's covariance: at every event, after predicts (carried through the
    motion) and updates (from the Bayes tree) alike, cross-covariances included."""
    sim = loop(steps=60, landmarks=25).run(noise=Noise.none(), init_pose_sigma=(0.0, 0.0, 0.0))
    params = FilterParams(init_pose_sigma=(0.05, 0.05, 0.02))
    ekf, isam = EkfSlam(params), Isam2Slam(params)
    for event in sim.events:
        if isinstance(event, Control):
            ekf.predict(event.d, event.alpha)
            isam.predict(event.d, event.alpha)
        else:
            ekf.observe(event.ids, event.z)
            isam.update(event.ids, event.z)
        assert isam.landmark_ids == ekf.landmark_ids
        difference = isam.x - ekf.x
        difference[2] = math.remainder(difference[2], 2 * math.pi)
        np.testing.assert_allclose(difference, 0.0, atol=1e-7)
        np.testing.assert_allclose(isam.P, ekf.P, rtol=1e-6, atol=1e-8 * np.abs(ekf.P).max())


@pytest.mark.slow
def test_isam2_is_consistent_on_simulated_loops_with_matched_noise() -> None:
    """Pose NEES (3 dof) inside its 95 % bounds at >= 90 % of the updates of noisy loops,
    pooled over three runs (one run's steps are strongly correlated)."""
    scenario = loop(steps=200, landmarks=50)
    noise = scenario.noise
    params = FilterParams(
        sigma_x=noise.sigma_x, sigma_y=noise.sigma_y, sigma_alpha=noise.sigma_alpha,
        sigma_bearing=noise.sigma_bearing, sigma_range=noise.sigma_range,
        init_pose_sigma=scenario.init_pose_sigma,
    )  # fmt: skip
    inside = []
    for seed in (1, 2, 3):
        sim = scenario.run(seed=seed)
        slam, step = Isam2Slam(params), 0
        for event in sim.events:
            if isinstance(event, Control):
                slam.predict(event.d, event.alpha)
                step += 1
                continue
            slam.update(event.ids, event.z)
            error = slam.x[:3] - sim.poses_xytheta[step]
            error[2] = math.remainder(error[2], 2 * math.pi)
            nees = error @ np.linalg.solve(slam.P[:3, :3], error)
            inside.append(0.2158 <= nees <= 9.3484)
    assert np.mean(inside) >= 0.9


def test_classic_sample_batch_and_isam2_hold_the_truth_in_3_sigma_beside_the_ekf() -> None:
    """The bundled classic sample: every landmark's truth inside the 3-sigma ellipse of
    iSAM2 and of the batch optimum; the errors of all three side by side in the output."""
    events = list(with_ids(read_log(DATA / "classic.txt")))
    truth = read_truth(DATA / "classic_truth.json")
    ekf = EkfSlam(FilterParams())
    isam, batch = Isam2Slam(FilterParams()), BatchSlam(FilterParams())
    for event in events:
        if isinstance(event, Control):
            ekf.predict(event.d, event.alpha)
        else:
            ekf.observe(event.ids, event.z)
    run(isam, events)
    run(batch, events)
    batch.finish()
    table = ["filter  " + "  ".join(f"L{i}: err m / mahal" for i in ekf.landmark_ids)]
    states = [
        ("ekf", (ekf.x, ekf.P, np.array(ekf.landmark_ids))),
        ("isam2", state_of(isam)),
        ("batch", state_of(batch)),
    ]
    for name, (x, P, ids) in states:
        euclidean, mahalanobis = landmark_errors(
            x[3:].reshape(-1, 2), landmark_marginals(P, len(ids)), truth.lookup(ids)
        )
        table.append(
            f"{name:6}  "
            + "  ".join(f"{e:.3f} / {m:.2f}" for e, m in zip(euclidean, mahalanobis, strict=True))
        )
        if name != "ekf":
            assert (mahalanobis < 3.0).all(), f"{name}: {mahalanobis}"
    print("\n".join(table))


def test_batch_shows_its_initial_guess_until_finish_and_nothing_after() -> None:
    sim = classic().run(seed=3)
    batch = BatchSlam(FilterParams())
    run(batch, sim.events[:3])  # first sighting, a control, an observation
    guess = batch.x.copy()
    # the guess: landmarks where the first sighting put them, the pose dead-reckoned
    control = sim.events[1]
    assert isinstance(control, Control)
    np.testing.assert_allclose(guess[:3], [control.d, 0.0, control.alpha], atol=1e-12)
    assert batch.P.shape == (15, 15) and np.linalg.eigvalsh(batch.P).min() > 0
    batch.finish()
    assert not np.allclose(batch.x, guess)
    with pytest.raises(FilterError, match="final"):
        batch.predict(1.0, 0.0)


@pytest.mark.parametrize("cls", [Isam2Slam, BatchSlam])
def test_a_landmark_named_twice_is_a_filter_error(cls: type[GtsamFilter]) -> None:
    slam = cls(FilterParams())
    with pytest.raises(FilterError, match="twice"):
        slam.update(np.array([1, 1]), np.array([[0.1, 2.0], [0.2, 3.0]]))


def test_gtsam_filters_satisfy_the_protocol() -> None:
    assert isinstance(Isam2Slam(FilterParams()), SlamFilter)
    assert isinstance(BatchSlam(FilterParams()), SlamFilter)


def test_without_gtsam_the_filters_say_how_to_install_it() -> None:
    code = (
        "import sys\n"
        "class NoGtsam:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] == 'gtsam':\n"
        "            raise ImportError('no gtsam')\n"
        "sys.meta_path.insert(0, NoGtsam())\n"
        "from ekfviz.filters.spec import FilterSpecError, load_filter\n"
        "for name in ('isam2', 'batch'):\n"
        "    try:\n"
        "        load_filter(name)\n"
        "    except FilterSpecError as error:\n"
        "        print(error)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    lines = result.stdout.strip().split("\n")
    assert len(lines) == 2
    assert all(INSTALL_HINT in line and "--filter" in line for line in lines)


@pytest.mark.parametrize("cls", [Isam2Slam, BatchSlam])
def test_a_start_known_exactly_is_a_tight_prior(cls: type[GtsamFilter]) -> None:
    """--init-pose-sigma 0 0 0: GTSAM cannot whiten a zero sigma, so the prior is
    PRIOR_SIGMA_FLOOR; the estimate stays beside the EKF's with the exact start."""
    params = FilterParams(init_pose_sigma=(0.0, 0.0, 0.0))
    events = list(with_ids(read_log(DATA / "classic.txt")))
    ekf, smoother = EkfSlam(params), cls(params)
    run(ekf, events)
    run(smoother, events)
    if isinstance(smoother, BatchSlam):
        smoother.finish()
    assert np.abs(smoother.x[:2] - ekf.x[:2]).max() < 0.05
    assert np.sqrt(smoother.P[0, 0]) == pytest.approx(np.sqrt(ekf.P[0, 0]), rel=0.1)


def test_gtsams_long_messages_become_one_line() -> None:
    from ekfviz.filters.gtsam import reason

    message = (
        "\nIndeterminate linear system detected while working near variable\n"
        "8646911284551352320 (Symbol: x0).\n\nThrown when a linear system is ill-posed.\n"
    )
    assert reason(RuntimeError(message)) == (
        "Indeterminate linear system detected while working near variable"
        " 8646911284551352320 (Symbol: x0)."
    )
    assert reason(RuntimeError("")) == "RuntimeError"
