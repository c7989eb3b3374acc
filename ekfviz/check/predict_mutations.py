"""The mutations of a predict's operations, written one by one (see
:mod:`ekfviz.check.operators`): the control, the motion, G, W, Q and the covariances."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from ekfviz.check.operators import (
    DEG,
    Mutation,
    declared,
    in_context,
    operands,
    own_motion_noise,
    reflected,
    result,
    turned,
    with_heading,
    written,
)


def predict_mutations() -> Iterator[Mutation]:
    yield from _control_and_motion()
    yield from _jacobians_and_noise()
    yield from _covariance_mutations()


def _control_and_motion() -> Iterator[Mutation]:
    """The control's and the motion model's."""
    yield written(
        "control",
        "swapped",
        "swapped",
        "the control is read as (alpha, d) where it is"
        " (d, alpha): the robot drives alpha and turns d",
        operands(lambda d, alpha: (alpha, d)),
        fix="d, alpha = control[0], control[1] (the distance first, then the turn)",
        tokens=("control",),
    )
    yield written(
        "control",
        "degrees",
        "degrees",
        "the turn alpha is taken for degrees and"
        " converted (alpha pi / 180): it is in radians already",
        operands(lambda d, alpha: (d, alpha * DEG)),
        fix="use alpha as it is (radians)",
        tokens=("deg2rad", "radians", "180"),
    )
    yield written(
        "motion",
        "turn_first",
        "stale",
        "the robot turns before it drives: x' = x + d"
        " cos(theta + alpha), y' = y + d sin(theta + alpha)",
        in_context(lambda rr, f, pose, d, alpha: f(pose + np.array((0.0, 0.0, alpha)), d, 0.0)),
        fix="drive d along the old heading, then turn alpha: x' = x + d cos(theta)",
    )
    yield written(
        "motion",
        "cos_sin_swapped",
        "swapped",
        "the motion model has cos and sin swapped: x' = x + d sin(theta), y' = y + d cos(theta)",
        in_context(
            lambda rr, f, pose, d, alpha: with_heading(
                f(turned(pose, math.pi / 2), d, 0.0), pose[2] + alpha
            )
        ),
        tokens=("sin", "cos"),
    )
    yield written(
        "motion",
        "sign_x",
        "sign",
        "the motion model subtracts its x term: x' = x - d cos(theta)",
        in_context(lambda rr, f, pose, d, alpha: reflected(f(pose, d, alpha), pose, 0)),
        tokens=("cos",),
    )
    yield written(
        "motion",
        "sign_y",
        "sign",
        "the motion model subtracts its y term: y' = y - d sin(theta)",
        in_context(lambda rr, f, pose, d, alpha: reflected(f(pose, d, alpha), pose, 1)),
        tokens=("sin",),
    )
    yield written(
        "motion",
        "turn_missing",
        "missing",
        "the motion model does not turn: theta' = theta",
        in_context(
            lambda rr, f, pose, d, alpha: with_heading(f(pose, d, alpha), pose[2], wrap=False)
        ),
    )
    yield written("motion", "heading_not_wrapped", "wrap", "the predicted heading theta + alpha is"
             " not wrapped to (-pi, pi]", in_context(lambda rr, f, pose, d, alpha:
             with_heading(f(pose, d, alpha), pose[2] + alpha, wrap=False)),
             fix="theta' = wrap(theta + alpha)")  # fmt: skip
    yield written(
        "motion",
        "heading_wrapped_0_2pi",
        "wrap",
        "the predicted heading is wrapped to"
        " [0, 2 pi) ((theta + alpha) % (2 pi)), not to (-pi, pi]",
        in_context(
            lambda rr, f, pose, d, alpha: with_heading(
                f(pose, d, alpha), (pose[2] + alpha) % (2 * math.pi), wrap=False
            )
        ),
        fix="theta' = (theta + alpha + pi) % (2 pi) - pi",
        tokens=("%",),
    )
    yield written(
        "motion",
        "skipped",
        "skipped",
        "the pose is not moved by the control",
        in_context(lambda rr, f, pose, d, alpha: np.array(pose, dtype=np.float64)),
    )


def _jacobians_and_noise() -> Iterator[Mutation]:
    """G's, W's (and the pose they are evaluated at) and Q's."""
    yield written(
        "linearisation_pose",
        "after_motion",
        "stale",
        "G and W are evaluated at the"
        " pose after the motion (the heading theta + alpha), not before it",
        in_context(lambda rr, f, pose: rr.moved),
        fix="compute G and W from the heading before the predict (before X is moved)",
    )
    yield written(
        "motion_jacobian",
        "after_motion",
        "stale",
        "G is evaluated at the heading after the turn, theta + alpha",
        in_context(lambda rr, f, pose, d: f(rr.moved, d)),
        fix="G at the heading before the predict",
    )
    yield written(
        "motion_jacobian",
        "missing_factor_d",
        "missing",
        "G's heading column lacks the factor d: [-sin(theta), cos(theta), 1]",
        operands(lambda pose, d: (pose, 1.0)),
    )
    yield written(
        "noise_jacobian",
        "missing",
        "missing",
        "the motion noise Q (robot frame: along,"
        " sideways, turn) is added as it is, not rotated into the world frame by W",
        result(lambda value: np.eye(3)),
        fix="add W Q W^T, W the rotation by the heading",
    )
    yield written(
        "noise_jacobian",
        "transposed",
        "transpose",
        "W rotates by -theta: the rotation is transposed",
        result(lambda value: value.T),
        fix="W = [[cos(theta), -sin(theta), 0], [sin(theta), cos(theta), 0], [0, 0, 1]]",
    )
    yield written(
        "noise_jacobian",
        "cos_sin_swapped",
        "swapped",
        "W has cos and sin swapped",
        operands(lambda pose: (turned(pose, math.pi / 2),)),
        tokens=("sin", "cos"),
    )
    yield written(
        "noise_jacobian",
        "after_motion",
        "stale",
        "W is evaluated at the heading after the turn, theta + alpha",
        in_context(lambda rr, f, pose: f(rr.moved)),
        fix="W at the heading before the predict",
    )
    yield from motion_noise_mutations()


