"""The catalogue of real EKF-SLAM mistakes, and the re-runs that recognise them.

Each :class:`Cause` has a stable id (used in ``check``'s report and the README's table).
A divergence is explained by a set of causes only when re-running that event from the
filter's own prior state with exactly those mistakes (and the form of update the filter
uses) reproduces the filter's whole result: mean, covariance and landmark ids. Nothing is
guessed: where no set reproduces it, or two different sets do equally, the cause is
``unknown``.

Predicts are judged without assuming the filter's motion noise: the mistake in the
Jacobian is found from what the noise does not touch (the mean, the cross-covariances),
and the noise the filter added to the pose block is then read off and compared with the
run's Q (rotated into the world frame, unrotated, missing, or a Q of the filter's own).

Dense algebra throughout (these re-runs are for states up to a few hundred entries).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.angles import wrap_angle

UNKNOWN = "unknown"
# what a re-run of a mistake may raise on a state it does not fit (a singular S, a
# landmark at the robot): that mistake does not reproduce the event
RERUN_ERRORS = (ValueError, IndexError, ArithmeticError, np.linalg.LinAlgError)


@dataclass(frozen=True, slots=True)
class Cause:
    """One mistake of the catalogue.

    :param id: stable, for reports and scripts
    :param event: ``predict`` or ``update`` (a new landmark's initialisation is an update)
    :param wrong: what the code does wrong
    :param seen: what ``check`` sees
    :param fix: how to fix it
    """

    id: str
    event: str
    wrong: str
    seen: str
    fix: str


CATALOGUE: tuple[Cause, ...] = (
    Cause("independent_landmark_init", "update",
          "a new landmark gets no cross-covariance with the pose (and the map), as"
          " P = block_diag(pose_cov, landmark_cov) does",
          "the pose-landmark cross-covariance of a new landmark is 0",
          "P_lx = J_p P_px: the new rows are J_p times the pose rows of P"),
    Cause("landmark_cov_missing_pose_term", "update",
          "a new landmark's covariance comes from the measurement noise alone:"
          " P_ll = J_z R J_z^T",
          "the new landmark's covariance is too small by J_p P_pp J_p^T",
          "P_ll = J_p P_pp J_p^T + J_z R J_z^T"),
    Cause("landmark_cov_missing_measurement_term", "update",
          "a new landmark's covariance lacks the measurement noise: P_ll = J_p P_pp J_p^T",
          "the new landmark's covariance is too small by J_z R J_z^T",
          "P_ll = J_p P_pp J_p^T + J_z R J_z^T"),
    Cause("fixed_landmark_init_covariance", "update",
          "a new landmark starts with a constant covariance (np.eye(2) times a number, a"
          " fixed diagonal), whatever its range and the pose's uncertainty",
          "the new landmark's covariance is the same constant matrix at every range",
          "P_ll = J_p P_pp J_p^T + J_z R J_z^T (with P_lx = J_p P_px)"),
    Cause("landmark_init_in_line_order", "update",
          "a new landmark is initialised where it comes in the line, from the pose before"
          " the known landmarks after it corrected it",
          "a new landmark's mean and covariance match the pose before the line's updates",
          "fold in the known landmarks first, then initialise the new ones (or say so:"
          " the reference does known first)"),
    Cause("update_at_initialisation", "update",
          "a new landmark, once initialised from a measurement, is updated with that same"
          " measurement (a zero innovation: the measurement counted twice)",
          "the new landmark's covariance (and the pose's) shrink at its first sighting",
          "initialise a new landmark from its measurement and do not fold that measurement"
          " in again"),
    Cause("joint_update", "update",
          "all landmarks of a line are folded in at once (one stacked H, S, K), where the"
          " reference folds them in one after another",
          "every update differs slightly (the linearisation point); --update joint"
          " checks against the joint form instead",
          "not a bug in itself: check with --update joint, or update one landmark at a"
          " time, re-linearising in between"),
    Cause("unwrapped_innovation", "update",
          "the bearing innovation z - h(x) is not wrapped to (-pi, pi]",
          "near bearings of +-pi the innovation is about 2 pi off: a jump in the pose"
          " and the map at that update",
          "wrap the bearing component of z - h(x) (after the subtraction) before using it"),
    Cause("missing_measurement_noise", "update",
          "R is missing from the innovation covariance: S = H P H^T",
          "the update is too strong: the covariance shrinks far too much",
          "S = H P H^T + R"),
    Cause("arctan_bearing", "update",
          "the expected bearing uses np.arctan(dy / dx), which cannot tell a landmark"
          " behind the robot from one ahead of it",
          "updates differ (by pi in the bearing) whenever a landmark has dx < 0",
          "h(x)'s bearing = wrap(arctan2(dy, dx) - theta)"),
    Cause("atan2_arguments_swapped", "update",
          "the expected bearing uses np.arctan2(dx, dy), the arguments the other way round"
          " (arctan2 takes y first)",
          "every update's bearing innovation is off (by pi/2 minus twice the direction)",
          "h(x)'s bearing = wrap(arctan2(dy, dx) - theta): dy first"),
    Cause("predicted_measurement_swapped", "update",
          "h(x) is built as (range, bearing) while the measurement z is (bearing, range):"
          " the innovation subtracts a range from a bearing and a bearing from a range",
          "every update's innovation is far off, in both components",
          "h(x) = (bearing, range), in the order of z"),
    Cause("bearing_not_relative_to_heading", "update",
          "the expected bearing is arctan2(dy, dx), the landmark's direction in the world,"
          " without subtracting the heading theta",
          "every update's innovation is off by the heading",
          "h(x)'s bearing = wrap(arctan2(dy, dx) - theta)"),
    Cause("innovation_wrapped_to_0_2pi", "update",
          "the bearing innovation is wrapped into [0, 2 pi) (angle % (2 pi)), not into"
          " [-pi, pi): a slightly negative innovation becomes almost 2 pi",
          "an update jumps wherever the bearing innovation is negative",
          "warp2pi(a) = (a + pi) % (2 pi) - pi"),
    Cause("measurement_jacobian_rows_swapped", "update",
          "H's rows are in the order (range, bearing) (as in Probabilistic Robotics) where"
          " the measurement and the innovation are (bearing, range)",
          "every update is wrong: the gain mixes the bearing and range innovations",
          "H's first row is the bearing's: [dy/q, -dx/q, -1, -dy/q, dx/q], then the"
          " range's: [-dx/r, -dy/r, 0, dx/r, dy/r]"),
    Cause("measurement_jacobian_bearing_sign", "update",
          "the bearing row of H has the signs of its position derivatives flipped:"
          " [-dy/q, dx/q, -1, dy/q, -dx/q] (d atan2(dy, dx) taken the wrong way round)",
          "every update is wrong: the gain moves the pose and the landmark the wrong way"
          " in bearing",
          "H's bearing row = [dy/q, -dx/q, -1, -dy/q, dx/q] with dx, dy the landmark"
          " minus the robot"),
    Cause("only_first_landmark", "update",
          "only the first landmark of a line is folded in (e.g. a return inside the loop"
          " over the landmarks)",
          "the other landmarks of a line change nothing",
          "fold in every landmark of the line; return after the loop"),
    Cause("linearised_once", "update",
          "landmarks are folded in one after another, but h(x) and H are computed at the"
          " predicted state (X_pre) for all of them, not at the state the previous ones"
          " corrected",
          "the second and later landmarks of a line are corrected from a stale mean",
          "inside the loop, compute dx, dy, h(x) and H from the current X"),
    Cause("measurement_noise_not_squared", "update",
          "R is built from the sigmas, not their squares: R = diag(sigma_bearing,"
          " sigma_range), in S and in a new landmark's covariance",
          "every update is too weak (R too large, for sigmas under 1) and new landmarks"
          " too uncertain",
          "R = diag(sigma_bearing^2, sigma_range^2): a covariance holds variances"),
    Cause("measurement_noise_twice", "update",
          "R is added twice to the innovation covariance: S = H P H^T + 2 R",
          "the update is too weak",
          "S = H P H^T + R"),
    Cause("joseph_without_measurement_noise", "update",
          "Joseph's form without its noise term: P = (I - K H) P (I - K H)^T",
          "the covariance shrinks too much at every update",
          "P = (I - K H) P (I - K H)^T + K R K^T, or simply P = (I - K H) P"),
    Cause("init_range_bearing_swapped", "update",
          "a new landmark is initialised from (range, bearing) where the measurement is"
          " (bearing, range): r and beta swapped",
          "new landmarks are far from where the reference puts them",
          "beta, r = measure[2 i], measure[2 i + 1] (bearing first)"),
    Cause("init_cos_sin_swapped", "update",
          "a new landmark's position uses sin for x and cos for y:"
          " l = pose + r (sin(theta + beta), cos(theta + beta))",
          "new landmarks are mirrored about the diagonal through the robot",
          "l = pose + r (cos(theta + beta), sin(theta + beta))"),
    Cause("transposed_motion_jacobian", "predict",
          "the motion Jacobian is applied transposed: G^T P G instead of G P G^T",
          "the pose covariance (and the pose-landmark cross-covariance) of a predict are"
          " wrong when the robot drives",
          "P' = G P G^T + W Q W^T (G on the left)"),
    Cause("wrong_jacobian_sign", "predict",
          "the heading column of the motion Jacobian G has the wrong sign:"
          " [d sin(theta), -d cos(theta), 1]",
          "the pose covariance of a predict is wrong when the robot drives",
          "G = [[1, 0, -d sin(theta)], [0, 1, d cos(theta)], [0, 0, 1]]"),
    Cause("identity_motion_jacobian", "predict",
          "the motion Jacobian G lacks its heading column: G is the identity",
          "the pose covariance of a predict does not grow with the heading's uncertainty",
          "G = [[1, 0, -d sin(theta)], [0, 1, d cos(theta)], [0, 0, 1]]"),
    Cause("jacobian_after_motion", "predict",
          "G (and W) are evaluated at the heading after the turn, theta + alpha",
          "the pose covariance of a predict is wrong after turns",
          "evaluate G and W at the heading before the predict"),
    Cause("predict_pose_block_only", "predict",
          "a predict changes only the pose block of P: the pose-landmark cross-covariances"
          " are not multiplied by G",
          "the pose-landmark cross-covariance of a predict is unchanged",
          "P_rm' = G P_rm for every landmark (only the robot's rows and columns change,"
          " but all of them)"),
    Cause("turn_before_drive", "predict",
          "the robot turns before it drives",
          "the predicted position is off after every turn",
          "drive d along the old heading, then turn alpha"),
    Cause("unrotated_motion_noise", "predict",
          "the motion noise Q (robot frame: along, sideways, turn) is added to P as it is,"
          " not rotated into the world frame",
          "the pose covariance of a predict is wrong whenever the heading is not 0 or pi",
          "add W Q W^T with W the rotation by the heading"),
    Cause("missing_motion_noise", "predict",
          "no motion noise is added: P' = G P G^T",
          "the pose covariance of a predict is too small",
          "P' = G P G^T + W Q W^T"),
    Cause("swapped_control", "predict",
          "the control is read as (alpha, d) where it is (d, alpha): the robot drives"
          " alpha and turns d",
          "the predicted pose is far off at every predict",
          "d, alpha = control[0], control[1] (distance first, then the turn)"),
    Cause("motion_noise_not_squared", "predict",
          "Q is built from the sigmas, not their squares: Q = diag(sigma_x, sigma_y,"
          " sigma_alpha)",
          "the pose covariance of a predict grows by the sigmas, not their squares",
          "Q = diag(sigma_x^2, sigma_y^2, sigma_alpha^2): a covariance holds variances"),
    Cause("different_motion_noise", "predict",
          "the filter adds a motion noise of its own, not the run's --sigma-x/-y/-alpha",
          "the pose covariance of a predict differs by a constant",
          "give ekfviz the filter's sigmas (--sigma-x, --sigma-y, --sigma-alpha) or expose"
          " them as motion_noise"),
)  # fmt: skip

CAUSES: dict[str, Cause] = {cause.id: cause for cause in CATALOGUE}


@dataclass(frozen=True, slots=True)
class State:
    """A filter state: x (3+2N,), P (3+2N, 3+2N), landmark ids (N,) in state order."""

    x: FloatArray
    P: FloatArray
    ids: IntArray

    def in_order_of(self, ids: IntArray) -> tuple[FloatArray, FloatArray]:
        """x and P with the landmarks in the order of ``ids`` (the same landmarks, e.g.
        another state's), to compare entry by entry.

        :raises KeyError: an id of ``ids`` that this state has not
        """
        where = {int(i): k for k, i in enumerate(self.ids.tolist())}
        index = [0, 1, 2]
        for landmark_id in ids.tolist():
            k = 3 + 2 * where[int(landmark_id)]
            index += [k, k + 1]
        return self.x[index], self.P[np.ix_(index, index)]


# -- predicts --------------------------------------------------------------------------------

JACOBIAN_FLAGS = (
    "transposed_motion_jacobian",
    "wrong_jacobian_sign",
    "identity_motion_jacobian",
    "jacobian_after_motion",
    "predict_pose_block_only",
    "turn_before_drive",
    "swapped_control",
)
_EXCLUSIVE_PREDICT = (
    {"wrong_jacobian_sign", "identity_motion_jacobian"},
    {"transposed_motion_jacobian", "identity_motion_jacobian"},
)


def predict_without_noise(
    s: State, d: float, alpha: float, flags: frozenset[str]
) -> tuple[State, FloatArray]:
    """The predict with the Jacobian mistakes of ``flags`` and no noise; and W (3x3), the
    rotation the noise should go through (at the heading the filter linearises at)."""
    x, P = s.x.copy(), s.P.copy()
    if "swapped_control" in flags:
        d, alpha = alpha, d
    theta = float(x[2])
    at = theta + alpha if "jacobian_after_motion" in flags else theta
    along = theta + alpha if "turn_before_drive" in flags else theta
    x[0] += d * math.cos(along)
    x[1] += d * math.sin(along)
    x[2] = wrap_angle(theta + alpha)
    G = np.eye(3)
    if "identity_motion_jacobian" not in flags:
        sign = -1.0 if "wrong_jacobian_sign" in flags else 1.0
        G[0, 2], G[1, 2] = -sign * d * math.sin(at), sign * d * math.cos(at)
    if "transposed_motion_jacobian" in flags:
        G = G.T
    P[:3, :3] = G @ P[:3, :3] @ G.T
    if "predict_pose_block_only" not in flags:
        P[:3, 3:] = G @ s.P[:3, 3:]
        P[3:, :3] = P[:3, 3:].T
    c, sn = math.cos(at), math.sin(at)
    W = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    return State(x, P, s.ids), W


def _close(a: FloatArray, b: FloatArray, tol: float) -> bool:
    if a.shape != b.shape:
        return False
    return bool(np.all(np.abs(a - b) <= tol * np.maximum(1.0, np.abs(b))))


def _noise_causes(N: FloatArray, W: FloatArray, Q: FloatArray, tol: float) -> set[str] | None:
    """Which noise mistakes make the filter's pose-block noise ``N`` (3x3), or None when it
    is no motion noise at all (not symmetric PSD and diagonal in either frame)."""
    if _close(N, W @ Q @ W.T, tol):
        return set()
    if _close(N, Q, tol):
        return {"unrotated_motion_noise"}
    if _close(N, np.zeros((3, 3)), tol):
        return {"missing_motion_noise"}
    sigmas = np.diag(np.sqrt(np.diag(Q)))  # Q = diag(sigma), in either frame
    if _close(N, W @ sigmas @ W.T, tol):
        return {"motion_noise_not_squared"}
    if _close(N, sigmas, tol):
        return {"motion_noise_not_squared", "unrotated_motion_noise"}
    if not _close(N, N.T, tol) or np.linalg.eigvalsh(0.5 * (N + N.T)).min() < -tol:
        return None
    in_robot = W.T @ N @ W
    if _close(in_robot, np.diag(np.diag(in_robot)), tol):
        return {"different_motion_noise"}
    if _close(N, np.diag(np.diag(N)), tol):
        return {"different_motion_noise", "unrotated_motion_noise"}
    return None


# -- updates ---------------------------------------------------------------------------------

UPDATE_FLAGS = (
    "joint_update",
    "unwrapped_innovation",
    "missing_measurement_noise",
    "landmark_init_in_line_order",
    "arctan_bearing",
    "bearing_not_relative_to_heading",
    "atan2_arguments_swapped",
    "predicted_measurement_swapped",
    "innovation_wrapped_to_0_2pi",
    "only_first_landmark",
    "linearised_once",
    "measurement_noise_twice",
    "measurement_noise_not_squared",
    "joseph_without_measurement_noise",
    "measurement_jacobian_rows_swapped",
    "measurement_jacobian_bearing_sign",
)
INIT_FLAGS = (
    "update_at_initialisation",
    "independent_landmark_init",
    "landmark_cov_missing_pose_term",
    "landmark_cov_missing_measurement_term",
    "fixed_landmark_init_covariance",
    "init_range_bearing_swapped",
    "init_cos_sin_swapped",
)
# the update mistakes that change a new landmark's initialisation too: tried at a line
# of new landmarks only
_INIT_AND_UPDATE_FLAGS = ("measurement_noise_not_squared",)
_EXCLUSIVE_UPDATE = (
    {
        "landmark_cov_missing_pose_term",
        "landmark_cov_missing_measurement_term",
        "fixed_landmark_init_covariance",
    },
    # one way of wrapping the innovation
    {"unwrapped_innovation", "innovation_wrapped_to_0_2pi", "predicted_measurement_swapped"},
    # one expression of the expected bearing
    {"arctan_bearing", "bearing_not_relative_to_heading", "atan2_arguments_swapped"},
    # one form of the loop over a line
    {"joint_update", "only_first_landmark", "linearised_once"},
    {"missing_measurement_noise", "measurement_noise_twice", "measurement_noise_not_squared"},
    {"measurement_jacobian_rows_swapped", "measurement_jacobian_bearing_sign"},
    {"init_range_bearing_swapped", "init_cos_sin_swapped"},
)
# how a filter may write what is mathematically one update; not mistakes
_VARIANTS = (
    {"form": "joseph", "wrap": "difference", "independent": "all"},
    {"form": "simple", "wrap": "difference", "independent": "all"},
    {"form": "joseph", "wrap": "nothing", "independent": "pose"},
    {"form": "simple", "wrap": "nothing", "independent": "pose"},
)


def update_with(
    R: FloatArray,
    s: State,
    ids: IntArray,
    z: FloatArray,
    flags: frozenset[str],
    *,
    form: str = "joseph",
    wrap: str = "difference",
    independent: str = "all",
    fixed: FloatArray | None = None,
) -> State:
    """The update of ``ids``/``z`` from ``s`` with the mistakes of ``flags``.

    :param form: how P is corrected: ``joseph`` ((I-KH) P (I-KH)^T + K R K^T) or
        ``simple`` ((I-KH) P); equal for a right gain, not for a wrong S
    :param wrap: with ``unwrapped_innovation``: ``difference`` (h(x) wrapped, z - h(x)
        not) or ``nothing`` (neither; the heading is not wrapped either)
    :param independent: with ``independent_landmark_init``: ``all`` cross-covariances 0,
        or only the ``pose`` ones (the landmarks of one line still correlated)
    :param fixed: the constant covariance of ``fixed_landmark_init_covariance``
    """
    x, P, state_ids = s.x.copy(), s.P.copy(), [int(i) for i in s.ids]
    unwrapped = "unwrapped_innovation" in flags
    if "measurement_noise_not_squared" in flags:  # the one R of the filter, everywhere
        R = np.diag(np.sqrt(np.diag(R)))
    noise = np.zeros((2, 2)) if "missing_measurement_noise" in flags else R
    if "measurement_noise_twice" in flags:
        noise = 2.0 * R
    if "joseph_without_measurement_noise" in flags:
        form = "joseph_without_noise"
    new_start = len(x)
    # where ``linearised_once`` computes h(x) and H: the state before the line
    line_x = s.x

    def add(landmark_id: int, bearing: float, rng: float) -> None:
        nonlocal x, P
        if "init_range_bearing_swapped" in flags:
            bearing, rng = rng, bearing
        n = len(x)
        phi = x[2] + bearing
        J_p = np.array([[1.0, 0.0, -rng * math.sin(phi)], [0.0, 1.0, rng * math.cos(phi)]])
        J_z = np.array(
            [[-rng * math.sin(phi), math.cos(phi)], [rng * math.cos(phi), math.sin(phi)]]
        )
        grown = np.zeros((n + 2, n + 2))
        grown[:n, :n] = P
        if "fixed_landmark_init_covariance" in flags and fixed is not None:
            block = fixed
        else:
            pose_term = J_p @ P[:3, :3] @ J_p.T
            measurement_term = J_z @ R @ J_z.T
            if "landmark_cov_missing_pose_term" in flags:
                pose_term = np.zeros((2, 2))
            if "landmark_cov_missing_measurement_term" in flags:
                measurement_term = np.zeros((2, 2))
            block = pose_term + measurement_term
        grown[n:, n:] = block
        if "independent_landmark_init" not in flags:
            grown[n:, :n] = J_p @ P[:3, :]
        elif independent == "pose":
            grown[n:, new_start:n] = J_p @ P[:3, new_start:n]
        grown[:n, n:] = grown[n:, :n].T
        P = grown
        c, sn = (math.sin(phi), math.cos(phi)) if "init_cos_sin_swapped" in flags else (
            math.cos(phi), math.sin(phi))  # fmt: skip
        x = np.concatenate([x, [x[0] + rng * c, x[1] + rng * sn]])
        state_ids.append(landmark_id)

    def correct(rows: list[tuple[int, float, float]]) -> None:
        nonlocal x, P
        n, m = len(x), len(rows)
        H = np.zeros((2 * m, n))
        nu = np.zeros(2 * m)
        # (a landmark initialised in this line is linearised where it was put)
        at = np.concatenate([line_x, x[len(line_x) :]]) if "linearised_once" in flags else x
        for k, (j, bearing, rng) in enumerate(rows):
            dx, dy = at[j] - at[0], at[j + 1] - at[1]
            q = dx * dx + dy * dy
            r = math.sqrt(q)
            H[2 * k : 2 * k + 2, :3] = [[dy / q, -dx / q, -1.0], [-dx / r, -dy / r, 0.0]]
            H[2 * k : 2 * k + 2, j : j + 2] = [[-dy / q, dx / q], [dx / r, dy / r]]
            if "measurement_jacobian_bearing_sign" in flags:
                H[2 * k, :2] *= -1.0
                H[2 * k, j : j + 2] *= -1.0
            if "measurement_jacobian_rows_swapped" in flags:
                H[[2 * k, 2 * k + 1]] = H[[2 * k + 1, 2 * k]]
            direction = math.atan(dy / dx) if "arctan_bearing" in flags else math.atan2(dy, dx)
            if "atan2_arguments_swapped" in flags:
                direction = math.atan2(dx, dy)
            if "bearing_not_relative_to_heading" in flags:
                predicted = direction
            else:
                predicted = direction - at[2]
            if "predicted_measurement_swapped" in flags:  # z - (range, bearing)
                nu[2 * k] = wrap_angle(bearing - r)
                nu[2 * k + 1] = rng - (wrap_angle(predicted) if wrap == "difference" else predicted)
                continue
            if "innovation_wrapped_to_0_2pi" in flags:
                nu[2 * k] = (bearing - predicted) % (2 * math.pi)
            elif not unwrapped:
                nu[2 * k] = wrap_angle(bearing - predicted)
            elif wrap == "difference":
                nu[2 * k] = bearing - wrap_angle(predicted)
            else:
                nu[2 * k] = bearing - predicted
            nu[2 * k + 1] = rng - r
        R_all = np.kron(np.eye(m), noise)
        HP = H @ P
        S = HP @ H.T + R_all
        K = np.linalg.solve(S, HP).T
        x = x + K @ nu
        if not (unwrapped and wrap == "nothing"):
            x[2] = wrap_angle(float(x[2]))
        # (I - K H) P as P - K (H P), and A (I - K H)^T as A - (A H^T) K^T: the same
        # algebra in O(n^2) (H has 2m rows), where forming I - K H costs O(n^3) on the
        # large states check re-runs (400 entries: ten times faster)
        corrected = P - K @ HP
        if form in ("joseph", "joseph_without_noise"):
            P = corrected - (corrected @ H.T) @ K.T
            if form == "joseph":
                P = P + K @ np.kron(np.eye(m), R) @ K.T
        else:
            P = 0.5 * (corrected + corrected.T)

    known: list[tuple[int, float, float]] = []
    new: list[tuple[int, float, float]] = []
    in_order = "landmark_init_in_line_order" in flags
    joint = "joint_update" in flags
    folded = 0
    for landmark_id, (bearing, rng) in zip(ids.tolist(), z.tolist(), strict=True):
        if landmark_id in state_ids and landmark_id not in [n[0] for n in new]:
            j = 3 + 2 * state_ids.index(landmark_id)
            if "only_first_landmark" in flags and folded:
                continue
            folded += 1
            if joint:
                known.append((j, bearing, rng))
            else:
                correct([(j, bearing, rng)])
        elif "update_at_initialisation" in flags and not joint:
            add(landmark_id, bearing, rng)
            correct([(len(x) - 2, bearing, rng)])
        elif in_order and not joint:
            add(landmark_id, bearing, rng)
        else:
            new.append((landmark_id, bearing, rng))
    if known:
        correct(known)
    for landmark_id, bearing, rng in new:
        add(landmark_id, bearing, rng)
    return State(x, P, np.array(state_ids, dtype=np.int64))


# -- the search ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Explanation:
    """What reproduces one divergent event: the causes (empty: none found), the other
    equally small explanations when the event cannot tell them apart, and details."""

    causes: tuple[str, ...]
    alternatives: tuple[tuple[str, ...], ...] = ()
    detail: str = ""

    @property
    def known(self) -> bool:
        return bool(self.causes) and not self.alternatives


def _subsets(
    flags: Iterable[str],
    found: frozenset[str],
    exclusive: tuple[set[str], ...],
    most: int,
    least: int = 0,
) -> list[frozenset[str]]:
    """Candidate sets: the mistakes already found plus ``least`` to ``most`` more,
    smallest first."""
    extra = [f for f in flags if f not in found]
    sets: list[frozenset[str]] = []
    for size in range(least, most + 1):
        for combo in itertools.combinations(extra, size):
            chosen = found | frozenset(combo)
            if any(len(chosen & group) > 1 for group in exclusive):
                continue
            sets.append(chosen)
    return sets


def _minimal(flags: frozenset[str], reproduces: Callable[[frozenset[str]], bool]) -> frozenset[str]:
    """``flags`` without the ones that make no difference at this event."""
    kept = set(flags)
    for flag in sorted(flags):
        trial = frozenset(kept - {flag})
        if reproduces(trial):
            kept.discard(flag)
    return frozenset(kept)


def _choose(
    found_sets: list[frozenset[str]], known: frozenset[str], detail: str = ""
) -> Explanation:
    if not found_sets:
        return Explanation(())
    smallest = min(len(s) for s in found_sets)
    candidates = sorted({s for s in found_sets if len(s) == smallest}, key=sorted)
    if len(candidates) > 1:
        confirmed = [s for s in candidates if s <= known]
        if len(confirmed) == 1:
            candidates = confirmed
    if len(candidates) == 1:
        return Explanation(tuple(sorted(candidates[0])), (), detail)
    return Explanation(tuple(sorted(candidates[0])), tuple(tuple(sorted(s)) for s in candidates))


def explain_predict(
    Q: FloatArray,
    before: State,
    after: State,
    d: float,
    alpha: float,
    found: frozenset[str],
    tolerance: float,
    divergence: float = 0.0,
) -> Explanation:
    """The causes that reproduce a divergent predict (see the module docstring).

    :param divergence: how far the filter is from the reference (scaled): a re-run
        reproduces the filter when it comes within ten times the tolerance (or a
        billionth of a huge divergence); nothing looser, which would name causes that
        merely come near
    """
    close = max(tolerance * 10, 1e-8, 1e-9 * divergence)
    if len(after.x) != len(before.x) or list(after.ids) != list(before.ids):
        return Explanation(())
    cache: dict[frozenset[str], tuple[frozenset[str], str] | None] = {}

    def noise_of(flags: frozenset[str]) -> tuple[frozenset[str], str] | None:
        """The noise causes that complete ``flags`` into a reproduction, or None."""
        if flags in cache:
            return cache[flags]
        cache[flags] = None
        candidate, W = predict_without_noise(before, d, alpha, flags)
        dx = after.x - candidate.x
        dx[2] = wrap_angle(float(dx[2]))
        if not np.all(np.abs(dx) <= close * np.maximum(1.0, np.abs(candidate.x))):
            return None
        rest = after.P.copy()
        rest[:3, :3] = candidate.P[:3, :3]
        if not _close(rest, candidate.P, close):
            return None
        N = after.P[:3, :3] - candidate.P[:3, :3]
        noise = _noise_causes(N, W, Q, close)
        if noise is None:
            return None
        detail = ""
        if "different_motion_noise" in noise:
            sigmas = np.sqrt(np.clip(np.diag(W.T @ N @ W), 0.0, None))
            detail = (
                "its motion sigmas are about"
                f" {sigmas[0]:.4g}, {sigmas[1]:.4g}, {sigmas[2]:.4g} (along, sideways, turn)"
            )
        cache[flags] = (frozenset(noise), detail)
        return cache[flags]

    base = found & frozenset(JACOBIAN_FLAGS)
    results: list[frozenset[str]] = []
    details: dict[frozenset[str], str] = {}
    for flags in _subsets(JACOBIAN_FLAGS, base, _EXCLUSIVE_PREDICT, 2):
        if noise_of(flags) is None:
            continue
        smallest = _minimal(flags, lambda f: noise_of(f) is not None)
        completed = noise_of(smallest)
        assert completed is not None
        chosen = smallest | completed[0]
        details[chosen] = completed[1]
        results.append(chosen)
    explanation = _choose([s for s in results if s], found)
    detail = details.get(frozenset(explanation.causes), "")
    return Explanation(explanation.causes, explanation.alternatives, detail)


def explain_update(
    R: FloatArray,
    before: State,
    after: State,
    ids: IntArray,
    z: FloatArray,
    found: frozenset[str],
    tolerance: float,
    divergence: float = 0.0,
    *,
    deep: bool = False,
) -> Explanation:
    """The causes that reproduce a divergent update (see :func:`explain_predict`).

    :param deep: try three more mistakes at once of all the catalogue; else at most one
        of the later ones (:data:`_LATER`) among them, and none among three
    """
    close = max(tolerance * 10, 1e-8, 1e-9 * divergence)
    if sorted(after.ids.tolist()) != sorted(set(before.ids.tolist()) | set(ids.tolist())):
        return Explanation(())
    has_new = any(int(i) not in before.ids.tolist() for i in ids)
    has_known = any(int(i) in before.ids.tolist() for i in ids)
    flags_here = (UPDATE_FLAGS if has_known else _INIT_AND_UPDATE_FLAGS) + (
        INIT_FLAGS if has_new else ()
    )
    if not (has_new and has_known):  # the order of a line matters only with both in it
        flags_here = tuple(f for f in flags_here if f != "landmark_init_in_line_order")
    fixed = _fixed_block(before, after, ids) if has_new else None
    if fixed is None:
        flags_here = tuple(f for f in flags_here if f != "fixed_landmark_init_covariance")
    base = found & frozenset(flags_here)

    def aligned(candidate: State) -> bool:
        if sorted(candidate.ids.tolist()) != sorted(after.ids.tolist()):
            return False
        x, P = after.in_order_of(candidate.ids)
        dx = x - candidate.x
        dx[2] = wrap_angle(float(dx[2]))
        if not np.all(np.abs(dx) <= close * np.maximum(1.0, np.abs(candidate.x))):
            return False
        return _close(P, candidate.P, close)

    cache: dict[frozenset[str], bool] = {}

    def reproduces(flags: frozenset[str]) -> bool:
        if flags not in cache:
            cache[flags] = False
            for variant in _variants(flags):
                try:
                    candidate = update_with(R, before, ids, z, flags, fixed=fixed, **variant)
                except RERUN_ERRORS:
                    continue
                if aligned(candidate):
                    cache[flags] = True
                    break
        return cache[flags]

    flags_here = _effective(flags_here, lambda flags: update_with(R, before, ids, z, flags,
                                                                  fixed=fixed))  # fmt: skip
    # the fewest more mistakes first: once sets of one size reproduce the event, larger
    # ones are not tried (with the catalogue's update mistakes, up to three more are
    # hundreds of re-runs; most events are explained by one). Unless deep, the later
    # mistakes one at a time, and up to two more beside it (beside the mistakes already
    # found, which every set has)
    results: list[frozenset[str]] = []
    for size in range(0, 4):
        for flags in _subsets(flags_here, base, _EXCLUSIVE_UPDATE, size, least=size):
            if not deep and len((flags - base) & _LATER) > (1 if size < 3 else 0):
                continue
            if reproduces(flags):
                smallest = _minimal(flags, reproduces)
                if smallest:
                    results.append(smallest)
        if results:
            break
    return _choose(results, found)


# the update mistakes met in real students' hand-ins beside the textbook ones: tried only
# where they change the event's result, and one at a time (beside those already found)
# but in the deep search
_PRUNABLE = frozenset({
    "arctan_bearing", "bearing_not_relative_to_heading", "innovation_wrapped_to_0_2pi",
    "atan2_arguments_swapped", "predicted_measurement_swapped",
    "only_first_landmark", "linearised_once", "measurement_noise_twice",
    "measurement_noise_not_squared", "init_range_bearing_swapped", "init_cos_sin_swapped",
})  # fmt: skip
_LATER = _PRUNABLE | {
    "joseph_without_measurement_noise",
    "measurement_jacobian_rows_swapped",
    "measurement_jacobian_bearing_sign",
}


def _effective(flags: tuple[str, ...], run: Callable[[frozenset[str]], State]) -> tuple[str, ...]:
    """``flags`` without the prunable mistakes that alone give exactly the correct result
    at this event (an arctan with every landmark ahead, the first landmark of a line of
    one): they would multiply the sets tried and can reproduce nothing more."""
    try:
        correct = run(frozenset())
    except RERUN_ERRORS:
        return flags
    kept = []
    for flag in flags:
        if flag in _PRUNABLE:
            try:
                alone = run(frozenset({flag}))
            except RERUN_ERRORS:
                continue
            if np.array_equal(alone.x, correct.x) and np.array_equal(alone.P, correct.P):
                continue
        kept.append(flag)
    return tuple(kept)


def _variants(flags: frozenset[str]) -> list[dict[str, str]]:
    """The ways of writing the update (:data:`_VARIANTS`) that differ for ``flags``:
    ``wrap`` only matters with an unwrapped innovation, ``independent`` with independent
    landmarks, and ``form`` not with Joseph's form without its noise (the flag sets it)."""
    seen: set[tuple[str, str, str]] = set()
    chosen = []
    for variant in _VARIANTS:
        key = (
            "" if "joseph_without_measurement_noise" in flags else variant["form"],
            variant["wrap"] if "unwrapped_innovation" in flags else "",
            variant["independent"] if "independent_landmark_init" in flags else "",
        )
        if key not in seen:
            seen.add(key)
            chosen.append(variant)
    return chosen


def _fixed_block(before: State, after: State, ids: IntArray) -> FloatArray | None:
    """The filter's covariance of its new landmarks where it is one constant diagonal
    matrix for all of them (a fixed initial covariance), else None."""
    known = set(before.ids.tolist())
    where = {int(i): k for k, i in enumerate(after.ids.tolist())}
    blocks = []
    for landmark_id in ids.tolist():
        if int(landmark_id) in known or int(landmark_id) not in where:
            continue
        k = 3 + 2 * where[int(landmark_id)]
        blocks.append(after.P[k : k + 2, k : k + 2])
    if not blocks:
        return None
    first = blocks[0]
    scale = max(1e-12, float(np.abs(first).max()))
    if abs(first[0, 1]) > 1e-9 * scale:
        return None
    if any(np.abs(b - first).max() > 1e-9 * scale for b in blocks[1:]):
        return None
    return np.array(first)


def describe(causes: Iterable[str]) -> str:
    """The hint of a set of causes: what each does wrong and how to fix it."""
    parts = [f"{CAUSES[c].wrong}; fix: {CAUSES[c].fix}" for c in causes if c in CAUSES]
    return " AND ".join(parts)
