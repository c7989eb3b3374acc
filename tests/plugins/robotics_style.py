"""A protocol filter in the style of a well-known open-source EKF-SLAM example: the motion
Jacobian applied transposed to the pose block only, a noise of its own, a new landmark
started at a fixed covariance and then updated with its own measurement, S with the
motion noise. Written for the tests of ``check`` (no code of that project)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def pi_2_pi(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class RoboticsStyle:
    def __init__(self, params: Any) -> None:
        self.xs = np.array(params.init_pose, float).reshape(3, 1)
        self.P = np.diag(np.square(params.init_pose_sigma))
        self.landmark_ids: list[int] = []
        self.Cx = np.diag([0.5, 0.5, np.deg2rad(30.0)]) ** 2

    @property
    def x(self) -> Any:
        return self.xs.reshape(-1)

    def predict(self, d: float, alpha: float) -> None:
        th = self.xs[2, 0]
        G = np.eye(3)
        G[0, 2] = -d * math.sin(th)
        G[1, 2] = d * math.cos(th)
        self.xs[0, 0] += d * math.cos(th)
        self.xs[1, 0] += d * math.sin(th)
        self.xs[2, 0] += alpha
        self.P[0:3, 0:3] = G.T @ self.P[0:3, 0:3] @ G + self.Cx
        self.xs[2, 0] = pi_2_pi(self.xs[2, 0])

    def update(self, ids: Any, z: Any) -> None:
        for lid, (b, r) in zip(ids, z, strict=True):
            lid = int(lid)
            if lid not in self.landmark_ids:
                th = self.xs[2, 0]
                lm = np.array(
                    [[self.xs[0, 0] + r * math.cos(th + b)], [self.xs[1, 0] + r * math.sin(th + b)]]
                )
                n = len(self.xs)
                self.xs = np.vstack((self.xs, lm))
                P = np.zeros((n + 2, n + 2))
                P[:n, :n] = self.P
                P[n:, n:] = np.eye(2)
                self.P = P
                self.landmark_ids.append(lid)
            i = self.landmark_ids.index(lid)
            j = 3 + 2 * i
            dx = self.xs[j, 0] - self.xs[0, 0]
            dy = self.xs[j + 1, 0] - self.xs[1, 0]
            q = dx * dx + dy * dy
            sq = math.sqrt(q)
            zp = np.array([[sq], [pi_2_pi(math.atan2(dy, dx) - self.xs[2, 0])]])
            y = np.array([[r], [b]]) - zp
            y[1] = pi_2_pi(y[1])
            n = len(self.xs)
            H = np.zeros((2, n))
            H[0, :3] = [-dx / sq, -dy / sq, 0]
            H[1, :3] = [dy / q, -dx / q, -1]
            H[0, j : j + 2] = [dx / sq, dy / sq]
            H[1, j : j + 2] = [-dy / q, dx / q]
            S = H @ self.P @ H.T + self.Cx[0:2, 0:2]
            K = self.P @ H.T @ np.linalg.inv(S)
            self.xs = self.xs + K @ y
            self.P = (np.eye(n) - K @ H) @ self.P
        self.xs[2, 0] = pi_2_pi(self.xs[2, 0])


class RoboticsStyleExposed(RoboticsStyle):
    @property
    def measurement_noise(self) -> Any:
        return np.diag([self.Cx[1, 1], self.Cx[0, 0]])

    @property
    def motion_noise(self) -> Any:
        return self.Cx