def _covariance_mutations() -> Iterator[Mutation]:
    """The predicted covariances'."""
    yield written(
        "pose_covariance",
        "transposed",
        "transpose",
        "the pose covariance is propagated with G transposed: G^T P_rr G + W Q W^T",
        operands(lambda P, G, W, Q: (P, G.T, W, Q)),
        tokens=("G.T @ P",),
    )
    yield written(
        "pose_covariance",
        "elementwise",
        "product",
        "the pose covariance multiplies"
        " elementwise (*) where matrix products (@) belong: G * P * G^T + W * Q * W^T",
        operands(lambda P, G, W, Q: (G * P * G.T, np.eye(3), W * Q * W.T, np.eye(3))),
        tokens=("*",),
    )
    yield written(
        "pose_covariance",
        "noise_subtracted",
        "sign",
        "the motion noise is subtracted: G P_rr G^T - W Q W^T",
        operands(lambda P, G, W, Q: (P, G, W, -Q)),
        tokens=("-",),
    )
    yield written(
        "pose_covariance",
        "jacobian_missing",
        "missing",
        "the pose covariance is not propagated through G: P_rr' = P_rr + W Q W^T",
        operands(lambda P, G, W, Q: (P, np.eye(3), W, Q)),
    )
    yield written(
        "cross_covariance",
        "skipped",
        "skipped",
        "a predict changes only the pose block"
        " of P: the pose-landmark cross-covariances are not multiplied by G",
        in_context(lambda rr, f, G, P_rm: P_rm),
        fix="P_rm' = G P_rm for every landmark"
        " (only the robot's rows and columns change, but all of them)",
    )
    yield written(
        "cross_covariance",
        "transposed",
        "transpose",
        "the pose-landmark cross-covariances are multiplied by G transposed: G^T P_rm",
        operands(lambda G, P_rm: (G.T, P_rm)),
    )
    yield written(
        "cross_covariance",
        "zeroed",
        "missing",
        "a predict sets the pose-landmark cross-covariances to zero",
        in_context(lambda rr, f, G, P_rm: 0.0 * P_rm),
    )


def motion_noise_mutations() -> Iterator[Mutation]:
    yield written(
        "motion_noise",
        "sigmas",
        "variance",
        "Q is built from the sigmas, not their squares: Q = diag(sigma_x, sigma_y, sigma_alpha)",
        result(np.sqrt),
        fix="Q = diag(sigma_x^2, sigma_y^2, sigma_alpha^2): a covariance holds variances",
        tokens=("sqrt", "sigma"),
    )
    yield written(
        "motion_noise",
        "squared",
        "variance",
        "Q holds the variances squared: diag(sigma^4) (control_cov ** 2, a variance squared again)",
        result(np.square),
        fix="Q = diag(sigma^2): control_cov holds the variances already",
        tokens=("**",),
    )
    yield written(
        "motion_noise",
        "missing",
        "missing",
        "no motion noise is added: P' = G P G^T",
        result(lambda value: 0.0 * value),
        fix="P' = G P G^T + W Q W^T",
    )
    yield written(
        "motion_noise",
        "missing_when_still",
        "missing",
        "no motion noise is added"
        " when the robot stands still (d = alpha = 0): the predict returns early",
        in_context(lambda rr, f, Q: 0.0 * Q if rr.control == (0.0, 0.0) else Q),
        fix="add W Q W^T at every predict, whatever the control",
        when="still",
    )
    yield written(
        "motion_noise",
        "missing_when_not_driving",
        "missing",
        "no motion noise is added when the robot does not drive (d = 0)",
        in_context(lambda rr, f, Q: 0.0 * Q if rr.control[0] == 0.0 else Q),
        fix="add W Q W^T at every predict, whatever the control",
        when="not_driving",
    )
    yield written(
        "motion_noise",
        "declared",
        "own",
        "the filter adds the motion noise it declares as its own (motion_noise), not the run's",
        in_context(lambda rr, f, Q: declared(rr.noise.declared_motion, Q)),
        fix="use the run's Q (--sigma-x, --sigma-y, --sigma-alpha, or the log's header),"
        " or declare the same noise",
    )
    yield written(
        "motion_noise",
        "own",
        "own",
        "the filter adds a motion noise of its own, not the run's --sigma-x/-y/-alpha",
        in_context(own_motion_noise),
        fix="give ekfviz the filter's sigmas (--sigma-x, --sigma-y, --sigma-alpha) or use"
        " the run's Q",
    )
