"""Numerical health figures read off records."""

from __future__ import annotations

import numpy as np

from ekfviz.core.health import health
from ekfviz.core.records import EventKind, snapshot
from ekfviz.core.replay import replay
from ekfviz.sim.scenarios import classic


def test_a_healthy_run_has_no_problem() -> None:
    for record in replay(classic().run(seed=1).events):
        figures = health(record)
        assert figures.problems() == []
        assert figures.pose_min_eigenvalue > 0 and figures.pose_asymmetry == 0.0


def test_each_fault_is_named() -> None:
    x = np.zeros(5)
    P = np.eye(5)
    P[3:, 3:] = [[1.0, 2.0], [2.0, 1.0]]  # eigenvalues 3 and -1
    P[0, 1] = 0.5  # not symmetric
    P[2, 2] = -0.1
    figures = health(snapshot(x, P, event=0, step=0, kind=EventKind.INIT))
    assert figures.landmark_min_eigenvalue == -1.0
    assert figures.pose_asymmetry == 0.5
    assert figures.pose_min_eigenvalue < 0
    problems = " / ".join(figures.problems())
    for phrase in ("not symmetric", "pose covariance has a negative", "landmark covariance"):
        assert phrase in problems


def test_round_off_below_zero_is_not_a_fault() -> None:
    P = np.diag([1.0, 1.0, 1.0, 1.0, -1e-12])
    figures = health(snapshot(np.zeros(5), P, event=0, step=0, kind=EventKind.INIT))
    assert figures.landmark_min_eigenvalue == 0.0 and figures.problems() == []
