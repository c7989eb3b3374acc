"""The mutations of an update's operations and a new landmark's, written one by one (see
:mod:`ekfviz.check.operators`): the measurement, the loop over a line, h(x), H, the
innovation, R, S, K, the corrections, and the initialisation."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from ekfviz.check.operations import OPERATION
from ekfviz.check.operators import (
    DEG,
    Mutation,
    angle_swapped,
    bearing_sign,
    blocked,
    constant_landmark_covariance,
    declared,
    in_context,
    joseph,
    norm,
    operands,
    result,
    same_size,
    with_bearing,
    written,
)
from ekfviz.models.angles import wrap_angle


def update_mutations() -> Iterator[Mutation]:
    yield from _reading_and_loop()
    yield from _offset_and_prediction()
    yield from _jacobian_mutations()
    yield from _correction_chain()


def _reading_and_loop() -> Iterator[Mutation]:
    """The measurements' reading's and the loop over a line's."""
    readings = (("measurement", "the measurements"),
                ("init_measurement", "a new landmark's first measurement"))  # fmt: skip
    for operation, what in readings:
        yield written(
            operation,
            "swapped",
            "swapped",
            f"{what} are read as (range, bearing) where a log gives (bearing, range)",
            result(lambda pairs: pairs[:, ::-1]),
            fix="beta, r = measure[2 i], measure[2 i + 1] (bearing first)",
        )
        yield written(
            operation,
            "blocked",
            "index",
            f"{what} are read as [b1..bk, r1..rk] (all the"
            " bearings, then all the ranges) where a line interleaves them as [b1, r1, b2,"
            " r2, ...]",
            operands(lambda flat: (blocked(flat),)),
            fix="beta, r = measure[2 i], measure[2 i + 1]",
        )
        yield written(
            operation,
            "degrees",
            "degrees",
            f"{what}' bearings are taken for degrees and"
            " converted (beta pi / 180): they are in radians already",
            result(lambda pairs: pairs * (DEG, 1.0)),
            fix="use the bearings as they are (radians)",
            tokens=("deg2rad", "radians", "180"),
        )
    yield from loop_mutations()


def _offset_and_prediction() -> Iterator[Mutation]:
    """The landmark's offset's and h(x)'s."""
    yield written(
        "landmark_offset",
        "sign",
        "sign",
        "(dx, dy) is taken as the robot minus the landmark",
        result(lambda value: -value),
        tokens=("dx", "dy"),
    )
    yield written(
        "landmark_offset",
        "swapped",
        "swapped",
        "(dx, dy) is taken in the order (dy, dx)",
        result(lambda value: value[::-1]),
        tokens=("dx", "dy"),
    )
    yield written(
        "landmark_offset",
        "sign_dx",
        "sign",
        "dx is taken as the robot minus the landmark (dy the right way round)",
        result(lambda value: value * (-1.0, 1.0)),
        tokens=("dx",),
    )
    yield written(
        "landmark_offset",
        "sign_dy",
        "sign",
        "dy is taken as the robot minus the landmark (dx the right way round)",
        result(lambda value: value * (1.0, -1.0)),
        tokens=("dy",),
    )
    yield written(
        "landmark_offset",
        "index_before",
        "index",
        "the landmark is read one entry early in X (X[2 + 2 i], X[3 + 2 i])",
        operands(lambda x, j: (x, j - 1)),
        fix="lx, ly = X[3 + 2 i], X[4 + 2 i]",
    )
    yield written(
        "landmark_offset",
        "index_after",
        "index",
        "the landmark is read one entry late in X (X[4 + 2 i], X[5 + 2 i])",
        operands(lambda x, j: (x, j + 1)),
        fix="lx, ly = X[3 + 2 i], X[4 + 2 i]",
    )
    yield from expected_measurement_mutations()


