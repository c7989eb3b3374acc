"""Course-homework solutions of the classic assignment, as students write them.

Each is a module of the handout's functions (``init_landmarks``, ``predict``, ``update``
with column vectors), written out by :func:`write` with one or more real mistakes, so
that ``check`` is tried on code of the shape it meets in the wild: loops over landmarks,
``np.linalg.inv``, ``(I - K H) P``, the handout's imports. :data:`EDITS` are the
students of the wild: the correct module with the edit of one mistake real hand-ins make
(an arctan, a return inside the loop, a pause for a key...). :data:`MISTAKES` says which
causes ``check --all`` must name for each (for those no re-run reproduces: none but the
handout's).
"""

from __future__ import annotations

from pathlib import Path

HEADER = """\
import re

import numpy as np
{imports}

np.set_printoptions(suppress=True)


def warp2pi(angle_rad):
    return (angle_rad + np.pi) % (2 * np.pi) - np.pi
"""

INIT = """

def init_landmarks(init_measure, init_measure_cov, init_pose, init_pose_cov):
    k = init_measure.shape[0] // 2
    landmark = np.zeros((2 * k, 1))
    landmark_cov = np.zeros((2 * k, 2 * k))
    x, y, theta = init_pose[0, 0], init_pose[1, 0], init_pose[2, 0]
    for i in range(k):
        beta, r = init_measure[2 * i, 0], init_measure[2 * i + 1, 0]
        phi = theta + beta
        landmark[2 * i, 0] = x + r * np.cos(phi)
        landmark[2 * i + 1, 0] = y + r * np.sin(phi)
        J_p = np.array([[1, 0, -r * np.sin(phi)], [0, 1, r * np.cos(phi)]])
        J_z = np.array([[-r * np.sin(phi), np.cos(phi)], [r * np.cos(phi), np.sin(phi)]])
        block = {init_cov}
        landmark_cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = block
    return k, landmark, landmark_cov
"""

PREDICT = """

def predict(X, P, control, control_cov, k):
    d, alpha = control[0, 0], control[1, 0]
    theta = X[2, 0]
    X_pre = X.copy()
    X_pre[0, 0] += d * np.cos(theta)
    X_pre[1, 0] += d * np.sin(theta)
    X_pre[2, 0] = warp2pi(theta + alpha)
    G = np.eye(3 + 2 * k)
    G[0, 2] = -d * np.sin(theta)
    G[1, 2] = d * np.cos(theta)
    rot = np.array(
        [[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]]
    )
    Q = np.zeros((3 + 2 * k, 3 + 2 * k))
    Q[:3, :3] = {noise}
    P_pre = {propagate} + Q
    return X_pre, P_pre
"""

# a student of a few years ago: a ragged array, which numpy >= 1.24 refuses
PREDICT_RAGGED = """

def predict(X, P, control, control_cov, k):
    d, alpha = control[0, 0], control[1, 0]
    theta = X[2]
    X_pre = X.copy()
    X_pre[0, 0] += d * np.cos(theta[0])
    X_pre[1, 0] += d * np.sin(theta[0])
    X_pre[2, 0] = warp2pi(theta[0] + alpha)
    G_r = np.array([[1, 0, -d * np.sin(theta)], [0, 1, d * np.cos(theta)], [0, 0, 1]])
    G = np.eye(3 + 2 * k)
    G[:3, :3] = G_r
    c, s = np.cos(theta[0]), np.sin(theta[0])
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    Q = np.zeros((3 + 2 * k, 3 + 2 * k))
    Q[:3, :3] = rot @ control_cov @ rot.T
    return X_pre, G @ P @ G.T + Q
"""

