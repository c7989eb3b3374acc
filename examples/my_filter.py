"""A complete, small EKF-SLAM filter that follows ekfviz's filter protocol.

    ekfviz replay data/classic.txt --filter examples/my_filter.py:MyFilter --save mine.rrd
    ekfviz check data/classic.txt --filter examples/my_filter.py:MyFilter

Dense and plain on purpose: ekfviz needs only ``predict``, ``update`` and the state.
"""

from __future__ import annotations

import numpy as np


def wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


class MyFilter:
    def __init__(self, params) -> None:  # type: ignore[no-untyped-def]
        self.x = np.array(params.init_pose, dtype=float)  # [x, y, theta, l1x, l1y, ...]
        self.P = np.diag(np.square(params.init_pose_sigma))
        self.landmark_ids: list[int] = []  # in state order
        self.Q, self.R = params.Q, params.R  # motion noise (robot frame), (bearing, range)

    def predict(self, d: float, alpha: float) -> None:
        theta = self.x[2]
        c, s = np.cos(theta), np.sin(theta)
        self.x[:3] += [d * c, d * s, alpha]
        self.x[2] = wrap(self.x[2])
        G = np.eye(len(self.x))
        G[0, 2], G[1, 2] = -d * s, d * c
        W = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        self.P = G @ self.P @ G.T
        self.P[:3, :3] += W @ self.Q @ W.T

    def update(self, ids: np.ndarray, z: np.ndarray) -> None:
        new = []
        for landmark_id, (bearing, rng) in zip(ids.tolist(), z, strict=True):
            if landmark_id not in self.landmark_ids:
                new.append((landmark_id, bearing, rng))  # after the known ones corrected x
                continue
            j = 3 + 2 * self.landmark_ids.index(landmark_id)
            dx, dy = self.x[j] - self.x[0], self.x[j + 1] - self.x[1]
            q = dx * dx + dy * dy
            H = np.zeros((2, len(self.x)))
            H[:, :3] = [[dy / q, -dx / q, -1], [-dx / np.sqrt(q), -dy / np.sqrt(q), 0]]
            H[:, j : j + 2] = [[-dy / q, dx / q], [dx / np.sqrt(q), dy / np.sqrt(q)]]
            S = H @ self.P @ H.T + self.R
            K = np.linalg.solve(S, H @ self.P).T
            nu = np.array([wrap(bearing - np.arctan2(dy, dx) + self.x[2]), rng - np.sqrt(q)])
            self.x = self.x + K @ nu
            self.x[2] = wrap(self.x[2])
            self.P = self.P - K @ S @ K.T
            self.P = 0.5 * (self.P + self.P.T)
        for landmark_id, bearing, rng in new:
            n, phi = len(self.x), self.x[2] + bearing
            J_p = np.array([[1, 0, -rng * np.sin(phi)], [0, 1, rng * np.cos(phi)]])
            J_z = np.array([[-rng * np.sin(phi), np.cos(phi)], [rng * np.cos(phi), np.sin(phi)]])
            P = np.zeros((n + 2, n + 2))
            P[:n, :n] = self.P
            P[n:, :n] = J_p @ self.P[:3, :]  # correlated with the pose and the map
            P[:n, n:] = P[n:, :n].T
            P[n:, n:] = J_p @ self.P[:3, :3] @ J_p.T + J_z @ self.R @ J_z.T
            self.x = np.concatenate(
                [self.x, self.x[:2] + rng * np.array([np.cos(phi), np.sin(phi)])]
            )
            self.P = P
            self.landmark_ids.append(landmark_id)
