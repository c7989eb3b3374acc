"""The named operations of the filter: known answers, the laws they obey, and the factored
form of the update against the textbook one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jacobians import numerical_jacobian

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import (
    expected_measurement,
    init_jacobian_measurement,
    init_jacobian_pose,
    innovation,
    landmark_from_measurement,
    landmark_offset,
    measurement_jacobian_landmark,
    measurement_jacobian_pose,
    motion,
    motion_jacobian,
    noise_jacobian,
)
from ekfviz.models.kalman import (
    corrected_covariance,
    corrected_mean,
    innovation_covariance,
    kalman_gain,
    measurement_noise,
    motion_noise,
    new_landmark_covariance,
    new_landmark_cross_covariance,
    predicted_cross_covariance,
    predicted_pose_covariance,
    prior_covariance,
    whitened_correction,
)


def _spd(rng: np.random.Generator, n: int) -> FloatArray:
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.1 * np.eye(n)


def test_one_landmark_and_many_give_the_same_numbers() -> None:
    """Each operation of a measurement takes one offset (2,) or many (K, 2): the stack of
    the single answers (math's atan2 and numpy's may differ in the last bit)."""
    rng = np.random.default_rng(3)
    offsets = rng.uniform(-20.0, 20.0, (7, 2))
    offsets[0] = (-5.0, 1e-9)  # right behind: a bearing of about pi
    for operation in (measurement_jacobian_pose, measurement_jacobian_landmark):
        many = operation(offsets)
        assert many.shape[0] == 7
        for k in range(7):
            assert np.array_equal(many[k], operation(offsets[k]))
    many = expected_measurement(offsets, 0.3)
    for k in range(7):
        np.testing.assert_allclose(many[k], expected_measurement(offsets[k], 0.3), atol=1e-14)
    assert many[0, 0] == pytest.approx(math.pi - 0.3)  # the landmark behind
    z = expected_measurement(offsets, -2.0) + rng.normal(0.0, 0.1, (7, 2))
    np.testing.assert_allclose(innovation(z, many)[3], innovation(z[3], many[3]), atol=1e-14)


def test_known_answers_of_a_landmark_ahead_and_to_the_left() -> None:
    pose = np.array([1.0, 2.0, math.pi / 2])
    offset = landmark_offset(pose, np.array([4.0, 6.0]))  # (3, 4): range 5
    assert offset.tolist() == [3.0, 4.0]
    bearing, rng = expected_measurement(offset, math.pi / 2).tolist()
    assert rng == 5.0 and bearing == pytest.approx(math.atan2(4.0, 3.0) - math.pi / 2)
    np.testing.assert_allclose(
        measurement_jacobian_pose(offset), [[4 / 25, -3 / 25, -1.0], [-3 / 5, -4 / 5, 0.0]]
    )
    np.testing.assert_allclose(
        measurement_jacobian_landmark(offset), [[-4 / 25, 3 / 25], [3 / 5, 4 / 5]]
    )
    # a difference of bearings across +-pi is small
    assert innovation(np.array([math.pi - 0.01, 5.0]), np.array([-math.pi + 0.01, 4.5])) == (
        pytest.approx([-0.02, 0.5])
    )
    G = motion_jacobian(np.array([0.0, 0.0, math.pi / 2]), 2.0)
    np.testing.assert_allclose(G, [[1.0, 0.0, -2.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(noise_jacobian(np.array([0.0, 0.0, math.pi / 2]))[:2, :2],
                               [[0.0, -1.0], [1.0, 0.0]], atol=1e-15)  # fmt: skip
    assert motion(np.array([0.0, 0.0, 3.0]), 1.0, 0.5)[2] == pytest.approx(3.5 - 2 * math.pi)


@given(
    st.floats(-20.0, 20.0), st.floats(-20.0, 20.0), st.floats(-math.pi, math.pi),
    st.floats(-math.pi, math.pi), st.floats(0.5, 30.0),
)  # fmt: skip
@settings(max_examples=100)
def test_the_jacobians_are_the_derivatives_of_their_operations(
    x: float, y: float, theta: float, bearing: float, rng: float
) -> None:
    pose = np.array([x, y, theta])
    z = np.array([bearing, rng])
    landmark = landmark_from_measurement(pose, z)
    offset = landmark_offset(pose, landmark)

    def h_of_pose(p: FloatArray) -> FloatArray:
        return expected_measurement(landmark_offset(p, landmark), float(p[2]))

    def h_of_landmark(m: FloatArray) -> FloatArray:
        return expected_measurement(landmark_offset(pose, m), theta)

    atol = 1e-6 * max(1.0, 1.0 / rng)
    H_p = numerical_jacobian(h_of_pose, pose, (0,))
    np.testing.assert_allclose(measurement_jacobian_pose(offset), H_p, atol=atol)
    H_l = numerical_jacobian(h_of_landmark, landmark, (0,))
    np.testing.assert_allclose(measurement_jacobian_landmark(offset), H_l, atol=atol)
    np.testing.assert_allclose(
        init_jacobian_pose(pose, z),
        numerical_jacobian(lambda p: landmark_from_measurement(p, z), pose), atol=1e-5,
    )  # fmt: skip
    np.testing.assert_allclose(
        init_jacobian_measurement(pose, z),
        numerical_jacobian(lambda m: landmark_from_measurement(pose, m), z), atol=1e-5,
    )  # fmt: skip


@pytest.mark.parametrize("seed", range(5))
def test_the_factored_update_is_the_textbook_one(seed: int) -> None:
    """whitened_correction (the filter's form) against K = P H^T S^-1, x + K nu and
    P - K S K^T, for one landmark (2 rows) and a joint line (6 rows)."""
    rng = np.random.default_rng(seed)
    n = 11
    P = _spd(rng, n)
    x = rng.normal(size=n)
    for k in (2, 6):
        H = rng.normal(size=(k, n))
        R = np.diag(rng.uniform(0.01, 0.1, k))
        nu = rng.normal(size=k)
        S = innovation_covariance(H, P, R)
        K = kalman_gain(P @ H.T, S)
        factored = whitened_correction(H @ P, S, nu)
        assert factored is not None
        A, change, nis = factored
        np.testing.assert_allclose(change, K @ nu, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(A.T @ A, K @ S @ K.T, rtol=1e-10, atol=1e-12)
        assert nis == pytest.approx(float(nu @ np.linalg.solve(S, nu)), rel=1e-10)
        corrected = corrected_covariance(P, K, S)
        assert np.array_equal(corrected, corrected.T)
        np.testing.assert_allclose(corrected, (np.eye(n) - K @ H) @ P, rtol=1e-9, atol=1e-12)
        mean = corrected_mean(x, K, nu)
        assert mean[2] == pytest.approx(wrap_angle(float(x[2] + (K @ nu)[2])))
    # an S that is not positive definite has no factor
    assert whitened_correction(np.ones((2, n)), -np.eye(2), np.zeros(2)) is None
    assert whitened_correction(np.ones((2, n)), np.full((2, 2), np.nan), np.zeros(2)) is None


def test_the_covariances_of_a_predict_and_a_new_landmark() -> None:
    rng = np.random.default_rng(1)
    P = _spd(rng, 7)
    pose = np.array([1.0, -2.0, 0.7])
    G, W = motion_jacobian(pose, 1.5), noise_jacobian(pose)
    Q = motion_noise(0.25, 0.1, 0.1)
    np.testing.assert_allclose(Q, np.diag([0.0625, 0.01, 0.01]), rtol=1e-15)
    np.testing.assert_allclose(measurement_noise(0.01, 0.08), np.diag([1e-4, 0.0064]), rtol=1e-15)
    np.testing.assert_allclose(prior_covariance((0.02, 0.02, 0.1)), np.diag([4e-4, 4e-4, 0.01]),
                               rtol=1e-15)  # fmt: skip
    P_rr = predicted_pose_covariance(P[:3, :3], G, W, Q)
    F = np.eye(7)
    F[:3, :3] = G
    dense = F @ P @ F.T
    dense[:3, :3] += W @ Q @ W.T
    np.testing.assert_allclose(P_rr, dense[:3, :3], rtol=1e-12)
    assert np.array_equal(P_rr, P_rr.T)
    np.testing.assert_allclose(predicted_cross_covariance(G, P[:3, 3:]), dense[:3, 3:], rtol=1e-12)
    z = np.array([0.4, 6.0])
    J_p, J_z = init_jacobian_pose(pose, z), init_jacobian_measurement(pose, z)
    R = measurement_noise(0.01, 0.08)
    P_ll = new_landmark_covariance(J_p, P[:3, :3], J_z, R)
    np.testing.assert_allclose(P_ll, J_p @ P[:3, :3] @ J_p.T + J_z @ R @ J_z.T, rtol=1e-12)
    assert np.array_equal(P_ll, P_ll.T)
    np.testing.assert_allclose(new_landmark_cross_covariance(J_p, P[:3]), J_p @ P[:3])