def _jacobian_mutations() -> Iterator[Mutation]:
    """H's (beside the generated ones of its blocks)."""
    yield written(
        "measurement_jacobian",
        "rows_swapped",
        "transpose",
        "H's rows are in the order"
        " (range, bearing) (as in Probabilistic Robotics) where the measurement and the"
        " innovation are (bearing, range)",
        result(lambda H: H[::-1]),
        fix="H's first row is the bearing's: [dy/q, -dx/q, -1, -dy/q, dx/q], then the"
        " range's: [-dx/r, -dy/r, 0, dx/r, dy/r]",
    )
    yield written(
        "measurement_jacobian",
        "bearing_sign",
        "sign",
        "the bearing row of H has the"
        " signs of its position derivatives flipped: [-dy/q, dx/q, -1, dy/q, -dx/q]"
        " (d atan2(dy, dx) taken the wrong way round)",
        in_context(lambda rr, f, H_p, H_l, j, n: bearing_sign(f(H_p, H_l, j, n), j)),
        fix="H's bearing row = [dy/q, -dx/q, -1, -dy/q, dx/q] with dx, dy the landmark"
        " minus the robot",
    )
    yield written(
        "measurement_jacobian",
        "columns_after",
        "index",
        "H_l is placed one column late in H (at 4 + 2 i)",
        operands(lambda H_p, H_l, j, n: (H_p, H_l, j + 1, n)),
        fix="H[:, 3 + 2 i : 5 + 2 i] = H_l",
    )
    yield written(
        "measurement_jacobian",
        "columns_before",
        "index",
        "H_l is placed one column early in H (at 2 + 2 i)",
        operands(lambda H_p, H_l, j, n: (H_p, H_l, j - 1, n)),
        fix="H[:, 3 + 2 i : 5 + 2 i] = H_l",
    )
    for operation in ("measurement_jacobian_pose", "measurement_jacobian_landmark"):
        block = OPERATION[operation].title
        yield written(
            operation,
            "range_row_over_q",
            "missing",
            f"{block}'s range row divides by q where it divides by r = sqrt(q) (dx/q, dy/q)",
            in_context(lambda rr, f, offset: f(offset) * ((1.0,), (1.0 / norm(offset),))),
        )
        yield written(
            operation,
            "bearing_row_over_r",
            "missing",
            f"{block}'s bearing row divides by r = sqrt(q) where it divides by q (dy/r, dx/r)",
            in_context(lambda rr, f, offset: f(offset) * ((norm(offset),), (1.0,))),
        )


def _correction_chain() -> Iterator[Mutation]:
    """The innovation's, R's, S's, K's and the corrections'."""
    yield from innovation_and_noise_mutations()
    yield from correction_mutations()


def loop_mutations() -> Iterator[Mutation]:
    yield written(
        "update_loop",
        "only_first",
        "skipped",
        "only the first landmark of a line is"
        " folded in (e.g. a return inside the loop over the landmarks)",
        result(lambda known: list(known)[:1]),
        fix="fold in every landmark of the line; return after the loop",
        tokens=("return",),
    )
    yield written(
        "update_loop",
        "one_short",
        "index",
        "the loop over the landmarks stops one"
        " short: the last landmark of a line is never folded in",
        result(lambda known: list(known)[:-1]),
        fix="for i in range(k)",
        tokens=("range(",),
    )
    yield written(
        "update_loop",
        "skips_first",
        "index",
        "the loop over the landmarks starts at"
        " the second: the first landmark of a line is never folded in",
        result(lambda known: list(known)[1:]),
        fix="for i in range(k)",
        tokens=("range(",),
    )
    yield written(
        "update_loop",
        "stale_linearisation",
        "stale",
        "landmarks are folded in one after"
        " another, but h(x) and H are computed at the state before the line (X_pre)"
        " for all of them, not at the state the previous ones corrected",
        result(list),
        fix="inside the loop, compute dx, dy, h(x) and H from the current X",
        tokens=("X_pre", "mu_bar", "x_pre"),
    )
    yield written(
        "update_loop",
        "init_in_line_order",
        "stale",
        "a new landmark is initialised"
        " where it comes in the line, from the pose before the known landmarks after it"
        " corrected it",
        result(list),
        fix="fold in the known landmarks first, then"
        " initialise the new ones (or say so: the reference does known first)",
    )
    yield written(
        "update_loop",
        "update_at_init",
        "stale",
        "a new landmark, once initialised from"
        " a measurement, is updated with that same measurement (the measurement counted"
        " twice)",
        result(list),
        fix="initialise a new landmark from its measurement and"
        " do not fold that measurement in again",
    )
    yield written(
        "update_loop",
        "stale_covariance",
        "stale",
        "S and K are made from P as it was before the line (P_pre) for every landmark,"
        " not from the P the previous landmarks corrected",
        result(list),
        fix="inside the loop, S = H P H^T + R and K = P H^T S^-1 with the current P",
        tokens=("P_pre",),
    )
    yield Mutation(
        "update_loop",
        "joint",
        "form",
        "all landmarks of a line are folded in at"
        " once (one stacked H, S, K), where the reference folds them in one after"
        " another",
        "not a bug in itself: check with --update joint, or update one"
        " landmark at a time, re-linearising in between",
        result(list),
    )
    yield Mutation(
        "update_loop",
        "sequential",
        "form",
        "the landmarks of a line are folded"
        " in one after another, where the reference (--update joint) folds them in"
        " at once",
        "not a bug in itself: check with --update sequential",
        result(list),
    )


