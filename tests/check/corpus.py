"""A corpus of course modules to measure ``check``'s diagnosis on: mutants of two correct
modules, each with one mistake as students write it, and correct modules written in
unusual ways.

The two correct modules: the course skeleton (``examples/course_skeleton/ekf_slam.py``:
floats in loops, ``solve``, P - K S K^T, the cross-covariances of ``init_cross_covariance``)
and a real solution as students hand it in (``students.source("correct")``: the handout's
block-diagonal P, ``inv(S)``, (I - K H) P). A mutant is one of them with the edits of
one mistake (:data:`MISTAKES`: the cause ``check`` must name, the (old, new) replacements
in each style); ``check`` must name that cause alone (beside the handout's own
simplification of the real solution) on the battery of course logs (the classic sample
and the edge log). A correct module of :data:`CORRECT` must get no cause but the
handout's, no unknown divergence and no error.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import students

ROOT = Path(__file__).resolve().parents[2]
SKELETON_TEXT = (ROOT / "examples" / "course_skeleton" / "ekf_slam.py").read_text()
SOLUTION_TEXT = students.source("correct")
STYLES = {"skeleton": SKELETON_TEXT, "solution": SOLUTION_TEXT}
# the handout's own simplification of the real solution's initialisation
HANDOUT = "landmark_cross_covariance.skipped"

Edits = tuple[tuple[str, str], ...]


@dataclass(frozen=True, slots=True)
class Mistake:
    """One mistake: the cause check must name, and its edits in each style it has."""

    cause: str
    edits: dict[str, Edits] = field(default_factory=dict)


def _both(*edits: tuple[str, str]) -> dict[str, Edits]:
    return {"skeleton": edits, "solution": edits}


_G = "G[0, 2] = -d * np.sin(theta)\n    G[1, 2] = d * np.cos(theta)"
_S_SKELETON = "S = H @ P @ H.T + measure_cov"
_NU_SKELETON = "innovation = measure[2 * i : 2 * i + 2, 0] - [np.arctan2(dy, dx) - X[2, 0], r]"
_HP_SKELETON = "H[:, :3] = [[dy / q, -dx / q, -1], [-dx / r, -dy / r, 0]]"
_HL_SKELETON = "H[:, j : j + 2] = [[-dy / q, dx / q], [dx / r, dy / r]]"
_HP_SOLUTION = "H[:, :3] = [[dy / q, -dx / q, -1], [-dx / sq, -dy / sq, 0]]"
_HL_SOLUTION = "H[:, 3 + 2 * i : 5 + 2 * i] = [[-dy / q, dx / q], [dx / sq, dy / sq]]"
_ZHAT = "z_hat = np.array([[warp2pi(np.arctan2(dy, dx) - X[2, 0])], [sq]])"
_JP_SKELETON = "np.array([[1, 0, -rng * np.sin(phi)], [0, 1, rng * np.cos(phi)]])"
_JP_SOLUTION = "J_p = np.array([[1, 0, -r * np.sin(phi)], [0, 1, r * np.cos(phi)]])"
_JZ_SKELETON = "np.array([[-rng * np.sin(phi), np.cos(phi)], [rng * np.cos(phi), np.sin(phi)]])"
_JZ_SOLUTION = "J_z = np.array([[-r * np.sin(phi), np.cos(phi)], [r * np.cos(phi), np.sin(phi)]])"
_PLL_SKELETON = "block = block + J_z @ init_measure_cov @ J_z.T"
_RETURN_SKELETON = "        P = 0.5 * (P + P.T)\n    return X, P"
_RETURN_SOLUTION = "        P = (np.eye(n) - K @ H) @ P\n    return X, P"
_NU_SOLUTION = "nu = measure[2 * i : 2 * i + 2] - z_hat"


def _edited(name: str) -> dict[str, Edits]:
    """The real solution's edits of a student of :data:`students.EDITS`."""
    return {"solution": students.EDITS[name]}


