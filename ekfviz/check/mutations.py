"""The catalogue of mutations: the operators of :mod:`ekfviz.check.operators` applied to
every operation of :mod:`ekfviz.check.operations`.

A :class:`Mutation` is what a mistaken line of code computes in place of one operation:
a sign flipped (of a term, a row, a column), a transpose, an elementwise product where a
matrix product belongs (``S**-1`` for an inverse), a term or factor missing, arguments or
components swapped, degrees for radians, an index off by one, a stale operand, sigmas
where variances belong, a wrong wrap range or none, the whole operation skipped; and the
few that read a quantity off the filter's own result (its own Q, a constant covariance
of a new landmark). The matrix operations' sign, missing-term, transpose and swap
mutations are generated from their formulas (:data:`MATRICES`); the rest are written per
operation. A cause's id is ``operation.mutation``; its sentence says what the code does
and its fix the operation's equation.

Short names of causes (``transposed_motion_jacobian``) are accepted too: :data:`ALIASES`
maps each to its (operation, mutation).
"""

from __future__ import annotations

from ekfviz.check.operators import (
    FAMILIES,
    MatrixFormula,
    Mutation,
    NoiseUse,
    angle_swapped,
    heading_swapped,
    matrix_mutations,
    scaled_noise,
)
from ekfviz.check.predict_mutations import predict_mutations
from ekfviz.check.update_mutations import init_mutations, update_mutations

__all__ = [
    "ALIASES",
    "FAMILIES",
    "INERT",
    "MATRICES",
    "MUTATION",
    "MUTATIONS",
    "NOISE_USES",
    "Mutation",
    "resolve",
]  # fmt: skip

MATRICES: tuple[MatrixFormula, ...] = (
    MatrixFormula("motion_jacobian", ("x", "y", "theta"), ("x", "y", "theta"),
                  (("1", "0", "-d sin(theta)"), ("0", "1", "d cos(theta)"), ("0", "0", "1")),
                  heading_swapped),
    MatrixFormula("measurement_jacobian_pose", ("bearing", "range"), ("x", "y", "theta"),
                  (("dy/q", "-dx/q", "-1"), ("-dx/r", "-dy/r", "0"))),
    MatrixFormula("measurement_jacobian_landmark", ("bearing", "range"), ("lx", "ly"),
                  (("-dy/q", "dx/q"), ("dx/r", "dy/r"))),
    MatrixFormula("init_jacobian_pose", ("lx", "ly"), ("x", "y", "theta"),
                  (("1", "0", "-r sin(theta + beta)"), ("0", "1", "r cos(theta + beta)")),
                  angle_swapped),
    MatrixFormula("init_jacobian_measurement", ("lx", "ly"), ("bearing", "range"),
                  (("-r sin(theta + beta)", "cos(theta + beta)"),
                   ("r cos(theta + beta)", "sin(theta + beta)")), angle_swapped),
)  # fmt: skip


# every operation that takes a noise matrix (or makes one): each has a mutation of its noise
# scaled by a factor k that the search reads off the filter's result. (Joseph's form of the
# corrected covariance takes R too; a filter that writes it so and scales R there scales it
# in S as well, which is the measurement noise's mutation.)
NOISE_USES: tuple[NoiseUse, ...] = (
    NoiseUse("motion_noise", None, "Q", "the predicted covariance",
             "P_rr' = G P_rr G^T + W (k Q) W^T"),
    NoiseUse("pose_covariance", 3, "Q", "the predicted pose covariance",
             "P_rr' = G P_rr G^T + k W Q W^T"),
    NoiseUse("measurement_noise", None, "R", "S and in a new landmark's covariance",
             "S = H P H^T + k R, P_ll = J_p P_rr J_p^T + J_z (k R) J_z^T"),
    NoiseUse("innovation_covariance", 2, "R", "S", "S = H P H^T + k R"),
    NoiseUse("landmark_covariance", 3, "R", "a new landmark's covariance",
             "P_ll = J_p P_rr J_p^T + k J_z R J_z^T"),
)  # fmt: skip