UPDATE_SEQUENTIAL = """

def update(X_pre, P_pre, measure, measure_cov, k):
    X, P = X_pre.copy(), P_pre.copy()
    n = 3 + 2 * k
    for i in range(k):
        lx, ly = X[3 + 2 * i, 0], X[4 + 2 * i, 0]
        dx, dy = lx - X[0, 0], ly - X[1, 0]
        q = dx ** 2 + dy ** 2
        sq = np.sqrt(q)
        H = np.zeros((2, n))
        H[:, :3] = [[dy / q, -dx / q, -1], [-dx / sq, -dy / sq, 0]]
        H[:, 3 + 2 * i : 5 + 2 * i] = [[-dy / q, dx / q], [dx / sq, dy / sq]]
        z_hat = np.array([[warp2pi(np.arctan2(dy, dx) - X[2, 0])], [sq]])
        nu = measure[2 * i : 2 * i + 2] - z_hat
        {wrap}
        S = H @ P @ H.T{plus_r}
        K = P @ H.T @ np.linalg.inv(S)
        X = X + K @ nu
        X[2, 0] = warp2pi(X[2, 0])
        P = (np.eye(n) - K @ H) @ P
    return X, P
"""

UPDATE_JOINT = """

def update(X_pre, P_pre, measure, measure_cov, k):
    n = 3 + 2 * k
    H = np.zeros((2 * k, n))
    z_hat = np.zeros((2 * k, 1))
    for i in range(k):
        dx = X_pre[3 + 2 * i, 0] - X_pre[0, 0]
        dy = X_pre[4 + 2 * i, 0] - X_pre[1, 0]
        q = dx ** 2 + dy ** 2
        sq = np.sqrt(q)
        H[2 * i : 2 * i + 2, :3] = [[dy / q, -dx / q, -1], [-dx / sq, -dy / sq, 0]]
        H[2 * i : 2 * i + 2, 3 + 2 * i : 5 + 2 * i] = [[-dy / q, dx / q], [dx / sq, dy / sq]]
        z_hat[2 * i, 0] = warp2pi(np.arctan2(dy, dx) - X_pre[2, 0])
        z_hat[2 * i + 1, 0] = sq
    nu = measure - z_hat
    {wrap}
    R = np.kron(np.eye(k), measure_cov)
    S = H @ P_pre @ H.T + R
    K = P_pre @ H.T @ np.linalg.inv(S)
    X = X_pre + K @ nu
    X[2, 0] = warp2pi(X[2, 0])
    P = (np.eye(n) - K @ H) @ P_pre
    return X, P
"""

CORRECT_INIT = "J_p @ init_pose_cov @ J_p.T + J_z @ init_measure_cov @ J_z.T"
WRAP_SEQUENTIAL = "nu[0, 0] = warp2pi(nu[0, 0])"
WRAP_JOINT = "nu[0::2] = warp2pi(nu[0::2])"

# name -> the module's options, and the causes check --all must name on the battery
STUDENTS: dict[str, dict[str, str]] = {
    "correct": {},
    "missing_pose_term": {"init_cov": "J_z @ init_measure_cov @ J_z.T"},
    "fixed_init": {"init_cov": "0.5 * np.eye(2)"},
    "transposed": {"propagate": "G.T @ P @ G"},
    "unrotated": {"noise": "control_cov"},
    "no_r": {"plus_r": ""},
    "joint": {"update": "joint"},
    "joint_unwrapped": {"update": "joint", "wrap": "pass"},
    "sequential_unwrapped": {"wrap": "pass"},
    "transposed_and_missing_pose_term": {
        "propagate": "G.T @ P @ G",
        "init_cov": "J_z @ init_measure_cov @ J_z.T",
    },
    "ragged": {"predict": "ragged"},
    "tkagg": {
        "imports": "import matplotlib\n\nmatplotlib.use('TkAgg')\nimport matplotlib.pyplot as plt"
    },
}