MISTAKES: dict[str, Mistake] = {
    # -- predict
    "g_transposed": Mistake("motion_jacobian.transposed", {
        "skeleton": (("P = G @ P @ G.T", "P = G.T @ P @ G"),),
        "solution": (("P_pre = G @ P @ G.T + Q", "P_pre = G.T @ P @ G + Q"),)}),
    "g_heading_sign": Mistake("motion_jacobian.sign_column_theta", _both(
        (_G, "G[0, 2] = d * np.sin(theta)\n    G[1, 2] = -d * np.cos(theta)"))),
    "g_one_sign": Mistake("motion_jacobian.sign_y_theta", _both(
        ("G[1, 2] = d * np.cos(theta)", "G[1, 2] = -d * np.cos(theta)"))),
    "g_cos_sin": Mistake("motion_jacobian.cos_sin_swapped", _both(
        (_G, "G[0, 2] = -d * np.cos(theta)\n    G[1, 2] = d * np.sin(theta)"))),
    "g_identity": Mistake("motion_jacobian.missing_column_theta", _both(("    " + _G + "\n", ""))),
    "q_unrotated": Mistake("noise_jacobian.missing", {
        "skeleton": (("P[:3, :3] += W @ control_cov @ W.T", "P[:3, :3] += control_cov"),),
        "solution": (("Q[:3, :3] = rot @ control_cov @ rot.T", "Q[:3, :3] = control_cov"),)}),
    "w_transposed": Mistake("noise_jacobian.transposed", {
        "skeleton": (("W @ control_cov @ W.T", "W.T @ control_cov @ W"),),
        "solution": (("rot @ control_cov @ rot.T", "rot.T @ control_cov @ rot"),)}),
    "q_sigmas": Mistake("motion_noise.sigmas", {
        "skeleton": (("W @ control_cov @ W.T", "W @ np.sqrt(control_cov) @ W.T"),),
        **_edited("q_sigmas")}),
    "q_missing": Mistake("motion_noise.missing", {
        "skeleton": (("    P[:3, :3] += W @ control_cov @ W.T", "    pass  #"),),
        "solution": (("Q[:3, :3] = rot @ control_cov @ rot.T", "Q[:3, :3] = 0 * control_cov"),)}),
    "still_no_noise": Mistake("motion_noise.missing_when_still", _both(
        ("d, alpha = control[0, 0], control[1, 0]\n",
         "d, alpha = control[0, 0], control[1, 0]\n    if d == 0 and alpha == 0:\n"
         "        return X, P\n"))),
    "control_swapped": Mistake("control.swapped", _both(
        ("d, alpha = control[0, 0], control[1, 0]", "alpha, d = control[0, 0], control[1, 0]"))),
    "alpha_degrees": Mistake("control.degrees", {
        "skeleton": (("warp2pi(theta + alpha)", "warp2pi(theta + np.deg2rad(alpha))"),),
        **_edited("degrees")}),
    "turn_first": Mistake("motion.turn_first", {
        "skeleton": (("X[0, 0] += d * np.cos(theta)\n    X[1, 0] += d * np.sin(theta)",
                      "X[0, 0] += d * np.cos(theta + alpha)\n"
                      "    X[1, 0] += d * np.sin(theta + alpha)"),),
        "solution": (("X_pre[0, 0] += d * np.cos(theta)\n    X_pre[1, 0] += d * np.sin(theta)",
                      "X_pre[0, 0] += d * np.cos(theta + alpha)\n"
                      "    X_pre[1, 0] += d * np.sin(theta + alpha)"),)}),
    "jacobians_after_motion": Mistake("linearisation_pose.after_motion", {
        "skeleton": ((_G, _G.replace("theta", "X[2, 0]")),
                     ("W = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta),"
                      " np.cos(theta), 0], [0, 0, 1]])",
                      "W = np.array([[np.cos(X[2, 0]), -np.sin(X[2, 0]), 0], [np.sin(X[2, 0]),"
                      " np.cos(X[2, 0]), 0], [0, 0, 1]])")),
        "solution": ((_G, _G.replace("theta", "X_pre[2, 0]")),
                     ("[[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0],"
                      " [0, 0, 1]]",
                      "[[np.cos(X_pre[2, 0]), -np.sin(X_pre[2, 0]), 0], [np.sin(X_pre[2, 0]),"
                      " np.cos(X_pre[2, 0]), 0], [0, 0, 1]]"))}),
    "pose_block_only": Mistake("cross_covariance.skipped", {
        "skeleton": (("P = G @ P @ G.T", "P[:3, :3] = G[:3, :3] @ P[:3, :3] @ G[:3, :3].T"),),
        "solution": (("P_pre = G @ P @ G.T + Q",
                      "P_pre = P.copy()\n    P_pre[:3, :3] = G[:3, :3] @ P[:3, :3] @ G[:3, :3].T"
                      "\n    P_pre = P_pre + Q"),)}),
    "motion_cos_sin": Mistake("motion.cos_sin_swapped", {
        "skeleton": (("X[0, 0] += d * np.cos(theta)\n    X[1, 0] += d * np.sin(theta)",
                      "X[0, 0] += d * np.sin(theta)\n    X[1, 0] += d * np.cos(theta)"),),
        "solution": (("X_pre[0, 0] += d * np.cos(theta)\n    X_pre[1, 0] += d * np.sin(theta)",
                      "X_pre[0, 0] += d * np.sin(theta)\n    X_pre[1, 0] += d * np.cos(theta)"),)}),
    # -- update
    "no_r": Mistake("innovation_covariance.noise_missing", {
        "skeleton": ((_S_SKELETON, "S = H @ P @ H.T"),),
        "solution": (("S = H @ P @ H.T + measure_cov", "S = H @ P @ H.T"),)}),
    "r_twice": Mistake("innovation_covariance.noise_twice", {
        "skeleton": ((_S_SKELETON, "S = H @ P @ H.T + 2 * measure_cov"),),
        **_edited("r_twice")}),
    "r_sigmas": Mistake("measurement_noise.sigmas", {
        "skeleton": ((_S_SKELETON, "S = H @ P @ H.T + np.sqrt(measure_cov)"),
                     ("J_z @ init_measure_cov @ J_z.T", "J_z @ np.sqrt(init_measure_cov) @ J_z.T")),
        **_edited("r_sigmas")}),
    "innovation_sign": Mistake("innovation.sign", {
        "skeleton": ((_NU_SKELETON,
                      "innovation = np.array([np.arctan2(dy, dx) - X[2, 0], r])"
                      " - measure[2 * i : 2 * i + 2, 0]"),),
        "solution": ((_NU_SOLUTION, "nu = z_hat - measure[2 * i : 2 * i + 2]"),)}),
    # (the skeleton never wraps h(x) either: a form of its own, not a mistake)
    "unwrapped": Mistake("innovation.not_wrapped", {
        "skeleton": (("innovation[0] = warp2pi(innovation[0])", "pass"),),
        "solution": (("nu[0, 0] = warp2pi(nu[0, 0])", "pass"),)}),
    "wrapped_0_2pi": Mistake("innovation.wrapped_0_2pi", {
        "skeleton": (("innovation[0] = warp2pi(innovation[0])",
                      "innovation[0] = innovation[0] % (2 * np.pi)"),),
        "solution": (("nu[0, 0] = warp2pi(nu[0, 0])", "nu[0, 0] = nu[0, 0] % (2 * np.pi)"),)}),
    "arctan": Mistake("expected_measurement.arctan", {
        "skeleton": (("np.arctan2(dy, dx) - X[2, 0]", "np.arctan(dy / dx) - X[2, 0]"),),
        **_edited("arctan")}),
    "atan2_swapped": Mistake("expected_measurement.atan2_swapped", {
        "skeleton": (("np.arctan2(dy, dx)", "np.arctan2(dx, dy)"),), **_edited("atan2_swapped")}),
    "bearing_world": Mistake("expected_measurement.heading_missing", {
        "skeleton": (("np.arctan2(dy, dx) - X[2, 0]", "np.arctan2(dy, dx)"),),
        **_edited("bearing_world")}),
    "z_hat_swapped": Mistake("expected_measurement.swapped", {
        "skeleton": (("[np.arctan2(dy, dx) - X[2, 0], r]", "[r, np.arctan2(dy, dx) - X[2, 0]]"),),
        **_edited("z_hat_swapped")}),
    "range_squared": Mistake("expected_measurement.range_squared", {
        "skeleton": (("[np.arctan2(dy, dx) - X[2, 0], r]", "[np.arctan2(dy, dx) - X[2, 0], q]"),),
        "solution": ((_ZHAT, _ZHAT.replace("[sq]]", "[q]]")),)}),
    "h_rows_swapped": Mistake("measurement_jacobian.rows_swapped", {
        "skeleton": ((_HP_SKELETON, "H[:, :3] = [[-dx / r, -dy / r, 0], [dy / q, -dx / q, -1]]"),
                     (_HL_SKELETON, "H[:, j : j + 2] = [[dx / r, dy / r], [-dy / q, dx / q]]")),
        **_edited("h_rows_swapped")}),
    "h_bearing_sign": Mistake("measurement_jacobian.bearing_sign", {
        "skeleton": ((_HP_SKELETON, "H[:, :3] = [[-dy / q, dx / q, -1], [-dx / r, -dy / r, 0]]"),
                     (_HL_SKELETON, "H[:, j : j + 2] = [[dy / q, -dx / q], [dx / r, dy / r]]")),
        **_edited("h_bearing_sign")}),
    "hl_transposed": Mistake("measurement_jacobian_landmark.transposed", {
        "skeleton": ((_HL_SKELETON, "H[:, j : j + 2] = [[-dy / q, dx / r], [dx / q, dy / r]]"),),
        "solution": ((_HL_SOLUTION,
                      "H[:, 3 + 2 * i : 5 + 2 * i] = [[-dy / q, dx / sq], [dx / q, dy / sq]]"),)}),
    "hl_range_over_q": Mistake("measurement_jacobian_landmark.range_row_over_q", {
        "skeleton": ((_HL_SKELETON, "H[:, j : j + 2] = [[-dy / q, dx / q], [dx / q, dy / q]]"),),
        "solution": ((_HL_SOLUTION,
                      "H[:, 3 + 2 * i : 5 + 2 * i] = [[-dy / q, dx / q], [dx / q, dy / q]]"),)}),
    "dx_reversed": Mistake("landmark_offset.sign", {
        "skeleton": (("dx, dy = X[j, 0] - X[0, 0], X[j + 1, 0] - X[1, 0]",
                      "dx, dy = X[0, 0] - X[j, 0], X[1, 0] - X[j + 1, 0]"),),
        "solution": (("dx, dy = lx - X[0, 0], ly - X[1, 0]",
                      "dx, dy = X[0, 0] - lx, X[1, 0] - ly"),)}),
    "stale_linearisation": Mistake("update_loop.stale_linearisation", {
        "skeleton": (("dx, dy = X[j, 0] - X[0, 0], X[j + 1, 0] - X[1, 0]",
                      "dx, dy = X_pre[j, 0] - X_pre[0, 0], X_pre[j + 1, 0] - X_pre[1, 0]"),
                     ("np.arctan2(dy, dx) - X[2, 0]", "np.arctan2(dy, dx) - X_pre[2, 0]")),
        **_edited("stale_linearisation")}),
    "stale_covariance": Mistake("update_loop.stale_covariance", {
        "skeleton": ((_S_SKELETON + "\n        K = np.linalg.solve(S, H @ P).T",
                      "S = H @ P_pre @ H.T + measure_cov\n"
                      "        K = np.linalg.solve(S, H @ P_pre).T"),)}),
    "only_first": Mistake("update_loop.only_first", {
        "skeleton": ((_RETURN_SKELETON,
                      _RETURN_SKELETON.replace("\n    return", "\n        return")),),
        **_edited("return_in_loop")}),
    "one_short": Mistake("update_loop.one_short", {
        "skeleton": (("    for i in range(k):\n        j = 3 + 2 * i",
                      "    for i in range(k - 1):\n        j = 3 + 2 * i"),),
        "solution": (("    for i in range(k):\n        lx, ly",
                      "    for i in range(k - 1):\n        lx, ly"),)}),
    "s_inverse_elementwise": Mistake("kalman_gain.inverse_elementwise", {
        "skeleton": (("K = np.linalg.solve(S, H @ P).T", "K = P @ H.T @ S**-1"),),
        "solution": (("K = P @ H.T @ np.linalg.inv(S)", "K = P @ H.T @ S**-1"),)}),
    "p_not_reduced": Mistake("corrected_covariance.skipped", {
        "skeleton": (("P = P - K @ S @ K.T", "P = P"),),
        "solution": (("P = (np.eye(n) - K @ H) @ P", "P = P"),)}),
    "p_elementwise": Mistake("corrected_covariance.elementwise", {
        "skeleton": (("P = P - K @ S @ K.T", "P = (np.eye(n) - K @ H) * P"),),
        "solution": (("P = (np.eye(n) - K @ H) @ P", "P = (np.eye(n) - K @ H) * P"),)}),
    "joseph_no_krk": Mistake("corrected_covariance.joseph_without_noise", {
        "skeleton": (("P = P - K @ S @ K.T",
                      "P = (np.eye(n) - K @ H) @ P @ (np.eye(n) - K @ H).T"),),
        **_edited("joseph_no_krk")}),
    "blocked_measurements": Mistake("measurement.blocked", {
        "skeleton": (("measure[2 * i : 2 * i + 2, 0] - [",
                      "np.array([measure[i, 0], measure[k + i, 0]]) - ["),),
        "solution": ((_NU_SOLUTION,
                      "nu = np.array([[measure[i, 0]], [measure[k + i, 0]]]) - z_hat"),)}),
    "bearing_degrees": Mistake("measurement.degrees", {
        "skeleton": (("measure[2 * i : 2 * i + 2, 0] - [",
                      "measure[2 * i : 2 * i + 2, 0] * [np.pi / 180, 1] - ["),),
        "solution": ((_NU_SOLUTION,
                      "nu = measure[2 * i : 2 * i + 2] * [[np.pi / 180], [1]] - z_hat"),)}),
    # -- initialisation
    "pll_no_pose_term": Mistake("landmark_covariance.pose_term_missing", {
        "skeleton": ((_PLL_SKELETON, "block = J_z @ init_measure_cov @ J_z.T"),),
        "solution": ((students.CORRECT_INIT, "J_z @ init_measure_cov @ J_z.T"),)}),
    "pll_no_noise_term": Mistake("landmark_covariance.noise_term_missing", {
        "skeleton": ((_PLL_SKELETON, "block = block"),),
        "solution": ((students.CORRECT_INIT, "J_p @ init_pose_cov @ J_p.T"),)}),
    "pll_constant": Mistake("landmark_covariance.constant", {
        "skeleton": ((_PLL_SKELETON, "block = 0.5 * np.eye(2)"),),
        "solution": ((students.CORRECT_INIT, "0.5 * np.eye(2)"),)}),
    "init_range_bearing": Mistake("init_measurement.swapped", {
        "skeleton": (("bearing, rng = init_measure[2 * i : 2 * i + 2, 0]",
                      "rng, bearing = init_measure[2 * i : 2 * i + 2, 0]"),),
        **_edited("range_bearing_init")}),
    "init_cos_sin": Mistake("landmark_position.cos_sin_swapped", {
        "skeleton": (("[x + rng * np.cos(phi), y + rng * np.sin(phi)]",
                      "[x + rng * np.sin(phi), y + rng * np.cos(phi)]"),),
        **_edited("cos_sin_init")}),
    # (the skeleton's phi = theta + bearing, the solution's phi = theta + beta)
    "init_bearing_negated": Mistake("init_measurement.bearing_negated", _both(
        ("phi = theta + b", "phi = theta - b"))),
    "init_no_heading": Mistake("init_pose.heading_missing", _both(
        ("phi = theta + b", "phi = b"))),
    "jp_sign": Mistake("init_jacobian_pose.sign_column_theta", {
        "skeleton": ((_JP_SKELETON,
                      "np.array([[1, 0, rng * np.sin(phi)], [0, 1, -rng * np.cos(phi)]])"),),
        "solution": ((_JP_SOLUTION,
                      "J_p = np.array([[1, 0, r * np.sin(phi)], [0, 1, -r * np.cos(phi)]])"),)}),
    # (the solution's J_p heading column negated changes nothing: see UNTELLABLE; nor can
    # its P_ll alone tell which entry of that column is negated)
    "jp_one_sign": Mistake("init_jacobian_pose.sign_ly_theta", {
        "skeleton": ((_JP_SKELETON,
                      "np.array([[1, 0, -rng * np.sin(phi)], [0, 1, -rng * np.cos(phi)]])"),)}),
    "jz_transposed": Mistake("init_jacobian_measurement.transposed", {
        "skeleton": ((_JZ_SKELETON, "np.array([[-rng * np.sin(phi), rng * np.cos(phi)],"
                                    " [np.cos(phi), np.sin(phi)]])"),),
        "solution": ((_JZ_SOLUTION, "J_z = np.array([[-r * np.sin(phi), r * np.cos(phi)],"
                                    " [np.cos(phi), np.sin(phi)]])"),)}),
}  # fmt: skip