def expected_measurement_mutations() -> Iterator[Mutation]:
    operation = "expected_measurement"
    yield written(
        operation,
        "atan2_swapped",
        "swapped",
        "h(x)'s bearing uses arctan2(dx, dy), the"
        " arguments the other way round (arctan2 takes y first)",
        operands(lambda offset, theta: (offset[::-1], theta)),
        fix="h(x)'s bearing = wrap(arctan2(dy, dx) - theta): dy first",
        tokens=("arctan2(",),
    )
    yield written(
        operation,
        "arctan",
        "wrap",
        "h(x)'s bearing uses arctan(dy / dx), whose range"
        " (-pi/2, pi/2) cannot tell a landmark behind the robot from one ahead of it",
        in_context(
            lambda rr, f, offset, theta: with_bearing(
                f(offset, theta), wrap_angle(math.atan(offset[1] / offset[0]) - theta)
            )
        ),
        fix="h(x)'s bearing = wrap(arctan2(dy, dx) - theta)",
        tokens=("arctan(",),
    )
    yield written(
        operation,
        "heading_missing",
        "missing",
        "h(x)'s bearing is arctan2(dy, dx), the"
        " landmark's direction in the world, without subtracting the heading theta",
        operands(lambda offset, theta: (offset, 0.0)),
        fix="h(x)'s bearing = wrap(arctan2(dy, dx) - theta)",
        tokens=("arctan2(",),
    )
    yield written(
        operation,
        "heading_added",
        "sign",
        "h(x)'s bearing adds the heading: arctan2(dy, dx) + theta",
        operands(lambda offset, theta: (offset, -theta)),
        fix="h(x)'s bearing = wrap(arctan2(dy, dx) - theta)",
        tokens=("arctan2(",),
    )
    yield written(
        operation,
        "swapped",
        "swapped",
        "h(x) is built as (range, bearing) while the"
        " measurement z is (bearing, range): the innovation subtracts a range from a"
        " bearing and a bearing from a range",
        result(lambda value: value[::-1]),
        fix="h(x) = (bearing, range), in the order of z",
    )
    yield written(
        operation,
        "range_squared",
        "missing",
        "h(x)'s range is q = dx^2 + dy^2, the square root missing",
        result(lambda value: value * (1.0, value[1])),
        fix="h(x)'s range = sqrt(dx^2 + dy^2)",
        tokens=("**", "sqrt"),
    )
    yield written(
        operation,
        "not_wrapped",
        "wrap",
        "h(x)'s bearing arctan2(dy, dx) - theta is not wrapped",
        in_context(
            lambda rr, f, offset, theta: with_bearing(
                f(offset, theta), math.atan2(offset[1], offset[0]) - theta
            )
        ),
        fix="h(x)'s bearing = wrap(arctan2(dy, dx) - theta)",
    )
    yield written(
        operation,
        "degrees",
        "degrees",
        "h(x)'s bearing is in degrees (np.degrees) where the measurement's is in radians",
        result(lambda value: value * (1.0 / DEG, 1.0)),
        fix="h(x)'s bearing in radians",
        tokens=("degrees", "rad2deg", "180"),
    )


