"""The operations of an EKF-SLAM event as ``check`` names them: what each computes, its
equation, and the names students' code computes it under.

Each operation is one call of :class:`~ekfviz.check.rerun.Rerun` (the reference re-run
of an event, over the named operations of :mod:`ekfviz.models`); a mistake is an
operation with a mutation (:mod:`ekfviz.check.mutations`). The symbols are those of the
project's reference (`docs/ekf-slam.md`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Operation:
    """One operation of an event.

    :param id: stable, the first half of a cause's id
    :param title: what it is, as a sentence names it ("the motion Jacobian G")
    :param event: ``predict``, ``update`` or ``init`` (a new landmark's initialisation)
    :param equation: what it computes, in the reference's symbols
    :param names: the names a student's code computes it under, to quote its line
    :param function: the course module's function it belongs to
    :param units: of its value, for the numbers of a divergence nothing explains
    """

    id: str
    title: str
    event: str
    equation: str
    names: tuple[str, ...]
    function: str
    units: str = ""


OPERATIONS: tuple[Operation, ...] = (
    # -- predict
    Operation("control", "the control", "predict", "(d, alpha) = (control[0], control[1]):"
              " the distance first, then the turn", ("d", "alpha", "control", "u"), "predict"),
    Operation("motion", "the motion model", "predict", "x' = x + d cos(theta),"
              " y' = y + d sin(theta), theta' = wrap(theta + alpha) (drive, then turn)",
              ("X_pre", "X", "x", "pose", "mu", "mu_bar"), "predict", "m, m, rad"),
    Operation("linearisation_pose", "the pose G and W are evaluated at", "predict",
              "G and W at the pose before the predict", ("theta",), "predict", "rad"),
    Operation("motion_jacobian", "the motion Jacobian G", "predict",
              "G = [[1, 0, -d sin(theta)], [0, 1, d cos(theta)], [0, 0, 1]]",
              ("G", "G_t", "Gt", "G_x", "Gx", "F", "Fx", "G_r", "jacobian"), "predict"),
    Operation("noise_jacobian", "the noise Jacobian W (the robot frame's rotation)", "predict",
              "W = [[cos(theta), -sin(theta), 0], [sin(theta), cos(theta), 0], [0, 0, 1]]",
              ("W", "V", "R_theta", "rot", "rotation", "L"), "predict"),
    Operation("motion_noise", "the motion noise Q", "predict",
              "Q = diag(sigma_x^2, sigma_y^2, sigma_alpha^2), variances in the robot frame",
              ("Q", "control_cov", "M", "R_t", "noise"), "predict", "m^2, m^2, rad^2"),
    Operation("pose_covariance", "the predicted pose covariance", "predict",
              "P_rr' = G P_rr G^T + W Q W^T", ("P_pre", "P", "P_bar", "Sigma", "sigma"),
              "predict", "m^2, rad^2"),
    Operation("cross_covariance", "the predicted pose-landmark cross-covariance", "predict",
              "P_rm' = G P_rm (only the robot's rows and columns of P change, all of them)",
              ("P_pre", "P", "P_bar", "Sigma"), "predict", "m^2, m rad"),
    # -- update
    Operation("measurement", "the measurement z", "update",
              "z_i = (measure[2 i], measure[2 i + 1]) = (bearing, range): pairs, bearing"
              " first", ("measure", "z", "meas", "beta", "r"), "update", "rad, m"),
    Operation("update_loop", "the loop over a line's landmarks", "update",
              "for every landmark of the line in turn: h(x), H, S, K and the correction from"
              " the current X and P", ("for", "range"), "update"),
    Operation("landmark_offset", "the landmark's offset (dx, dy)", "update",
              "(dx, dy) = (lx - x, ly - y): the landmark minus the robot",
              ("dx", "dy", "delta", "d", "diff", "lx", "ly"), "update", "m"),
    Operation("expected_measurement", "the expected measurement h(x)", "update",
              "h(x) = (wrap(atan2(dy, dx) - theta), sqrt(q)), bearing first",
              ("z_hat", "zhat", "z_pred", "h", "hx", "h_x", "predicted", "expected", "z_est"),
              "update", "rad, m"),
    Operation("measurement_jacobian", "the measurement Jacobian H", "update",
              "H = [[dy/q, -dx/q, -1, -dy/q, dx/q], [-dx/r, -dy/r, 0, dx/r, dy/r]] over"
              " the pose's columns and the landmark's (3 + 2 j, 4 + 2 j), r = sqrt(q)",
              ("H", "H_t", "Ht", "H_low", "H_i", "Hi", "H_small"), "update"),
    Operation("measurement_jacobian_pose", "H's pose block H_p", "update",
              "H_p = [[dy/q, -dx/q, -1], [-dx/r, -dy/r, 0]]", ("H", "H_p", "Hp", "H_pose"),
              "update"),
    Operation("measurement_jacobian_landmark", "H's landmark block H_l", "update",
              "H_l = [[-dy/q, dx/q], [dx/r, dy/r]]", ("H", "H_l", "Hl", "H_lm", "H_landmark"),
              "update"),
    Operation("innovation", "the innovation", "update",
              "nu = z - h(x), its bearing wrapped to (-pi, pi] after the subtraction",
              ("nu", "innovation", "y", "v", "residual", "diff", "z_diff", "delta_z"),
              "update", "rad, m"),
    Operation("measurement_noise", "the measurement noise R", "update",
              "R = diag(sigma_bearing^2, sigma_range^2), variances",
              ("R", "measure_cov", "Q", "Q_t", "noise"), "update", "rad^2, m^2"),
    Operation("innovation_covariance", "the innovation covariance S", "update",
              "S = H P H^T + R", ("S", "Z", "S_t", "Psi"), "update", "rad^2, m^2"),
    Operation("kalman_gain", "the Kalman gain K", "update", "K = P H^T S^-1",
              ("K", "K_t", "Kt", "gain"), "update"),
    Operation("corrected_mean", "the corrected mean", "update",
              "x' = x + K nu, its heading wrapped", ("X", "x", "mu", "X_new"), "update",
              "m, rad"),
    Operation("corrected_covariance", "the corrected covariance", "update",
              "P' = (I - K H) P = P - K S K^T (or Joseph's (I - K H) P (I - K H)^T + K R K^T)",
              ("P", "Sigma", "P_new"), "update", "m^2, rad^2"),
    # -- a new landmark's initialisation
    Operation("init_measurement", "the first measurement of a landmark", "init",
              "(beta, r) = (measure[2 i], measure[2 i + 1]): bearing first",
              ("init_measure", "beta", "r", "measure", "z"), "init_landmarks", "rad, m"),
    Operation("init_pose", "the pose a new landmark is placed from", "init",
              "the pose after the line's known landmarks corrected it",
              ("init_pose", "pose", "X"), "init_landmarks", "m, m, rad"),
    Operation("landmark_position", "a new landmark's position", "init",
              "l = (x + r cos(theta + beta), y + r sin(theta + beta))",
              ("landmark", "lm", "l", "lx", "ly", "landmarks"), "init_landmarks", "m"),
    Operation("init_jacobian_pose", "a new landmark's Jacobian J_p (by the pose)", "init",
              "J_p = [[1, 0, -r sin(theta + beta)], [0, 1, r cos(theta + beta)]]",
              ("J_p", "Jp", "L_p", "Lp", "G_p", "H_p", "J_pose", "J_x", "Jx"),
              "init_landmarks"),
    Operation("init_jacobian_measurement", "a new landmark's Jacobian J_z (by the measurement)",
              "init", "J_z = [[-r sin(theta + beta), cos(theta + beta)], [r cos(theta + beta),"
              " sin(theta + beta)]]", ("J_z", "Jz", "L_z", "Lz", "G_z", "H_z", "J_m", "Jm"),
              "init_landmarks"),
    Operation("landmark_covariance", "a new landmark's covariance P_ll", "init",
              "P_ll = J_p P_rr J_p^T + J_z R J_z^T", ("landmark_cov", "P_ll", "Pll", "cov",
              "block", "P_l"), "init_landmarks", "m^2"),
    Operation("landmark_cross_covariance", "a new landmark's cross-covariance P_lx", "init",
              "P_lx = J_p P_r: the new rows of P are J_p times the pose rows of P (the pose"
              " and every landmark already mapped)", ("P", "P_lx", "cross", "landmark_cov"),
              "init_landmarks", "m^2, m rad"),
)  # fmt: skip

OPERATION: dict[str, Operation] = {operation.id: operation for operation in OPERATIONS}