# the handout's main() builds P = block_diag(pose_cov, landmark_cov): every solution
# that keeps it initialises its landmarks without cross-covariances
HANDOUT = {"independent_landmark_init"}
MISTAKES: dict[str, set[str]] = {
    "correct": HANDOUT,
    "missing_pose_term": HANDOUT | {"landmark_cov_missing_pose_term"},
    "fixed_init": HANDOUT | {"fixed_landmark_init_covariance"},
    "transposed": HANDOUT | {"transposed_motion_jacobian"},
    "unrotated": HANDOUT | {"unrotated_motion_noise"},
    "no_r": HANDOUT | {"missing_measurement_noise"},
    "joint": HANDOUT | {"joint_update"},
    "joint_unwrapped": HANDOUT | {"joint_update", "unwrapped_innovation"},
    "sequential_unwrapped": HANDOUT | {"unwrapped_innovation"},
    "transposed_and_missing_pose_term": HANDOUT
    | {"transposed_motion_jacobian", "landmark_cov_missing_pose_term"},
    "ragged": HANDOUT,
    "tkagg": HANDOUT,
    "arctan": HANDOUT | {"arctan_bearing"},
    "bearing_world": HANDOUT | {"bearing_not_relative_to_heading"},
    "mod_2pi": HANDOUT | {"innovation_wrapped_to_0_2pi"},
    "return_in_loop": HANDOUT | {"only_first_landmark"},
    "stale_linearisation": HANDOUT | {"linearised_once"},
    "r_twice": HANDOUT | {"measurement_noise_twice"},
    "q_sigmas": HANDOUT | {"motion_noise_not_squared"},
    "atan2_swapped": HANDOUT | {"atan2_arguments_swapped"},
    "z_hat_swapped": HANDOUT | {"predicted_measurement_swapped"},
    "r_sigmas": HANDOUT | {"measurement_noise_not_squared"},
    "joseph_no_krk": HANDOUT | {"joseph_without_measurement_noise"},
    "control_swapped": HANDOUT | {"swapped_control"},
    "range_bearing_init": HANDOUT | {"init_range_bearing_swapped"},
    "cos_sin_init": HANDOUT | {"init_cos_sin_swapped"},
    "h_rows_swapped": HANDOUT | {"measurement_jacobian_rows_swapped"},
    "h_bearing_sign": HANDOUT | {"measurement_jacobian_bearing_sign"},
    "three_at_once": HANDOUT
    | {"arctan_bearing", "linearised_once", "joseph_without_measurement_noise"},
    # R tripled in S: the factor is read off the filter's result
    "r_thrice": HANDOUT | {"innovation_covariance.noise_scaled"},
    # the sign of H_p's position derivatives of the bearing (H_l's right), and alpha taken
    # for degrees: named since the catalogue is generated from every operation
    "jacobian_h_sign": HANDOUT | {"measurement_jacobian_pose.sign_row_bearing_derivatives"},
    "degrees": HANDOUT | {"control.degrees"},
    "inplace": HANDOUT,
    "lists": HANDOUT,
    "chatty": HANDOUT,
    "pauses": HANDOUT,
}
# the integer array's first event (the initialisation) is unknown, with its hint
MISTAKES_UNKNOWN_FIRST = {"int_landmarks"}


def source(name: str) -> str:
    """The module text of one student (of :data:`STUDENTS` or :data:`EDITS`)."""
    if name in EDITS:
        return edited(name)
    options = STUDENTS[name]
    joint = options.get("update") == "joint"
    update = UPDATE_JOINT if joint else UPDATE_SEQUENTIAL
    wrap = options.get("wrap", WRAP_JOINT if joint else WRAP_SEQUENTIAL)
    predict = PREDICT_RAGGED if options.get("predict") == "ragged" else PREDICT
    return (
        HEADER.format(imports=options.get("imports", "import matplotlib.pyplot as plt"))
        + INIT.format(init_cov=options.get("init_cov", CORRECT_INIT))
        + predict.format(
            noise=options.get("noise", "rot @ control_cov @ rot.T"),
            propagate=options.get("propagate", "G @ P @ G.T"),
        )
        + update.format(wrap=wrap, plus_r=options.get("plus_r", " + measure_cov"))
    )