def apply(text: str, edits: Edits) -> str:
    """``text`` with each (old, new) of ``edits`` replaced wherever it is (it must be)."""
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    return text


def mutants() -> list[tuple[str, str, str]]:
    """Every mutant: (name, the cause check must name, the module's text)."""
    found = []
    for name, mistake in MISTAKES.items():
        for style, edits in mistake.edits.items():
            found.append((f"{style}/{name}", mistake.cause, apply(STYLES[style], edits)))
    return found


# -- correct modules written in unusual ways -------------------------------------------------

FLAT_SKELETON = apply(SKELETON_TEXT, (
    ("x, y, theta = init_pose.reshape(3)",
     "assert init_pose.ndim == 1\n    x, y, theta = init_pose"),
    ("bearing, rng = init_measure[2 * i : 2 * i + 2, 0]",
     "bearing, rng = init_measure[2 * i : 2 * i + 2]"),
    ("landmark = np.zeros((2 * k, 1))", "landmark = np.zeros(2 * k)"),
    ("landmark[2 * i : 2 * i + 2, 0] = [", "landmark[2 * i : 2 * i + 2] = ["),
    ("theta = float(init_pose.reshape(3)[2])", "theta = float(init_pose[2])"),
    ("d, alpha = control[0, 0], control[1, 0]\n    theta = float(X[2, 0])",
     "assert X.ndim == 1 and control.ndim == 1\n    d, alpha = control\n    theta = float(X[2])"),
    ("X[0, 0] += d * np.cos(theta)\n    X[1, 0] += d * np.sin(theta)\n"
     "    X[2, 0] = warp2pi(theta + alpha)",
     "X[0] += d * np.cos(theta)\n    X[1] += d * np.sin(theta)\n    X[2] = warp2pi(theta + alpha)"),
    ("X, P = X_pre.copy(), P_pre.copy()",
     "assert X_pre.ndim == 1 and measure.ndim == 1\n    X, P = X_pre.copy(), P_pre.copy()"),
    ("dx, dy = X[j, 0] - X[0, 0], X[j + 1, 0] - X[1, 0]", "dx, dy = X[j] - X[0], X[j + 1] - X[1]"),
    ("innovation = measure[2 * i : 2 * i + 2, 0] - [np.arctan2(dy, dx) - X[2, 0], r]",
     "innovation = measure[2 * i : 2 * i + 2] - [np.arctan2(dy, dx) - X[2], r]"),
    ("X = X + (K @ innovation).reshape(-1, 1)\n        X[2, 0] = warp2pi(X[2, 0])",
     "X = X + K @ innovation\n        X[2] = warp2pi(X[2])"),
))  # fmt: skip

