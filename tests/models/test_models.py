"""Analytic Jacobians against central finite differences, and angle wrapping."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from jacobians import numerical_jacobian

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle, wrap_angles
from ekfviz.models.classic import (
    landmark_from_measurement,
    landmark_init_jacobians,
    measure,
    measurement_jacobians,
    motion,
    motion_jacobians,
)

coordinate = st.floats(-50.0, 50.0)
heading = st.floats(-3 * math.pi, 3 * math.pi)


@given(coordinate, coordinate, heading, st.floats(-5.0, 5.0), st.floats(-3.0, 3.0))
def test_motion_jacobians_match_finite_differences(
    x: float, y: float, theta: float, d: float, alpha: float
) -> None:
    pose = np.array([x, y, theta])
    G, W = motion_jacobians(pose, d)
    np.testing.assert_allclose(
        G, numerical_jacobian(lambda p: motion(p, d, alpha), pose, (2,)), atol=1e-6
    )

    def noisy(e: FloatArray) -> FloatArray:
        # the reference's noise model: e_x along the heading, e_y sideways, e_a on the turn
        c, s = math.cos(theta), math.sin(theta)
        return np.array(
            [x + (d + e[0]) * c - e[1] * s, y + (d + e[0]) * s + e[1] * c, theta + alpha + e[2]]
        )

    np.testing.assert_allclose(W, numerical_jacobian(noisy, np.zeros(3), (2,)), atol=1e-6)


@given(coordinate, coordinate, heading, coordinate, coordinate)
@settings(max_examples=300)
def test_measurement_jacobians_match_finite_differences(
    x: float, y: float, theta: float, lx: float, ly: float
) -> None:
    pose, landmark = np.array([x, y, theta]), np.array([lx, ly])
    if math.hypot(lx - x, ly - y) < 0.5:
        return  # the Jacobian is undefined at the landmark and stiff near it
    z_D_pose, z_D_landmark = measurement_jacobians(pose, landmark)
    np.testing.assert_allclose(
        z_D_pose,
        numerical_jacobian(lambda p: measure(p, landmark), pose, (0,)),
        rtol=1e-5,
        atol=1e-6,
    )
    np.testing.assert_allclose(
        z_D_landmark,
        numerical_jacobian(lambda m: measure(pose, m), landmark, (0,)),
        rtol=1e-5,
        atol=1e-6,
    )


@given(coordinate, coordinate, heading, st.floats(-math.pi, math.pi), st.floats(0.1, 40.0))
def test_landmark_init_jacobians_match_finite_differences(
    x: float, y: float, theta: float, bearing: float, rng: float
) -> None:
    pose, z = np.array([x, y, theta]), np.array([bearing, rng])
    l_D_pose, l_D_z = landmark_init_jacobians(pose, z)
    np.testing.assert_allclose(
        l_D_pose,
        numerical_jacobian(lambda p: landmark_from_measurement(p, z), pose),
        rtol=1e-5,
        atol=1e-5,
    )
    np.testing.assert_allclose(
        l_D_z,
        numerical_jacobian(lambda m: landmark_from_measurement(pose, m), z),
        rtol=1e-5,
        atol=1e-5,
    )


@given(coordinate, coordinate, heading, st.floats(-math.pi, math.pi), st.floats(0.1, 40.0))
def test_inverse_measurement_inverts_measurement(
    x: float, y: float, theta: float, bearing: float, rng: float
) -> None:
    pose = np.array([x, y, theta])
    z = measure(pose, landmark_from_measurement(pose, np.array([bearing, rng])))
    assert abs(wrap_angle(z[0] - bearing)) < 1e-9
    assert z[1] == np.float64(z[1]) and abs(z[1] - rng) < 1e-9


@given(st.floats(-1e4, 1e4))
def test_wrap_angle_lands_in_half_open_interval(angle: float) -> None:
    wrapped = wrap_angle(angle)
    assert -math.pi < wrapped <= math.pi
    assert abs(math.remainder(wrapped - angle, 2 * math.pi)) < 1e-9
    assert (
        wrap_angles(np.array([angle]))[0] == np.float64(wrapped)
        or abs(wrap_angles(np.array([angle]))[0] - wrapped) < 1e-9
    )


def test_wrap_angle_maps_minus_pi_to_pi() -> None:
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(3 * math.pi) == math.pi
    assert wrap_angles(np.array([-math.pi]))[0] == math.pi


def test_measurement_bearing_wraps_across_pi() -> None:
    # a landmark just behind the robot on either side: bearings near +pi and -pi
    pose = np.array([0.0, 0.0, 0.0])
    above, below = measure(pose, np.array([-5.0, 1e-3])), measure(pose, np.array([-5.0, -1e-3]))
    assert above[0] > 3.14 and below[0] < -3.14
