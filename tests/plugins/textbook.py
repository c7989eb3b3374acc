"""A dense textbook EKF-SLAM as a protocol filter, and copies of it with classic bugs.

It shares no code with ekfviz (only numpy): full (3+2N)^2 products, selection matrices,
``inv(S)``. The filter math of ekfviz is written once, in ``ekfviz/models``; this is kept
on purpose as an independent dense derivation of it, to cross-check the built-in filter
and ``check``'s reference against. ``Textbook`` is correct; each subclass switches on one
bug that students make, for ``ekfviz check`` to find. Loaded by the tests as
``tests/plugins/textbook.py:Class``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def _wrap(angle: float) -> float:
    wrapped = float(np.remainder(angle + np.pi, 2 * np.pi) - np.pi)
    return np.pi if wrapped == -np.pi else wrapped


class Textbook:
    """Dense EKF-SLAM on a growing state; sequential update, correlated initialisation."""

    heading_sign = 1.0  # sign of the heading column of the motion Jacobian
    rotate_noise = True  # motion noise W Q W^T (robot frame) or Q as if in the world frame
    add_r = True  # S = H P H^T + R
    wrap_innovation = True  # the bearing innovation wrapped to (-pi, pi]
    cross_covariances = True  # a new landmark correlated with the pose and the map

    def __init__(self, params: Any) -> None:
        self.x: Array = np.array(params.init_pose, dtype=float)
        self.P: Array = np.diag(np.square(np.asarray(params.init_pose_sigma, dtype=float)))
        self.landmark_ids: list[int] = []
        self.Q: Array = np.asarray(params.Q, dtype=float)
        self.R: Array = np.asarray(params.R, dtype=float)

    def predict(self, d: float, alpha: float) -> None:
        n = len(self.x)
        theta = self.x[2]
        F_x = np.hstack([np.eye(3), np.zeros((3, n - 3))])
        self.x = self.x + F_x.T @ np.array([d * np.cos(theta), d * np.sin(theta), alpha])
        self.x[2] = _wrap(self.x[2])
        s = self.heading_sign
        g = np.array([[0, 0, -s * d * np.sin(theta)], [0, 0, s * d * np.cos(theta)], [0, 0, 0]])
        G = np.eye(n) + F_x.T @ g @ F_x
        W = np.array(
            [[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]]
        )
        noise = W @ self.Q @ W.T if self.rotate_noise else self.Q
        self.P = G @ self.P @ G.T + F_x.T @ noise @ F_x

    def update(self, ids: Any, z: Any) -> None:
        """Known landmarks one after another in file order, then the new ones."""
        z = np.asarray(z, dtype=float).reshape(-1, 2)
        new = []
        for landmark_id, (bearing, rng) in zip(np.asarray(ids).tolist(), z, strict=True):
            if landmark_id not in self.landmark_ids:
                new.append((landmark_id, bearing, rng))
                continue
            self._correct(3 + 2 * self.landmark_ids.index(landmark_id), bearing, rng)
        for landmark_id, bearing, rng in new:
            self._add(landmark_id, bearing, rng)

    def _correct(self, j: int, bearing: float, rng: float) -> None:
        n = len(self.x)
        dx, dy = self.x[j] - self.x[0], self.x[j + 1] - self.x[1]
        q = dx * dx + dy * dy
        sq = np.sqrt(q)
        z_hat = np.array([_wrap(np.arctan2(dy, dx) - self.x[2]), sq])
        h = np.array(
            [[dy / q, -dx / q, -1, -dy / q, dx / q], [-dx / sq, -dy / sq, 0, dx / sq, dy / sq]]
        )
        F = np.zeros((5, n))
        F[:3, :3] = np.eye(3)
        F[3:, j : j + 2] = np.eye(2)
        H = h @ F
        S = H @ self.P @ H.T + (self.R if self.add_r else 0.0)
        K = self.P @ H.T @ np.linalg.inv(S)
        nu = np.array([bearing, rng]) - z_hat
        if self.wrap_innovation:
            nu[0] = _wrap(nu[0])
        self.x = self.x + K @ nu
        self.x[2] = _wrap(self.x[2])
        I_KH = np.eye(n) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ self.R @ K.T  # Joseph form

    def _add(self, landmark_id: int, bearing: float, rng: float) -> None:
        n = len(self.x)
        x, y, theta = self.x[:3]
        phi = theta + bearing
        J_p = np.array([[1, 0, -rng * np.sin(phi)], [0, 1, rng * np.cos(phi)]])
        J_z = np.array([[-rng * np.sin(phi), np.cos(phi)], [rng * np.cos(phi), np.sin(phi)]])
        P = np.zeros((n + 2, n + 2))
        P[:n, :n] = self.P
        P[n:, n:] = J_p @ self.P[:3, :3] @ J_p.T + J_z @ self.R @ J_z.T
        if self.cross_covariances:
            P[n:, :n] = J_p @ self.P[:3, :]
            P[:n, n:] = P[n:, :n].T
        self.P = P
        self.x = np.concatenate([self.x, [x + rng * np.cos(phi), y + rng * np.sin(phi)]])
        self.landmark_ids.append(int(landmark_id))

    def remove_landmarks(self, ids: Any) -> None:
        """Drop landmarks with their rows and columns (an association's tentative ones)."""
        gone = {int(i) for i in ids}
        keep = [0, 1, 2] + [
            3 + 2 * k + o
            for k, landmark_id in enumerate(self.landmark_ids)
            if landmark_id not in gone
            for o in (0, 1)
        ]
        self.x = self.x[keep]
        self.P = self.P[np.ix_(keep, keep)]
        self.landmark_ids = [i for i in self.landmark_ids if i not in gone]


class NoRemoval(Textbook):
    """A filter that cannot drop landmarks: an association needs --confirm 1 with it."""

    remove_landmarks = None  # type: ignore[assignment]


class Joint(Textbook):
    """All known landmarks of a line in one step, linearised at the predicted state."""

    def update(self, ids: Any, z: Any) -> None:
        z = np.asarray(z, dtype=float).reshape(-1, 2)
        known = [(i, zk) for i, zk in zip(np.asarray(ids).tolist(), z, strict=True)
                 if i in self.landmark_ids]  # fmt: skip
        if known:
            n = len(self.x)
            H = np.zeros((2 * len(known), n))
            nu = np.zeros(2 * len(known))
            for k, (landmark_id, (bearing, rng)) in enumerate(known):
                j = 3 + 2 * self.landmark_ids.index(landmark_id)
                dx, dy = self.x[j] - self.x[0], self.x[j + 1] - self.x[1]
                q = dx * dx + dy * dy
                sq = np.sqrt(q)
                H[2 * k : 2 * k + 2, :3] = [[dy / q, -dx / q, -1], [-dx / sq, -dy / sq, 0]]
                H[2 * k : 2 * k + 2, j : j + 2] = [[-dy / q, dx / q], [dx / sq, dy / sq]]
                nu[2 * k : 2 * k + 2] = [_wrap(bearing - np.arctan2(dy, dx) + self.x[2]), rng - sq]
            R = np.kron(np.eye(len(known)), self.R)
            S = H @ self.P @ H.T + R
            K = self.P @ H.T @ np.linalg.inv(S)
            self.x = self.x + K @ nu
            self.x[2] = _wrap(self.x[2])
            I_KH = np.eye(n) - K @ H
            self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T
        for landmark_id, (bearing, rng) in zip(np.asarray(ids).tolist(), z, strict=True):
            if landmark_id not in self.landmark_ids:
                self._add(landmark_id, bearing, rng)


class WrongJacobianSign(Textbook):
    heading_sign = -1.0


class UnrotatedMotionNoise(Textbook):
    rotate_noise = False


class NoRInS(Textbook):
    add_r = False


class UnwrappedBearing(Textbook):
    wrap_innovation = False


class NothingWrapped(Textbook):
    """Neither the heading, nor the predicted bearing, nor the innovation is wrapped."""

    wrap_innovation = False

    def predict(self, d: float, alpha: float) -> None:
        theta = self.x[2] + alpha
        super().predict(d, alpha)
        self.x[2] = theta

    def _correct(self, j: int, bearing: float, rng: float) -> None:
        global _wrap
        wrap, _wrap = _wrap, lambda angle: float(angle)
        try:
            super()._correct(j, bearing, rng)
        finally:
            _wrap = wrap


class NoCrossCovariances(Textbook):
    cross_covariances = False


class Raises(Textbook):
    """Fails at its third predict."""

    calls = 0

    def predict(self, d: float, alpha: float) -> None:
        self.calls += 1
        if self.calls == 3:
            raise ZeroDivisionError("division by zero in my predict")
        super().predict(d, alpha)


class WrongShape(Textbook):
    def update(self, ids: Any, z: Any) -> None:
        super().update(ids, z)
        self.x = self.x[:-1]


class NotFinite(Textbook):
    def predict(self, d: float, alpha: float) -> None:
        super().predict(d, alpha)
        self.x[0] = np.nan


class Asymmetric(Textbook):
    def predict(self, d: float, alpha: float) -> None:
        super().predict(d, alpha)
        self.P[0, 1] += 1e-3


class Drifting(Textbook):
    """A P made asymmetric a little more at every event, as the rounding of a filter that
    never symmetrises P is: by ``growth`` times the share of the event before (starting at
    ``first`` of P's largest entry), in one entry."""

    first = 3e-9
    growth = 1.0  # 1: the share adds up; over 1: it grows as a product does
    _share = 0.0

    def _drift(self) -> None:
        self._share = self.first if not self._share else self._share * self.growth
        self.P[0, 1] += self._share * float(np.abs(self.P).max())

    def predict(self, d: float, alpha: float) -> None:
        super().predict(d, alpha)
        self._drift()

    def update(self, ids: Any, z: Any) -> None:
        super().update(ids, z)
        self._drift()


class DriftingFast(Drifting):
    """Its asymmetry doubles at every event: past any drift rounding makes."""

    growth = 2.0


class LosesIds(Textbook):
    def update(self, ids: Any, z: Any) -> None:
        super().update(ids, z)
        self.landmark_ids = self.landmark_ids[:-1]


class Offline(Textbook):
    """An offline filter (it has finish()): only its state after finish() is recorded."""

    finished = False

    def finish(self) -> None:
        self.finished = True


class OfflineWithPath(Offline):
    """An offline filter that gives its whole path after finish(): here the pose it held
    after each predict (the start's first, the last one x's)."""

    def __init__(self, params: Any) -> None:
        super().__init__(params)
        self.path: list[Array] = [self.x[:3].copy()]

    def predict(self, d: float, alpha: float) -> None:
        super().predict(d, alpha)
        self.path.append(self.x[:3].copy())

    @property
    def poses_xytheta(self) -> Array | None:
        if not self.finished:
            return None
        path = np.array(self.path)
        path[-1] = self.x[:3]
        return path


class BadPath(OfflineWithPath):
    @property
    def poses_xytheta(self) -> Array | None:
        return np.zeros((3, 2))


class BadConstructor:
    def __init__(self, params: Any) -> None:
        raise RuntimeError("cannot start")