# flat vectors in predict and update, a column pose in init_landmarks (one function's
# shapes must not lock another's)
MIXED_SKELETON = apply(FLAT_SKELETON, (
    ("assert init_pose.ndim == 1\n    x, y, theta = init_pose",
     "assert init_pose.shape == (3, 1)\n    x, y, theta = init_pose[:, 0]"),
    ("theta = float(init_pose[2])", "theta = float(init_pose[2, 0])"),
))  # fmt: skip

FLOAT32_SKELETON = apply(SKELETON_TEXT, (
    ("    d, alpha = control[0, 0], control[1, 0]\n",
     "    X, P, control = X.astype(np.float32), P.astype(np.float32), control.astype(np.float32)\n"
     "    control_cov = control_cov.astype(np.float32)\n"
     "    d, alpha = control[0, 0], control[1, 0]\n"),
    ("G = np.eye(3 + 2 * k)", "G = np.eye(3 + 2 * k, dtype=np.float32)"),
    ("W = np.array([[np.cos(theta)", "W = np.float32([[np.cos(theta)"),
    ("    X, P = X_pre.copy(), P_pre.copy()\n",
     "    X, P = X_pre.astype(np.float32), P_pre.astype(np.float32)\n"
     "    measure, measure_cov = measure.astype(np.float32), measure_cov.astype(np.float32)\n"),
    ("H = np.zeros((2, n))", "H = np.zeros((2, n), dtype=np.float32)"),
    ("innovation = measure[2 * i : 2 * i + 2, 0] - [",
     "innovation = measure[2 * i : 2 * i + 2, 0] - np.float32(["),
    (", r]\n", ", r])\n"),
    ("    return k, landmark, landmark_cov",
     "    return k, landmark.astype(np.float32), landmark_cov.astype(np.float32)"),
    ("    return cross", "    return cross.astype(np.float32)"),
))  # fmt: skip

