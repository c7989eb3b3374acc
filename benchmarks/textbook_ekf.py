"""A textbook dense EKF-SLAM, written the way course skeletons are.

Full (3+2N)^2 products everywhere: F_x selection matrices, G = I + F_x^T g F_x, full H
through a selection matrix, ``inv(S)``, ``(I - K H) P``. It is the baseline the
benchmarks time ekfviz against, and an independent oracle for the tests: it shares no
code with ekfviz (whose filter math is written once, in ``ekfviz/models``), kept on
purpose as an independent dense derivation to cross-check against. Landmarks are all
known from the first line (the classic format), so the state has a fixed size.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


class TextbookEkfSlam:
    """Dense EKF-SLAM over a fixed number of landmarks."""

    def __init__(
        self,
        n_landmarks: int,
        Q: Array,
        R: Array,
        init_pose_sigma: tuple[float, float, float] = (0.02, 0.02, 0.1),
        correlated_init: bool = True,
    ) -> None:
        self.N = n_landmarks
        dim = 3 + 2 * n_landmarks
        self.x = np.zeros(dim)
        self.P = np.zeros((dim, dim))
        self.P[:3, :3] = np.diag(np.square(init_pose_sigma))
        self.Q = Q
        self.R = R
        self.correlated_init = correlated_init
        self.F_x = np.hstack([np.eye(3), np.zeros((3, 2 * n_landmarks))])

    def run(self, events: Sequence[Any]) -> None:
        """Initialise from the first line, then predict or update line by line.

        Duck-typed so that this file shares no code with ekfviz: a control has ``d`` and
        ``alpha``, an observation has ``z`` and ``ids``, landmark i having id i+1.
        """
        self.initialise(events[0].z)
        for event in events[1:]:
            if hasattr(event, "d"):
                self.predict(event.d, event.alpha)
            else:
                self.update(event.z, [int(i) - 1 for i in event.ids])

    def initialise(self, z: Array) -> None:
        """Initialise landmark i from the i-th (bearing, range) of the first line."""
        for i, (bearing, rng) in enumerate(z.reshape(-1, 2)):
            x, y, theta = self.x[:3]
            phi = theta + bearing
            j = 3 + 2 * i
            self.x[j : j + 2] = [x + rng * np.cos(phi), y + rng * np.sin(phi)]
            J_p = np.array([[1, 0, -rng * np.sin(phi)], [0, 1, rng * np.cos(phi)]])
            J_z = np.array([[-rng * np.sin(phi), np.cos(phi)], [rng * np.cos(phi), np.sin(phi)]])
            P_ll = J_p @ self.P[:3, :3] @ J_p.T + J_z @ self.R @ J_z.T
            self.P[j : j + 2, j : j + 2] = P_ll
            if self.correlated_init:
                # landmarks not yet initialised have zero rows, so this is P_l,map
                cross = J_p @ self.P[:3, :]
                cross[:, j : j + 2] = P_ll
                self.P[j : j + 2, :] = cross
                self.P[:, j : j + 2] = cross.T

    def predict(self, d: float, alpha: float) -> None:
        theta = self.x[2]
        self.x = self.x + self.F_x.T @ np.array([d * np.cos(theta), d * np.sin(theta), alpha])
        self.x[2] = _wrap(self.x[2])
        g = np.array([[0, 0, -d * np.sin(theta)], [0, 0, d * np.cos(theta)], [0, 0, 0]])
        G = np.eye(len(self.x)) + self.F_x.T @ g @ self.F_x
        W = np.array(
            [[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]]
        )
        self.P = G @ self.P @ G.T + self.F_x.T @ (W @ self.Q @ W.T) @ self.F_x

    def update(self, z: Array, landmarks: Sequence[int] | None = None) -> None:
        """Sequential update with every landmark, in order.

        ``landmarks`` gives the 0-based index of the landmark of each (bearing, range) pair
        of ``z`` when not all are seen (default: all of them, in order).
        """
        dim = len(self.x)
        z = z.reshape(-1, 2)
        if landmarks is None:
            landmarks = range(len(z))
        for i, (bearing, rng) in zip(landmarks, z, strict=True):
            j = 3 + 2 * i
            dx, dy = self.x[j] - self.x[0], self.x[j + 1] - self.x[1]
            q = dx * dx + dy * dy
            sq = np.sqrt(q)
            z_hat = np.array([_wrap(np.arctan2(dy, dx) - self.x[2]), sq])
            h = np.array(
                [
                    [dy / q, -dx / q, -1, -dy / q, dx / q],
                    [-dx / sq, -dy / sq, 0, dx / sq, dy / sq],
                ]
            )
            F = np.zeros((5, dim))
            F[:3, :3] = np.eye(3)
            F[3:, j : j + 2] = np.eye(2)
            H = h @ F
            S = H @ self.P @ H.T + self.R
            K = self.P @ H.T @ np.linalg.inv(S)
            nu = np.array([bearing, rng]) - z_hat
            nu[0] = _wrap(nu[0])
            self.x = self.x + K @ nu
            self.x[2] = _wrap(self.x[2])
            self.P = (np.eye(dim) - K @ H) @ self.P