# -- the catalogue ---------------------------------------------------------------------------


def _catalogue() -> tuple[Mutation, ...]:
    mutations: list[Mutation] = []
    mutations += predict_mutations()
    for formula in MATRICES[:1]:
        mutations += matrix_mutations(formula)
    mutations += update_mutations()
    for formula in MATRICES[1:3]:
        mutations += matrix_mutations(formula)
    mutations += init_mutations()
    for formula in MATRICES[3:]:
        mutations += matrix_mutations(formula)
    mutations += [scaled_noise(use) for use in NOISE_USES]
    return tuple(mutations)


MUTATIONS: tuple[Mutation, ...] = _catalogue()
MUTATION: dict[str, Mutation] = {mutation.id: mutation for mutation in MUTATIONS}

# the mutations that change no event at all alone (check compares the heading modulo 2 pi,
# and R's diagonal hides a sign of a column of J_z): the search leaves them out, as they
# can only round differently; a test checks this against the probes
# (ekfviz.check.probes.is_inert)
INERT = frozenset({
    "corrected_mean.heading_not_wrapped", "expected_measurement.not_wrapped",
    "init_jacobian_measurement.sign_column_bearing",
    "init_jacobian_measurement.sign_column_range", "motion.heading_not_wrapped",
    "motion.heading_wrapped_0_2pi",
})  # fmt: skip

# every id ``check`` named causes by before its operations were named, and its mutation
ALIASES: dict[str, str] = {
    "independent_landmark_init": "landmark_cross_covariance.skipped",
    "landmark_cov_missing_pose_term": "landmark_covariance.pose_term_missing",
    "landmark_cov_missing_measurement_term": "landmark_covariance.noise_term_missing",
    "fixed_landmark_init_covariance": "landmark_covariance.constant",
    "landmark_init_in_line_order": "update_loop.init_in_line_order",
    "update_at_initialisation": "update_loop.update_at_init",
    "joint_update": "update_loop.joint",
    "unwrapped_innovation": "innovation.not_wrapped",
    "missing_measurement_noise": "innovation_covariance.noise_missing",
    "arctan_bearing": "expected_measurement.arctan",
    "bearing_not_relative_to_heading": "expected_measurement.heading_missing",
    "atan2_arguments_swapped": "expected_measurement.atan2_swapped",
    "predicted_measurement_swapped": "expected_measurement.swapped",
    "innovation_wrapped_to_0_2pi": "innovation.wrapped_0_2pi",
    "measurement_jacobian_rows_swapped": "measurement_jacobian.rows_swapped",
    "measurement_jacobian_bearing_sign": "measurement_jacobian.bearing_sign",
    "only_first_landmark": "update_loop.only_first",
    "linearised_once": "update_loop.stale_linearisation",
    "measurement_noise_not_squared": "measurement_noise.sigmas",
    "measurement_noise_twice": "innovation_covariance.noise_twice",
    "joseph_without_measurement_noise": "corrected_covariance.joseph_without_noise",
    "init_range_bearing_swapped": "init_measurement.swapped",
    "init_cos_sin_swapped": "landmark_position.cos_sin_swapped",
    "transposed_motion_jacobian": "motion_jacobian.transposed",
    "wrong_jacobian_sign": "motion_jacobian.sign_column_theta",
    "identity_motion_jacobian": "motion_jacobian.missing_column_theta",
    "jacobian_after_motion": "linearisation_pose.after_motion",
    "predict_pose_block_only": "cross_covariance.skipped",
    "turn_before_drive": "motion.turn_first",
    "unrotated_motion_noise": "noise_jacobian.missing",
    "missing_motion_noise": "motion_noise.missing",
    "swapped_control": "control.swapped",
    "motion_noise_not_squared": "motion_noise.sigmas",
    "different_motion_noise": "motion_noise.own",
}


def resolve(cause: str) -> str:
    """A cause's id as ``check`` names it now (an alias, or the id itself)."""
    return ALIASES.get(cause, cause)