MATRIX_SOLUTION = apply(SOLUTION_TEXT, (
    ("    P_pre = G @ P @ G.T + Q\n    return X_pre, P_pre",
     "    G, P, Q = np.matrix(G), np.matrix(P), np.matrix(Q)\n    P_pre = G * P * G.T + Q\n"
     "    return np.matrix(X_pre), P_pre"),
    ("        S = H @ P @ H.T + measure_cov\n        K = P @ H.T @ np.linalg.inv(S)",
     "        H, P = np.matrix(H), np.matrix(P)\n        S = H * P * H.T + measure_cov\n"
     "        K = P * H.T * S.I"),
    ("        X = X + K @ nu\n", "        X = X + np.asarray(K * nu)\n"),
    ("        P = (np.eye(n) - K @ H) @ P\n", "        P = np.asarray((np.eye(n) - K * H) * P)\n"),
))  # fmt: skip

JOSEPH_SOLUTION = apply(SOLUTION_TEXT, (
    ("P = (np.eye(n) - K @ H) @ P",
     "I_KH = np.eye(n) - K @ H\n        P = I_KH @ P @ I_KH.T + K @ measure_cov @ K.T"),
))  # fmt: skip

ATAN2_WRAP = apply(SKELETON_TEXT, (
    ("return float((angle + np.pi) % (2 * np.pi) - np.pi)",
     "return float(np.arctan2(np.sin(angle), np.cos(angle)))"),
))  # fmt: skip

