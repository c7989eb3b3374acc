"""The time-scaled motion noise: Q = diag(sigma^2) dt, its Jacobians and its units."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from jacobians import numerical_jacobian

from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams, MotionNoise
from ekfviz.core.records import Control
from ekfviz.core.types import FloatArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.io.extended import read_extended
from ekfviz.models.classic import motion, motion_jacobians

SIGMAS = (0.03, 0.01, 0.02)  # m/sqrt(s), m/sqrt(s), rad/sqrt(s)


def timed() -> FilterParams:
    return FilterParams(
        *SIGMAS, motion_noise=MotionNoise.PER_SQRT_SECOND, init_pose=(1.0, 2.0, 0.7)
    )


def test_predict_adds_W_diag_sigma2_dt_W_T_with_the_models_jacobians(compiled: bool) -> None:
    """P' = G P G^T + W Q dt W^T, G and W of the motion model (which the finite
    differences in test_models check), for a control spanning dt seconds."""
    d, alpha, dt = 0.4, 0.1, 0.37
    ekf = EkfSlam(timed(), compiled=compiled)
    ekf.observe([4], np.array([[0.3, 5.0]]))  # a landmark, so that P_rm is checked too
    x0, P0 = ekf.x.copy(), ekf.P.copy()
    ekf.predict(d, alpha, dt)
    G, W = motion_jacobians(x0[:3], d)
    F = np.eye(len(x0))
    F[:3, :3] = G
    expected = F @ P0 @ F.T
    expected[:3, :3] += W @ np.diag(np.square(SIGMAS)) @ W.T * dt
    np.testing.assert_allclose(ekf.P, expected, atol=1e-15)
    np.testing.assert_allclose(ekf.x[:3], motion(x0[:3], d, alpha), atol=1e-15)


def test_the_noise_jacobian_W_is_that_of_noise_acting_per_sqrt_second() -> None:
    """Noise of e * sqrt(dt) in the robot frame has Jacobian W sqrt(dt) in e."""
    pose, d, alpha, dt = np.array([1.0, -2.0, 2.5]), 0.3, -0.2, 0.25
    _, W = motion_jacobians(pose, d)
    c, s = math.cos(pose[2]), math.sin(pose[2])

    def noisy(e: FloatArray) -> FloatArray:
        e = e * math.sqrt(dt)
        return np.array(
            [
                pose[0] + (d + e[0]) * c - e[1] * s,
                pose[1] + (d + e[0]) * s + e[1] * c,
                pose[2] + alpha + e[2],
            ]
        )

    np.testing.assert_allclose(
        W * math.sqrt(dt), numerical_jacobian(noisy, np.zeros(3), (2,)), atol=1e-8
    )


def test_units_the_noise_of_a_span_does_not_depend_on_how_it_is_cut(compiled: bool) -> None:
    """Creeping (d = 1e-10 m, so that G is the identity to 1e-12) for one second adds
    sigma^2 * 1 s, in one control or in 100: the noise per sqrt(s) is a random walk,
    whatever the logging rate. Per step it is not."""
    whole = EkfSlam(timed(), compiled=compiled)
    whole.predict(1e-10, 0.0, 1.0)
    cut = EkfSlam(timed(), compiled=compiled)
    for _ in range(100):
        cut.predict(1e-12, 0.0, 0.01)
    np.testing.assert_allclose(cut.P, whole.P, rtol=1e-9, atol=1e-12)
    prior = np.square(FilterParams().init_pose_sigma)
    c, s = math.cos(0.7), math.sin(0.7)
    qx, qy, qa = np.square(SIGMAS)
    assert whole.P[2, 2] == pytest.approx(prior[2] + qa * 1.0)
    assert whole.P[0, 0] == pytest.approx(prior[0] + (c * c * qx + s * s * qy) * 1.0)
    per_step = EkfSlam(FilterParams(*SIGMAS), compiled=compiled)
    for _ in range(100):
        per_step.predict(0.0, 0.0, 0.01)
    assert per_step.P[2, 2] == pytest.approx(prior[2] + 100 * qa)  # grows with the rate


def test_a_robot_standing_still_gains_no_uncertainty_from_time(compiled: bool) -> None:
    """Zero odometry (parked, wheels still) for a minute: the time-scaled noise adds
    nothing, where any motion, however small, adds sigma^2 dt."""
    still = EkfSlam(timed(), compiled=compiled)
    before = still.P[:3, :3].copy()
    for _ in range(3000):
        still.predict(0.0, 0.0, 0.02)
    np.testing.assert_array_equal(still.P[:3, :3], before)
    turning = EkfSlam(timed(), compiled=compiled)
    turning.predict(0.0, 1e-6, 60.0)
    assert turning.P[2, 2] == pytest.approx(before[2, 2] + SIGMAS[2] ** 2 * 60.0)
    assert timed().Q_of_motion(0.0, 0.0, 5.0) == pytest.approx(np.zeros((3, 3)))


def test_time_scaled_noise_needs_the_span() -> None:
    ekf = EkfSlam(timed())
    with pytest.raises(FilterError, match="no time span: use --motion-noise per-step"):
        ekf.predict(1.0, 0.0)
    assert FilterParams().Q_of(None) == pytest.approx(FilterParams().Q)
    np.testing.assert_allclose(timed().Q_of(0.5), 0.5 * timed().Q)


def test_extended_controls_span_the_time_since_the_previous_timestamp(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text(
        "observe 1 0.1 5\n2.0 control 1 0\n2.5 observe 1 0.1 4\n3.0 control 1 0\ncontrol 1 0\n"
    )
    controls = [e for e in read_extended(log) if isinstance(e, Control)]
    assert [c.dt for c in controls] == [None, 0.5, None]
