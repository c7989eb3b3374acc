"""Run a course-style EKF-SLAM module (functions ``init_landmarks``, ``predict``,
``update``) as an ekfviz filter::

    ekfviz check data.txt --filter examples/course_skeleton/adapter.py:Skeleton

``Skeleton`` runs ``ekf_slam.py`` beside this file; to check your own module, copy this
file next to it and set ``MODULE`` to its file name. The module may also have
``init_cross_covariance(init_measure, init_pose, init_pose_cov)``, the new landmarks'
cross-covariance with the pose; without it P starts as block_diag(pose_cov,
landmark_cov), as many skeletons' main() builds it, and ``ekfviz check`` says so at the
first line (``--landmark-init independent`` checks against that variant instead).
The skeleton reads the classic format: every observation line names all k landmarks of
the first line, in the same order.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np


def _load(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"course_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise ImportError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class Skeleton:
    """A function-style EKF-SLAM module behind the ekfviz filter protocol."""

    MODULE = "ekf_slam.py"

    def __init__(self, params: Any) -> None:
        self.slam = _load(Path(__file__).with_name(self.MODULE))
        self.X = np.asarray(params.init_pose, dtype=float).reshape(3, 1)
        self.P = np.diag(np.square(np.asarray(params.init_pose_sigma, dtype=float)))
        self.control_cov = np.asarray(params.Q, dtype=float)
        self.measure_cov = np.asarray(params.R, dtype=float)
        self.landmark_ids: list[int] = []

    @property
    def x(self) -> Any:
        return self.X.reshape(-1)

    @property
    def k(self) -> int:
        return len(self.landmark_ids)

    def predict(self, d: float, alpha: float) -> None:
        self.X, self.P = self.slam.predict(
            self.X, self.P, np.array([d, alpha]), self.control_cov, self.k
        )

    def update(self, ids: Any, z: Any) -> None:
        ids = [int(i) for i in ids]
        measure = np.asarray(z, dtype=float).reshape(-1, 1)
        if not self.landmark_ids:
            self._initialise(ids, measure)
        elif ids != self.landmark_ids:
            raise ValueError(
                "the course skeleton reads the classic format: every observation names the"
                f" landmarks {self.landmark_ids} in that order, this one {ids}"
            )
        else:
            self.X, self.P = self.slam.update(self.X, self.P, measure, self.measure_cov, self.k)

    def _initialise(self, ids: list[int], measure: Any) -> None:
        pose, pose_cov = self.X[:3], self.P[:3, :3]
        k, landmark, landmark_cov = self.slam.init_landmarks(
            measure, self.measure_cov, pose, pose_cov
        )
        P = np.zeros((3 + 2 * k, 3 + 2 * k))
        P[:3, :3] = pose_cov
        P[3:, 3:] = landmark_cov
        if hasattr(self.slam, "init_cross_covariance"):
            cross = self.slam.init_cross_covariance(measure, pose, pose_cov)
            P[3:, :3] = cross
            P[:3, 3:] = cross.T
        self.X = np.vstack([pose, landmark])
        self.P = P
        self.landmark_ids = ids