MATH_SKELETON = apply(SKELETON_TEXT, (
    ("import numpy as np\n", "import math\n\nimport numpy as np\n"),
    ("X[0, 0] += d * np.cos(theta)\n    X[1, 0] += d * np.sin(theta)",
     "X[0, 0] += d * math.cos(theta)\n    X[1, 0] += d * math.sin(theta)"),
    ("innovation[0] = warp2pi(innovation[0])",
     "innovation[0] = math.remainder(innovation[0], 2 * math.pi)"),
))  # fmt: skip

NO_CROSS_SKELETON = apply(SKELETON_TEXT, (
    ("def init_cross_covariance(", "def _unused_cross_covariance("),
))  # fmt: skip

SOLVE_TRANSPOSED = apply(SOLUTION_TEXT, (
    ("K = P @ H.T @ np.linalg.inv(S)", "K = np.linalg.solve(S.T, (P @ H.T).T).T"),
))  # fmt: skip

SYMMETRISED = apply(SOLUTION_TEXT, (
    ("        P = (np.eye(n) - K @ H) @ P\n",
     "        P = (np.eye(n) - K @ H) @ P\n        P = (P + P.T) / 2\n"),
))  # fmt: skip

PREDICT_BLOCKS = apply(SOLUTION_TEXT, (
    ("    P_pre = G @ P @ G.T + Q\n",
     "    P_pre = P.copy()\n    g = G[:3, :3]\n    P_pre[:3, :3] = g @ P[:3, :3] @ g.T\n"
     "    P_pre[:3, 3:] = g @ P[:3, 3:]\n    P_pre[3:, :3] = P_pre[:3, 3:].T\n"
     "    P_pre = P_pre + Q\n"),
))  # fmt: skip

ROW_STATE = apply(SKELETON_TEXT, (
    ("    P = 0.5 * (P + P.T)\n    return X, P", "    P = 0.5 * (P + P.T)\n    return X.T, P"),
))  # fmt: skip


def _class_of(text: str, keep_functions: bool = False) -> str:
    """A module whose functions are the methods of one class (made without arguments)."""
    body = text.split("\n\n\n", 1)[1]
    for function in ("warp2pi", "init_landmarks", "init_cross_covariance", "predict", "update"):
        body = body.replace(f"{function}(", f"self.{function}(")
        body = body.replace(f"def self.{function}(", f"def {function}(self, ")
    methods = "\n".join("    " + line if line.strip() else line for line in body.splitlines())
    head = text.split("\n\n\n", 1)[0]
    return f"{head}\n\n\nclass EkfSlam:\n    def __init__(self):\n        self.k = 0\n\n{methods}\n"