def innovation_and_noise_mutations() -> Iterator[Mutation]:
    yield from _innovation_mutations()
    yield from _noise_mutations()


def _innovation_mutations() -> Iterator[Mutation]:
    """The innovation's."""
    yield written(
        "innovation",
        "sign",
        "sign",
        "the innovation has the wrong sign: h(x) - z where"
        " it is z - h(x) (or the update subtracts K nu)",
        result(lambda value: -value),
        fix="nu = z - h(x), x' = x + K nu",
    )
    yield written(
        "innovation",
        "not_wrapped",
        "wrap",
        "the bearing innovation z - h(x) is not wrapped to (-pi, pi]",
        in_context(lambda rr, f, z, h: np.asarray(z) - h),
        fix="wrap the bearing component of z - h(x) (after the subtraction) before using it",
    )
    yield written(
        "innovation",
        "wrapped_0_2pi",
        "wrap",
        "the bearing innovation is wrapped into"
        " [0, 2 pi) (angle % (2 pi)), not into (-pi, pi]: a slightly negative innovation"
        " becomes almost 2 pi",
        in_context(
            lambda rr, f, z, h: with_bearing(
                np.asarray(z) - h, (float(z[0]) - float(h[0])) % (2 * math.pi)
            )
        ),
        fix="warp2pi(a) = (a + pi) % (2 pi) - pi",
        tokens=("%",),
    )
    yield written(
        "innovation",
        "swapped",
        "swapped",
        "the innovation's components are in the order (range, bearing)",
        result(lambda value: value[::-1]),
    )


def _noise_mutations() -> Iterator[Mutation]:
    """R's and S's."""
    yield written(
        "measurement_noise",
        "sigmas",
        "variance",
        "R is built from the sigmas, not their"
        " squares: R = diag(sigma_bearing, sigma_range), in S and in a new landmark's"
        " covariance",
        result(np.sqrt),
        fix="R = diag(sigma_bearing^2, sigma_range^2): a covariance holds variances",
        tokens=("sqrt", "sigma"),
    )
    yield written(
        "measurement_noise",
        "squared",
        "variance",
        "R holds the variances squared (measure_cov ** 2)",
        result(np.square),
        fix="R = diag(sigma^2): measure_cov holds the variances already",
        tokens=("**",),
    )
    yield written(
        "measurement_noise",
        "declared",
        "own",
        "the filter uses the measurement noise it"
        " declares as its own (measurement_noise), not the run's",
        in_context(lambda rr, f, R: declared(rr.noise.declared_measurement, R)),
        fix="use the run's R (--sigma-bearing, --sigma-range, or the log's header), or"
        " declare the same noise",
    )
    yield written(
        "innovation_covariance",
        "noise_missing",
        "missing",
        "R is missing from the innovation covariance: S = H P H^T",
        operands(lambda H, P, R: (H, P, 0.0 * R)),
        fix="S = H P H^T + R",
    )
    yield written(
        "innovation_covariance",
        "noise_twice",
        "missing",
        "R is added twice to the innovation covariance: S = H P H^T + 2 R",
        operands(lambda H, P, R: (H, P, 2.0 * R)),
        fix="S = H P H^T + R",
    )
    yield written(
        "innovation_covariance",
        "noise_sigmas",
        "variance",
        "S adds the measurement"
        " sigmas, not their squares: S = H P H^T + diag(sigma_bearing, sigma_range)",
        operands(lambda H, P, R: (H, P, np.sqrt(R))),
        fix="S = H P H^T + R, R = diag(sigma^2)",
        tokens=("sqrt",),
    )
    yield written(
        "innovation_covariance",
        "stale_P",
        "stale",
        "S is made from P as it was before"
        " the line (P_pre), not the P the previous landmarks corrected",
        in_context(lambda rr, f, H, P, R: f(H, same_size(rr.P_line, P), R)),
        fix="S = H P H^T + R with the current P",
        tokens=("P_pre",),
    )


