"""Numerical health figures read off a run's states."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ekfviz.core.batch import StateParts
from ekfviz.core.errors import FilterError
from ekfviz.core.health import CHECK_EVERY_STEPS, check_covariance, health
from ekfviz.core.params import FilterParams, LandmarkInit, UpdateMode
from ekfviz.core.records import Control, EventRecord, LogEvent, Sighting
from ekfviz.filters.ekf import EkfSlam
from ekfviz.runner.replay import FilterLineError, replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import classic, loop


def test_a_healthy_run_has_no_problem() -> None:
    for record in every_event(replay(classic().run(seed=1).events)):
        figures = health(record.pose_cov, record.landmark_covs)
        assert figures.problems() == []
        assert figures.pose_min_eigenvalue > 0 and figures.pose_asymmetry == 0.0


def test_each_fault_is_named() -> None:
    x = np.zeros(5)
    P = np.eye(5)
    P[3:, 3:] = [[1.0, 2.0], [2.0, 1.0]]  # eigenvalues 3 and -1
    P[0, 1] = 0.5  # not symmetric
    P[2, 2] = -0.1
    parts = StateParts.of(x, P)
    figures = health(parts.pose_cov, parts.landmark_covs)
    assert figures.landmark_min_eigenvalue == -1.0
    assert figures.pose_asymmetry == 0.5
    assert figures.pose_min_eigenvalue < 0
    problems = " / ".join(figures.problems())
    for phrase in ("not symmetric", "pose covariance has a negative", "landmark covariance"):
        assert phrase in problems


def test_round_off_below_zero_is_not_a_fault() -> None:
    P = np.diag([1.0, 1.0, 1.0, 1.0, -1e-12])
    parts = StateParts.of(np.zeros(5), P)
    figures = health(parts.pose_cov, parts.landmark_covs)
    assert figures.landmark_min_eigenvalue == 0.0 and figures.problems() == []


# -- faults the filter meets: each constructed, each seen and survived or stopped ------


def _mapped_then_on_top(params: FilterParams, compiled: bool) -> EkfSlam:
    """A filter that has mapped landmark 1 at (1, 0) and driven onto it."""
    ekf = EkfSlam(params, compiled=compiled)
    ekf.observe([1, 2], np.array([[0.0, 1.0], [0.5, 4.0]]))
    ekf.predict(1.0, 0.0)
    return ekf


@pytest.mark.parametrize("mode", list(UpdateMode))
def test_a_landmark_at_zero_range_is_skipped_with_a_warning(
    mode: UpdateMode, compiled: bool
) -> None:
    ekf = _mapped_then_on_top(FilterParams(update=mode), compiled)
    x, P = ekf.x.copy(), ekf.P.copy()
    observations = ekf.observe([1], np.array([[0.0, 0.5]]))
    assert observations.skipped.tolist() == [True] and np.isnan(observations.nis).all()
    assert len(ekf.warnings) == 1
    assert "landmark 1: predicted 0 m from the robot" in ekf.warnings[0]
    assert "Jacobian" in ekf.warnings[0] and "skipped" in ekf.warnings[0]
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)
    # the other landmark of the same line is still used
    both = ekf.observe([1, 2], np.array([[0.0, 0.5], [0.9, 3.2]]))
    assert both.skipped.tolist() == [True, False] and np.isfinite(both.nis[1])
    assert not np.array_equal(ekf.x, x)


@pytest.mark.parametrize("mode", list(UpdateMode))
def test_an_innovation_covariance_that_is_not_definite_is_skipped(
    mode: UpdateMode, compiled: bool
) -> None:
    ekf = EkfSlam(FilterParams(update=mode), compiled=compiled)
    ekf.observe([1], np.array([[0.0, 3.0]]))
    # a landmark block with a large negative eigenvalue along the line of sight: the
    # fault a broken covariance update makes
    ekf._P[3, 3] = -5.0
    x, P = ekf.x.copy(), ekf.P.copy()
    observations = ekf.observe([1], np.array([[0.0, 3.0]]))
    assert observations.skipped.tolist() == [True] and np.isnan(observations.nis).all()
    assert "not positive definite" in ekf.warnings[0]
    assert observations.S[0, 1, 1] < 0  # the S that was refused is kept for inspection
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)
    problems = check_covariance(ekf.P).problems()
    assert problems and "not positive semi-definite" in problems[0]


@pytest.mark.parametrize("mode", list(UpdateMode))
def test_a_nan_in_the_covariance_stops_the_update(mode: UpdateMode, compiled: bool) -> None:
    ekf = EkfSlam(FilterParams(update=mode), compiled=compiled)
    ekf.observe([1, 2], np.array([[0.0, 3.0], [1.0, 2.0]]))
    ekf._P[3, 5] = ekf._P[5, 3] = np.nan  # a cross-covariance between the two landmarks
    with pytest.raises(FilterError, match="non-finite"):
        ekf.observe([1, 2], np.array([[0.0, 3.0], [1.0, 2.0]]))


def test_an_overflow_stops_the_replay_at_its_line() -> None:
    events: list[LogEvent] = [
        Sighting(1, np.array([1]), np.array([[0.1, 5.0]])),
        Control(2, 1.0, 0.0),
        Control(3, 1e308, 0.0),
        Control(4, 1.0, 0.0),
    ]
    records: list[EventRecord] = []
    with pytest.raises(FilterLineError, match="non-finite") as caught:
        for batch in replay(events):
            records.extend(batch)
    assert caught.value.line == 3
    assert [record.line for record in records] == [1, 2]  # everything before it
    assert all(np.isfinite(record.pose).all() for record in records)


def test_a_broken_covariance_is_named_by_the_check() -> None:
    P = np.diag([1.0, 1.0, 0.1, 2.0, 2.0])
    assert check_covariance(P).problems() == [] and check_covariance(P).condition == 20.0
    P[0, 4] = 1e-3  # one asymmetric entry
    assert "not symmetric" in check_covariance(P).problems()[0]
    P[0, 4] = P[4, 0] = 5.0  # symmetric again, but indefinite
    check = check_covariance(P)
    assert check.min_eigenvalue < 0 and check.condition == np.inf
    assert "not positive semi-definite" in check.problems()[0]
    P[1, 1] = np.inf
    assert check_covariance(P).problems() == ["the covariance P holds NaN or infinity"]


@pytest.mark.parametrize("mode", list(UpdateMode))
@pytest.mark.parametrize("init", list(LandmarkInit))
def test_a_replay_checks_its_covariance_and_keeps_it_exactly_symmetric(
    mode: UpdateMode, init: LandmarkInit
) -> None:
    events = loop(steps=300, landmarks=40).run(seed=3).events
    params = FilterParams(update=mode, landmark_init=init)
    records = every_event(replay(events, params))
    checked = [record for record in records if record.covariance is not None]
    assert checked[0] is records[0] and checked[-1] is records[-1]
    steps = [record.step for record in checked]
    assert all(0 <= b - a <= CHECK_EVERY_STEPS for a, b in itertools.pairwise(steps))
    assert len(checked) >= 300 // CHECK_EVERY_STEPS
    for record in checked:
        assert record.covariance is not None
        assert record.covariance.asymmetry == 0.0  # exactly, not to round-off
        assert record.covariance.min_eigenvalue > 0.0
        assert record.warnings == ()


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    landmarks=st.integers(1, 12),
    mode=st.sampled_from(list(UpdateMode)),
    sigma_range=st.floats(1e-4, 1.0),
    compiled=st.booleans(),
)
def test_any_run_keeps_p_symmetric_and_positive_definite(
    seed: int, landmarks: int, mode: UpdateMode, sigma_range: float, compiled: bool
) -> None:
    run = loop(steps=60, landmarks=landmarks).run(seed=seed)
    params = FilterParams(update=mode, sigma_range=sigma_range)
    ekf = EkfSlam(params, compiled=compiled)
    for event in run.events:
        if isinstance(event, Control):
            ekf.predict(event.d, event.alpha)
        else:
            ekf.observe(event.ids, event.z)
        check = check_covariance(ekf.P)
        assert check.asymmetry == 0.0 and check.min_eigenvalue > 0.0, check