CORRECT: dict[str, str] = {
    "skeleton": SKELETON_TEXT,
    "solution": SOLUTION_TEXT,
    "flat": FLAT_SKELETON,
    "flat_but_column_pose_at_init": MIXED_SKELETON,
    "float32": FLOAT32_SKELETON,
    "np_matrix": MATRIX_SOLUTION,
    "lists": students.source("lists"),
    "class_of_the_solution": students.class_based(),
    "class_of_the_skeleton": _class_of(SKELETON_TEXT),
    "class_with_the_handouts_init": _class_of(NO_CROSS_SKELETON),
    "handouts_init_with_correlated_landmarks": NO_CROSS_SKELETON,
    "joseph": JOSEPH_SOLUTION,
    "joint": students.source("joint"),
    "wrap_by_atan2": ATAN2_WRAP,
    "math_floats": MATH_SKELETON,
    "in_place": students.source("inplace"),
    "chatty": students.source("chatty"),
    "main_at_import": SOLUTION_TEXT + students.MAIN_AT_IMPORT,
    "solve_transposed": SOLVE_TRANSPOSED,
    "symmetrised": SYMMETRISED,
    "predict_in_blocks": PREDICT_BLOCKS,
    "row_state": ROW_STATE,
    "tkagg": students.source("tkagg"),
}


# -- mutants of the families the search fits a quantity for -----------------------------------
#
# each in several shapes of code (the course functions with column vectors, the skeleton
# with flat ones, a class of the course functions, a protocol filter class): a noise
# matrix used scaled (the factor read off the filter), a noise of the filter's own that it
# does not declare beside another mistake, and J_p's heading sign
_TEXTBOOK = (ROOT / "tests" / "plugins" / "textbook.py").read_text()
_OWN_Q = "np.diag([0.3, 0.15, 0.05]) ** 2"


def _textbook_with(name: str, body: str) -> str:
    """The textbook protocol filter's module with a subclass ``name`` of ``body``."""
    return f"{_TEXTBOOK}\n\nclass {name}(Textbook):\n{body}"


_OWN_NOISE_INIT = f"""    def __init__(self, params: Any) -> None:
        super().__init__(params)
        self.Q = {_OWN_Q}
"""


@dataclass(frozen=True, slots=True)
class FamilyMutant:
    """A module of a family beside the corpus's: its text, the causes check must name
    beside the handout's, and the class to load from it (none: the module's functions)."""

    causes: frozenset[str]
    text: str
    spec: str = ""


def _causes(*ids: str) -> frozenset[str]:
    return frozenset(ids)


FAMILY_MUTANTS: dict[str, FamilyMutant] = {
    # a noise matrix used scaled
    "scaled/textbook_r_everywhere": FamilyMutant(_causes("measurement_noise.scaled"),
        _textbook_with("RTenfold", _OWN_NOISE_INIT.replace(f"self.Q = {_OWN_Q}",
                                                           "self.R = 10.0 * self.R")),
        "RTenfold"),
    "scaled/skeleton_r_in_s": FamilyMutant(_causes("innovation_covariance.noise_scaled"),
        apply(SKELETON_TEXT, ((_S_SKELETON, "S = H @ P @ H.T + 10 * measure_cov"),))),
    "scaled/flat_q_halved": FamilyMutant(_causes("motion_noise.scaled"),
        apply(FLAT_SKELETON, (("W @ control_cov @ W.T", "W @ (control_cov / 2) @ W.T"),))),
    "scaled/class_pll_quarter": FamilyMutant(_causes("landmark_covariance.noise_scaled"),
        _class_of(apply(SKELETON_TEXT, ((_PLL_SKELETON,
                                         "block = block + J_z @ init_measure_cov @ J_z.T / 4"),)))),
    "scaled/solution_r_everywhere": FamilyMutant(_causes("measurement_noise.scaled"),
        apply(SOLUTION_TEXT, (("    X, P = X_pre.copy(), P_pre.copy()\n",
                               "    X, P = X_pre.copy(), P_pre.copy()\n"
                               "    measure_cov = measure_cov * 5\n"),
                              ("J_z @ init_measure_cov @ J_z.T",
                               "J_z @ (5 * init_measure_cov) @ J_z.T")))),
    # a noise of the filter's own, undeclared, beside another mistake
    "own_noise/textbook_g_heading_sign": FamilyMutant(
        _causes("motion_noise.own", "motion_jacobian.sign_column_theta"),
        _textbook_with("OwnNoise", "    heading_sign = -1.0\n\n" + _OWN_NOISE_INIT), "OwnNoise"),
    "own_noise/solution_g_transposed": FamilyMutant(
        _causes("motion_noise.own", "motion_jacobian.transposed"),
        apply(SOLUTION_TEXT, (("P_pre = G @ P @ G.T + Q", "P_pre = G.T @ P @ G + Q"),
                              ("    d, alpha = control[0, 0], control[1, 0]\n",
                               f"    d, alpha = control[0, 0], control[1, 0]\n"
                               f"    control_cov = {_OWN_Q}\n")))),
    "own_noise/flat_pose_block_only": FamilyMutant(
        _causes("motion_noise.own", "cross_covariance.skipped"),
        apply(FLAT_SKELETON, (("P = G @ P @ G.T",
                               "P[:3, :3] = G[:3, :3] @ P[:3, :3] @ G[:3, :3].T"),
                              ("W @ control_cov @ W.T", f"W @ {_OWN_Q} @ W.T")))),
    # J_p's heading column negated, where a correlated pose at initialisation shows it
    "jp_sign/class_of_the_skeleton": FamilyMutant(
        _causes("init_jacobian_pose.sign_column_theta"),
        _class_of(apply(SKELETON_TEXT, MISTAKES["jp_sign"].edits["skeleton"]))),
    "jp_sign/flat_one_entry": FamilyMutant(_causes("init_jacobian_pose.sign_ly_theta"),
        apply(FLAT_SKELETON, MISTAKES["jp_one_sign"].edits["skeleton"])),
    "jp_sign/flat": FamilyMutant(_causes("init_jacobian_pose.sign_column_theta"),
        apply(FLAT_SKELETON, MISTAKES["jp_sign"].edits["skeleton"])),
}  # fmt: skip