def correction_mutations() -> Iterator[Mutation]:
    yield written(
        "kalman_gain",
        "inverse_elementwise",
        "product",
        "K inverts S elementwise (S**-1, 1 / S) where it needs the matrix inverse",
        in_context(lambda rr, f, P, H, S: (P @ H.T) @ (1.0 / S)),
        fix="K = P H^T S^-1: np.linalg.inv(S), or np.linalg.solve(S, H @ P).T",
        tokens=("**", "1 /", "1/"),
    )
    yield written(
        "kalman_gain",
        "inverse_missing",
        "missing",
        "K lacks S^-1: K = P H^T",
        in_context(lambda rr, f, P, H, S: P @ H.T),
        tokens=("K =",),
    )
    yield written(
        "kalman_gain",
        "stale_P",
        "stale",
        "K is made from P as it was before the line"
        " (P_pre), not the P the previous landmarks corrected",
        in_context(lambda rr, f, P, H, S: f(same_size(rr.P_line, P), H, S)),
        fix="K = P H^T S^-1 with the current P",
        tokens=("P_pre",),
    )
    yield written(
        "corrected_mean",
        "sign",
        "sign",
        "the mean update subtracts the correction: x - K nu",
        operands(lambda x, K, nu: (x, K, -np.asarray(nu))),
        fix="x' = x + K nu",
    )
    yield written(
        "corrected_mean",
        "skipped",
        "skipped",
        "the mean is not corrected (x + K nu never stored)",
        in_context(lambda rr, f, x, K, nu: np.array(x)),
    )
    yield written(
        "corrected_mean",
        "heading_not_wrapped",
        "wrap",
        "the corrected heading is not wrapped to (-pi, pi]",
        in_context(lambda rr, f, x, K, nu: x + K @ nu),
        fix="wrap the heading after x + K nu",
    )
    yield written(
        "corrected_covariance",
        "skipped",
        "skipped",
        "the covariance is not corrected: P is never reduced by an update",
        in_context(lambda rr, f, P, K, S, H, R: P),
        fix="P = (I - K H) P",
    )
    yield written(
        "corrected_covariance",
        "elementwise",
        "product",
        "the covariance update"
        " multiplies elementwise: (I - K H) * P where it is the matrix product",
        in_context(lambda rr, f, P, K, S, H, R: (np.eye(len(P)) - K @ H) * P),
        fix="P = (I - K H) @ P",
        tokens=("*",),
    )
    yield written("corrected_covariance", "sign", "sign", "the covariance update adds what it"
             " should subtract: P + K S K^T", in_context(lambda rr, f, P, K, S, H, R:
             P + K @ S @ K.T), fix="P = P - K S K^T = (I - K H) P")  # fmt: skip
    yield written(
        "corrected_covariance",
        "joseph_without_noise",
        "missing",
        "Joseph's form without its noise term: P = (I - K H) P (I - K H)^T",
        in_context(lambda rr, f, P, K, S, H, R: joseph(P, K, H)),
        fix="P = (I - K H) P (I - K H)^T + K R K^T, or simply P = (I - K H) P",
    )


def init_mutations() -> Iterator[Mutation]:
    yield from _init_position_mutations()
    yield from _init_covariance_mutations()


