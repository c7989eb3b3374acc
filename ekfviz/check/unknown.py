"""Where a divergence that no set of mutations reproduces comes from: the first operation
whose value differs, and its numbers in the units of the quantity.

``check`` sees only what a filter leaves after an event; the quantities inside (the
innovation, the noise a predict added) are read off that result by inverting the
reference's operations that follow them: the innovation from the change of the mean
(x' - x = K nu, least squares over the reference's gain), G from the new cross-covariances
(P_rm' = G P_rm), the motion noise from the pose block (P_rr' - G P_rr G^T, in the robot
frame). The operations are looked at in the order the event computes them; the first
that differs is named.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ekfviz.check.operations import OPERATION
from ekfviz.check.rerun import Noise, Rerun, State, Step
from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import (
    expected_measurement,
    landmark_offset,
    measurement_jacobian_landmark,
    measurement_jacobian_pose,
    motion_jacobian,
    noise_jacobian,
)


@dataclass(frozen=True, slots=True)
class Unexplained:
    """The first operation whose value differs, what it is of, and both values.

    :param of: what the numbers are of (``landmark 3 (bearing, range)``)
    :param got: as read off the filter's result (``implied``: by inverting what follows)
    """

    operation: str
    of: str
    expected: tuple[float, ...]
    got: tuple[float, ...]
    units: tuple[str, ...]
    implied: bool = False

    def sentence(self) -> str:
        title = OPERATION[self.operation].title
        how = "implied by the filter's result" if self.implied else "the filter's"
        return (
            f"{title} differs first: {self.of} expected {_shown(self.expected, self.units)},"
            f" {how} {_shown(self.got, self.units)}"
        )

    def to_json(self) -> dict[str, object]:
        return {
            "operation": self.operation,
            "of": self.of,
            "expected": list(self.expected),
            "got": list(self.got),
            "units": list(self.units),
            "implied": self.implied,
        }


def _shown(values: tuple[float, ...], units: tuple[str, ...]) -> str:
    parts = [f"{v:.6g} {u}".rstrip() for v, u in zip(values, units, strict=True)]
    return "(" + ", ".join(parts) + ")"


def unexplained(
    noise: Noise, before: State, after: State, step: Step, tolerance: float
) -> Unexplained | None:
    """The first operation of ``step`` whose value in the filter's result ``after`` differs
    from the reference's (re-run from ``before``), or None where none is found."""
    expected = Rerun(noise).run(before, step)
    if sorted(expected.ids.tolist()) != sorted(after.ids.tolist()):
        return None
    got_x, got_P = after.in_order_of(expected.ids)
    if step.is_predict:
        return _predict(noise, before, expected, got_x, got_P, step, tolerance)
    return _update(noise, before, expected, got_x, got_P, step, tolerance)


def _differs(a: FloatArray, b: FloatArray, tolerance: float) -> bool:
    return bool(np.any(np.abs(a - b) > tolerance * np.maximum(1.0, np.abs(b))))


def _predict(
    noise: Noise,
    before: State,
    expected: State,
    got_x: FloatArray,
    got_P: FloatArray,
    step: Step,
    tolerance: float,
) -> Unexplained | None:
    """The pose, then G (from the cross-covariances), then the noise added to the pose."""
    pose = expected.x[:3]
    got_pose = got_x[:3].copy()
    got_pose[2] = pose[2] + wrap_angle(float(got_pose[2] - pose[2]))
    if _differs(got_pose, pose, tolerance):
        return Unexplained("motion", "the pose (x, y, theta)", tuple(pose.tolist()),
                           tuple(got_pose.tolist()), ("m", "m", "rad"))  # fmt: skip
    G = motion_jacobian(before.x[:3], step.d)
    P_rm = before.P[:3, 3:]
    got_G = G
    if P_rm.shape[1] >= 3 and np.linalg.matrix_rank(P_rm) == 3:
        # P_rm' = G P_rm: G from the cross-covariances, least squares
        got_G = np.linalg.lstsq(P_rm.T, got_P[:3, 3:].T, rcond=None)[0].T
        if _differs(got_G, G, tolerance):
            return Unexplained("motion_jacobian", "G's heading column (G[0, 2], G[1, 2], G[2, 2])",
                               tuple(G[:, 2].tolist()), tuple(got_G[:, 2].tolist()),
                               ("m/rad", "m/rad", ""), implied=True)  # fmt: skip
    W = noise_jacobian(before.x[:3])
    added = got_P[:3, :3] - got_G @ before.P[:3, :3] @ got_G.T
    in_robot = np.linalg.solve(W, np.linalg.solve(W, added).T).T
    if _differs(in_robot, noise.Q, tolerance):
        values = (in_robot[0, 0], in_robot[1, 1], in_robot[2, 2], in_robot[0, 1])
        return Unexplained("motion_noise", "the noise added, in the robot frame (Q_xx, Q_yy,"
                           " Q_aa, Q_xy)", (noise.Q[0, 0], noise.Q[1, 1], noise.Q[2, 2], 0.0),
                           tuple(float(v) for v in values), ("m^2", "m^2", "rad^2", "m^2"),
                           implied=True)  # fmt: skip
    if _differs(got_P, expected.P, tolerance):
        return _worst_covariance("pose_covariance", expected, got_P)
    return None