# mutants whose mistake changes no number a course module can give on the battery: the
# handout's init has no cross-covariances and init_landmarks gets a diagonal pose
# covariance, so J_p's heading column enters P_ll as J_p P_rr J_p^T, whatever its sign
UNTELLABLE = {"solution/jp_sign": "solution"}


# -- running check on them -------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Verdict:
    """What check said of a module on the battery: the causes named (mistakes, and the
    handout's and form's), how many groups of divergences were unknown, errors."""

    mistakes: frozenset[str]
    others: frozenset[str]
    unknown: int
    errors: tuple[str, ...]
    hints: tuple[str, ...]


def verdict(path: Path, every: bool = True, spec: str = "") -> Verdict:
    """``check`` of the module at ``path`` (its class ``spec``, if given) on the course
    logs of the battery."""
    from dataclasses import replace

    from ekfviz.check.lockstep import lockstep
    from ekfviz.check.mutations import MUTATION
    from ekfviz.core.params import FilterParams
    from ekfviz.core.records import with_ids
    from ekfviz.filters.spec import FilterSpec, FilterSpecError
    from ekfviz.sim.scenarios import EDGE_START
    from ekfviz.sources import read_log

    mistakes: set[str] = set()
    others: set[str] = set()
    unknown, errors, hints = 0, [], []
    for log, start in (("classic", None), ("edge", EDGE_START)):
        params = FilterParams() if start is None else replace(FilterParams(), init_pose=start)
        try:
            make_filter = FilterSpec(f"{path}:{spec}" if spec else str(path)).load()
        except FilterSpecError as error:
            errors.append(f"{log}: {error}")
            continue
        try:
            result = lockstep(list(with_ids(read_log(ROOT / "data" / f"{log}.txt"))), params,
                              make_filter, name=str(path), every=every)  # fmt: skip
        finally:
            make_filter.close()  # type: ignore[attr-defined]
        for cause in result.causes:
            (mistakes if MUTATION[cause].mistake else others).add(cause)
        unknown += sum(1 for group in result.groups if group.cause == "unknown")
        hints += [group.first.hint for group in result.groups]
        if result.error:
            errors.append(f"{log}: {result.error}")
    return Verdict(frozenset(mistakes), frozenset(others), unknown, tuple(errors), tuple(hints))


def main(folder: Path) -> None:
    """Run the whole corpus, print each verdict and the rates (``python tests/check/corpus.py
    DIR``: the modules are written into DIR)."""
    exact = area = wrong = missed = 0
    rows = []
    for name, cause, text in mutants():
        path = folder / name / "ekf_slam.py"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        found = verdict(path)
        if found.mistakes == {cause} and not found.unknown:  # (its own code may then fail)
            exact += 1
            said = "exact"
        elif found.mistakes - {cause}:
            wrong += 1
            said = "wrong"
        elif cause in found.mistakes:
            area += 1
            said = "named, with unknown beside"
        else:
            missed += 1
            said = "missed"
        rows.append({"module": name, "cause": cause, "verdict": said,
                     "named": sorted(found.mistakes), "unknown": found.unknown,
                     "errors": list(found.errors)})  # fmt: skip
        print(f"{said:28s} {name:40s} {sorted(found.mistakes)} unknown={found.unknown}", flush=True)
    alarms = crashes = 0
    for name, text in CORRECT.items():
        path = folder / "correct" / name / "ekf_slam.py"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        found = verdict(path)
        alarm = bool(found.mistakes or found.unknown)
        alarms += alarm
        crashes += bool(found.errors)
        rows.append(
            {
                "module": f"correct/{name}",
                "verdict": "alarm" if alarm else "pass",
                "named": sorted(found.mistakes | found.others),
                "errors": list(found.errors),
            }
        )
        print(f"{'ALARM' if alarm else 'pass':28s} correct/{name:32s} {sorted(found.mistakes)}"
              f" unknown={found.unknown} errors={found.errors}", flush=True)  # fmt: skip
    total = exact + area + wrong + missed
    print(f"mutants: {exact}/{total} named exactly ({exact / total:.0%}), {area} named with"
          f" unknown beside, {wrong} with a wrong cause, {missed} missed; correct modules:"
          f" {alarms} false alarms, {crashes} crashes of {len(CORRECT)}")  # fmt: skip
    (folder / "verdicts.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    import sys

    main(Path(sys.argv[1]))