def _init_position_mutations() -> Iterator[Mutation]:
    """The first measurement's, the pose's and the position's."""
    yield written(
        "init_measurement",
        "bearing_negated",
        "sign",
        "a new landmark's direction is theta - beta (the bearing's sign flipped), in its"
        " position and its Jacobians",
        result(lambda pairs: pairs * (-1.0, 1.0)),
        fix="phi = theta + beta",
        tokens=("phi",),
    )
    yield written(
        "init_pose",
        "heading_missing",
        "missing",
        "a new landmark's direction is beta alone, in its position and its Jacobians: the"
        " heading theta is not added",
        operands(lambda pose: (np.array([pose[0], pose[1], 0.0]),)),
        fix="phi = theta + beta",
        tokens=("phi",),
    )
    yield written(
        "init_pose",
        "before_line",
        "stale",
        "a new landmark is placed from the pose"
        " before the line's known landmarks corrected it (the predicted pose)",
        in_context(lambda rr, f, pose: rr.x_line[:3].copy()),
        fix="initialise new landmarks from the corrected pose, after the known ones",
    )
    yield written(
        "landmark_position",
        "cos_sin_swapped",
        "swapped",
        "a new landmark's position"
        " uses sin for x and cos for y: l = pose + r (sin(theta + beta), cos(theta +"
        " beta))",
        operands(angle_swapped),
        tokens=("sin", "cos"),
    )
    yield written(
        "landmark_position",
        "bearing_subtracted",
        "sign",
        "a new landmark's direction is theta - beta, not theta + beta",
        operands(lambda pose, z: (pose, np.array([-z[0], z[1]]))),
        tokens=("-",),
    )
    yield written(
        "landmark_position",
        "heading_missing",
        "missing",
        "a new landmark's direction is beta alone: the heading theta is not added",
        operands(lambda pose, z: (np.array([pose[0], pose[1], 0.0]), z)),
    )


def _init_covariance_mutations() -> Iterator[Mutation]:
    """P_ll's and P_lx's."""
    yield written(
        "landmark_covariance",
        "pose_term_missing",
        "missing",
        "a new landmark's covariance comes from the measurement noise alone: P_ll = J_z R J_z^T",
        operands(lambda J_p, P, J_z, R: (J_p, 0.0 * P, J_z, R)),
    )
    yield written(
        "landmark_covariance",
        "noise_term_missing",
        "missing",
        "a new landmark's covariance lacks the measurement noise: P_ll = J_p P_rr J_p^T",
        operands(lambda J_p, P, J_z, R: (J_p, P, J_z, 0.0 * R)),
    )
    yield written(
        "landmark_covariance",
        "noise_sigmas",
        "variance",
        "a new landmark's covariance"
        " adds the measurement sigmas, not their squares: J_z diag(sigma) J_z^T",
        operands(lambda J_p, P, J_z, R: (J_p, P, J_z, np.sqrt(R))),
        tokens=("sqrt",),
    )
    yield written(
        "landmark_covariance",
        "constant",
        "own",
        "a new landmark starts with a constant"
        " covariance (np.eye(2) times a number, a fixed diagonal), whatever its range and"
        " the pose's uncertainty",
        in_context(constant_landmark_covariance),
        fix="P_ll = J_p P_rr J_p^T + J_z R J_z^T (with P_lx = J_p P_r)",
        tokens=("eye",),
    )
    yield Mutation(
        "landmark_cross_covariance",
        "skipped",
        "handout",
        "the handout's"
        " simplification: a new landmark gets no cross-covariance with the pose"
        " nor the map, as P = block_diag(pose_cov, landmark_cov) of per-landmark"
        " blocks does",
        "P_lx = J_p P_r: the new rows are J_p times the pose rows of"
        " P (init_cross_covariance in a course module)",
        in_context(lambda rr, f, J_p, P_r: np.zeros((2, P_r.shape[1]))),
        ("block_diag", "zeros"),
    )
    yield Mutation(
        "landmark_cross_covariance",
        "pose_part_skipped",
        "handout",
        "the"
        " handout's simplification: the new landmarks get no cross-covariance with"
        " the pose (P = block_diag(pose_cov, landmark_cov)), only among themselves",
        "P_lx = J_p P_r: the new rows are J_p times the pose rows of P"
        " (init_cross_covariance in a course module)",
        result(lambda value: value),
        ("block_diag", "zeros"),
    )