def _update(
    noise: Noise,
    before: State,
    expected: State,
    got_x: FloatArray,
    got_P: FloatArray,
    step: Step,
    tolerance: float,
) -> Unexplained | None:
    """The known landmarks' innovation (from the mean's change), the corrected
    covariance, then each new landmark's position, covariance and cross-covariance."""
    assert step.ids is not None and step.z is not None
    n = len(before.x)
    state_ids = before.ids.tolist()
    known = [k for k, i in enumerate(step.ids.tolist()) if i in state_ids]
    if known:
        innovation = _implied_innovation(noise, before, expected, got_x, step, known)
        if innovation is not None:
            return innovation
        if _differs(got_P[:n, :n], expected.P[:n, :n], tolerance):
            return _worst_covariance("corrected_covariance", expected, got_P, n)
    for landmark_id in step.ids.tolist():
        if landmark_id in state_ids:
            continue
        j = 3 + 2 * expected.ids.tolist().index(landmark_id)
        of = f"new landmark {landmark_id}"
        if _differs(got_x[j : j + 2], expected.x[j : j + 2], tolerance):
            return Unexplained("landmark_position", f"{of}'s position (x, y)",
                               tuple(expected.x[j : j + 2].tolist()),
                               tuple(got_x[j : j + 2].tolist()), ("m", "m"))  # fmt: skip
        block = (j, j + 1)
        if _differs(got_P[np.ix_(block, block)], expected.P[np.ix_(block, block)], tolerance):
            e, g = expected.P[np.ix_(block, block)], got_P[np.ix_(block, block)]
            return Unexplained("landmark_covariance", f"{of}'s covariance (xx, yy, xy)",
                               (e[0, 0], e[1, 1], e[0, 1]), (g[0, 0], g[1, 1], g[0, 1]),
                               ("m^2", "m^2", "m^2"))  # fmt: skip
        if _differs(got_P[j : j + 2, :3], expected.P[j : j + 2, :3], tolerance):
            e, g = expected.P[j, :3], got_P[j, :3]
            return Unexplained("landmark_cross_covariance", f"{of}'s x with the pose (x, y,"
                               " theta)", tuple(e.tolist()), tuple(g.tolist()),
                               ("m^2", "m^2", "m rad"))  # fmt: skip
    return None


def _implied_innovation(
    noise: Noise,
    before: State,
    expected: State,
    got_x: FloatArray,
    step: Step,
    known: list[int],
) -> Unexplained | None:
    """The innovations of the known landmarks the filter's change of the mean implies
    (x' - x = K nu over the reference's joint gain at ``before``), against those the
    reference's own result implies the same way; the first landmark that differs."""
    assert step.ids is not None and step.z is not None
    n = len(before.x)
    state_ids = before.ids.tolist()
    H_rows, z_pred = [], []
    for k in known:
        j = 3 + 2 * state_ids.index(int(step.ids[k]))
        offset = landmark_offset(before.x[:3], before.x[j : j + 2])
        H = np.zeros((2, n))
        H[:, :3] = measurement_jacobian_pose(offset)
        H[:, j : j + 2] = measurement_jacobian_landmark(offset)
        H_rows.append(H)
        z_pred.append(expected_measurement(offset, float(before.x[2])))
    H = np.vstack(H_rows)
    R_all = np.kron(np.eye(len(known)), noise.R)
    S = H @ before.P @ H.T + R_all
    if np.linalg.cond(S) > 1e10:  # no gain to read an innovation through
        return None
    K = np.linalg.solve(S, H @ before.P).T

    def implied(x: FloatArray) -> FloatArray:
        change = x[:n] - before.x
        change[2] = wrap_angle(float(change[2]))
        nu: FloatArray = np.linalg.lstsq(K, change, rcond=None)[0]
        return nu.reshape(-1, 2)

    reference, filters = implied(expected.x), implied(got_x)
    for row, k in enumerate(known):
        # a tenth of a degree, or a millimetre: the sequential and the joint updates
        # imply innovations closer than this (the gain is the joint one's)
        if np.any(np.abs(filters[row] - reference[row]) > (1.7e-3, 1e-3)):
            landmark_id = int(step.ids[k])
            z = step.z[k]
            return Unexplained(
                "innovation",
                f"landmark {landmark_id}'s innovation (bearing, range), with z ="
                f" ({z[0]:.6g} rad, {z[1]:.6g} m) and h(x) = ({z_pred[row][0]:.6g} rad,"
                f" {z_pred[row][1]:.6g} m) from the state before",
                tuple(reference[row].tolist()),
                tuple(filters[row].tolist()),
                ("rad", "m"),
                implied=True,
            )
    return None


def _worst_covariance(
    operation: str, expected: State, got_P: FloatArray, n: int | None = None
) -> Unexplained:
    """The covariance entry that differs most, named and in its units."""
    size = len(expected.x) if n is None else n
    difference = np.abs(got_P[:size, :size] - expected.P[:size, :size]) / np.maximum(
        1.0, np.abs(expected.P[:size, :size])
    )
    i, j = (int(v) for v in np.unravel_index(int(np.argmax(difference)), difference.shape))
    i, j = min(i, j), max(i, j)
    names = ["x", "y", "theta"] + [f"L{k}.{c}" for k in expected.ids.tolist() for c in "xy"]
    unit = "rad^2" if i == j == 2 else ("m rad" if 2 in (i, j) else "m^2")
    return Unexplained(operation, f"P[{names[i]}, {names[j]}]", (float(expected.P[i, j]),),
                       (float(got_P[i, j]),), (unit,))  # fmt: skip