def write(folder: Path, name: str, file_name: str = "ekf_slam.py") -> Path:
    """Write one student's module into ``folder`` (made if missing); its path."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / file_name
    path.write_text(source(name))
    return path


# -- students of the wild: the correct module with one edit each ------------------------------
#
# mistakes seen in real hand-ins of this homework, each written as the students write it;
# (old, new) replacements in the text of source("correct")
_BEARING = "z_hat = np.array([[warp2pi(np.arctan2(dy, dx) - X[2, 0])], [sq]])"
_LANDMARK_XY = (
    "landmark[2 * i, 0] = x + r * np.cos(phi)\n        landmark[2 * i + 1, 0] = y + r * np.sin(phi)"
)
_PREDICT_START = "def predict(X, P, control, control_cov, k):\n"
EDITS: dict[str, tuple[tuple[str, str], ...]] = {
    "arctan": ((_BEARING, _BEARING.replace("np.arctan2(dy, dx)", "np.arctan(dy / dx)")),),
    "bearing_world": ((_BEARING, _BEARING.replace(" - X[2, 0]", "")),),
    "mod_2pi": (
        ("return (angle_rad + np.pi) % (2 * np.pi) - np.pi", "return angle_rad % (2 * np.pi)"),
    ),
    "return_in_loop": (
        ("        P = (np.eye(n) - K @ H) @ P\n    return X, P",
         "        P = (np.eye(n) - K @ H) @ P\n        return X, P"),
    ),
    "stale_linearisation": (
        ("lx, ly = X[3 + 2 * i, 0], X[4 + 2 * i, 0]\n        dx, dy = lx - X[0, 0], ly - X[1, 0]",
         "lx, ly = X_pre[3 + 2 * i, 0], X_pre[4 + 2 * i, 0]\n"
         "        dx, dy = lx - X_pre[0, 0], ly - X_pre[1, 0]"),
        (_BEARING, _BEARING.replace("X[2, 0]", "X_pre[2, 0]")),
    ),
    "r_twice": (
        ("S = H @ P @ H.T + measure_cov",
         "S = H @ P @ H.T + measure_cov\n        S += measure_cov"),
    ),
    "atan2_swapped": ((_BEARING, _BEARING.replace("np.arctan2(dy, dx)", "np.arctan2(dx, dy)")),),
    # h(x) as (range, bearing) where z is (bearing, range)
    "z_hat_swapped": (
        (_BEARING, "z_hat = np.array([[sq], [warp2pi(np.arctan2(dy, dx) - X[2, 0])]])"),
    ),
    # the sigmas taken for variances: Q = diag(sigma), R = diag(sigma) (in S and at init)
    "q_sigmas": (("Q[:3, :3] = rot @ control_cov @ rot.T",
                  "Q[:3, :3] = rot @ np.sqrt(control_cov) @ rot.T"),),
    "r_sigmas": (
        ("S = H @ P @ H.T + measure_cov", "S = H @ P @ H.T + np.sqrt(measure_cov)"),
        ("J_z @ init_measure_cov @ J_z.T", "J_z @ np.sqrt(init_measure_cov) @ J_z.T"),
    ),
    "joseph_no_krk": (
        ("P = (np.eye(n) - K @ H) @ P",
         "I_KH = np.eye(n) - K @ H\n        P = I_KH @ P @ I_KH.T"),
    ),
    "control_swapped": (
        ("d, alpha = control[0, 0], control[1, 0]", "alpha, d = control[0, 0], control[1, 0]"),
    ),
    "range_bearing_init": (
        ("beta, r = init_measure[2 * i, 0], init_measure[2 * i + 1, 0]",
         "r, beta = init_measure[2 * i, 0], init_measure[2 * i + 1, 0]"),
    ),
    "cos_sin_init": (
        (_LANDMARK_XY, _LANDMARK_XY.replace("np.cos", "COS").replace("np.sin", "np.cos")
         .replace("COS", "np.sin")),
    ),
    "h_rows_swapped": (
        ("H[:, :3] = [[dy / q, -dx / q, -1], [-dx / sq, -dy / sq, 0]]",
         "H[:, :3] = [[-dx / sq, -dy / sq, 0], [dy / q, -dx / q, -1]]"),
        ("H[:, 3 + 2 * i : 5 + 2 * i] = [[-dy / q, dx / q], [dx / sq, dy / sq]]",
         "H[:, 3 + 2 * i : 5 + 2 * i] = [[dx / sq, dy / sq], [-dy / q, dx / q]]"),
    ),
    "h_bearing_sign": (
        ("H[:, :3] = [[dy / q, -dx / q, -1], [-dx / sq, -dy / sq, 0]]",
         "H[:, :3] = [[-dy / q, dx / q, -1], [-dx / sq, -dy / sq, 0]]"),
        ("H[:, 3 + 2 * i : 5 + 2 * i] = [[-dy / q, dx / q], [dx / sq, dy / sq]]",
         "H[:, 3 + 2 * i : 5 + 2 * i] = [[dy / q, -dx / q], [dx / sq, dy / sq]]"),
    ),
    # three of the later mistakes at once, from the first update on (the deep search)
    "three_at_once": (
        ("lx, ly = X[3 + 2 * i, 0], X[4 + 2 * i, 0]\n        dx, dy = lx - X[0, 0], ly - X[1, 0]",
         "lx, ly = X_pre[3 + 2 * i, 0], X_pre[4 + 2 * i, 0]\n"
         "        dx, dy = lx - X_pre[0, 0], ly - X_pre[1, 0]"),
        (_BEARING, _BEARING.replace("np.arctan2(dy, dx) - X[2, 0]",
                                    "np.arctan(dy / dx) - X_pre[2, 0]")),
        ("P = (np.eye(n) - K @ H) @ P",
         "I_KH = np.eye(n) - K @ H\n        P = I_KH @ P @ I_KH.T"),
    ),
    "r_thrice": (("S = H @ P @ H.T + measure_cov", "S = H @ P @ H.T + 3 * measure_cov"),),
    "jacobian_h_sign": (
        ("H[:, :3] = [[dy / q, -dx / q, -1], [-dx / sq, -dy / sq, 0]]",
         "H[:, :3] = [[-dy / q, dx / q, -1], [-dx / sq, -dy / sq, 0]]"),
    ),
    "degrees": (
        ("X_pre[2, 0] = warp2pi(theta + alpha)",
         "X_pre[2, 0] = warp2pi(theta + np.deg2rad(alpha))"),
    ),
    "int_landmarks": (
        ("landmark = np.zeros((2 * k, 1))", "landmark = np.zeros((2 * k, 1), dtype=int)"),
    ),
    # harmless: the same results as the correct module
    "inplace": (("X_pre = X.copy()", "X_pre = X"),),
    "lists": (("    return X_pre, P_pre\n", "    return X_pre.tolist(), P_pre.tolist()\n"),),
    "chatty": (
        (_PREDICT_START,
         _PREDICT_START + "    print('P =', P)\n    plt.figure()\n    plt.plot([1, 2])\n"
         "    plt.show()\n"),
    ),
    # the handout's plots wait for a key after every step; a pause of the student's own
    "pauses": (
        ("    return X, P\n",
         "    plt.figure()\n    plt.draw()\n    plt.pause(30)\n    plt.waitforbuttonpress(0)\n"
         "    input('press enter')\n    return X, P\n"),
    ),
    # do not run as they are: one line each
    "p_x_order": (("    return X_pre, P_pre\n", "    return P_pre, X_pre\n"),),
    "q_wrong_size": (("P_pre = G @ P @ G.T + Q", "P_pre = G @ P @ G.T + control_cov"),),
}  # fmt: skip

# the handout's main(), called at import without the `if __name__ == "__main__":` guard
MAIN_AT_IMPORT = """

def main():
    data_file = open("../data/data.txt")
    print(re.split("[\\\\t ]", data_file.readline()))


main()
"""


def edited(name: str) -> str:
    """The module text of a student of :data:`EDITS`."""
    text = source("correct")
    for old, new in EDITS[name]:
        assert old in text, (name, old)
        text = text.replace(old, new)
    return text


def class_based() -> str:
    """The correct module written as a class whose methods are the handout's functions."""
    body = source("correct").split("np.set_printoptions(suppress=True)\n", 1)[1]
    for function in ("warp2pi", "init_landmarks", "predict", "update"):
        body = body.replace(f"{function}(", f"self.{function}(")
        body = body.replace(f"def self.{function}(", f"def {function}(self, ")
    methods = "\n".join("    " + line if line.strip() else line for line in body.splitlines())
    start = "import numpy as np\n\n\nclass EKFSLAM:\n    def __init__(self):\n        self.k = 0\n"
    return f"{start}{methods}\n"
