"""The pending low-rank changes of P kept across scans (see ekfviz.filters.ekf).

A large map's sequential update keeps P -= U^T U pending across observation lines,
predicts, new landmarks and removals, and folds it into P only when U is full or a reader
asks for the whole P. Known answer: the same run through a filter that folds every
observation at once (the textbook P -= A^T A, no U at all) gives the same state to
round-off, and every reader (the whole P, the records, the covariance checks, the
association's gating and joint covariance) sees that current P while changes are pending.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from conftest import few_by_default

from ekfviz.association.associator import _joint_covariance, state_rows
from ekfviz.association.gating import predict_landmarks, predict_landmarks_of
from ekfviz.core.params import FilterParams, LandmarkInit
from ekfviz.core.types import FloatArray
from ekfviz.filters.ekf import DEFER_MIN_DIM, DEFER_ROWS, HAVE_KERNEL, EkfSlam
from ekfviz.filters.model_ekf import ModelEkfSlam
from ekfviz.models.ackermann import Ackermann
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.runner.checks import current_covariance

SENSOR = RangeBearing(a=3.78, b=0.5)
_NONE = np.zeros((0, 0))


class EagerModel(ModelEkfSlam):
    """The model filter with every P -= A^T A applied at once (nothing pending): the
    numpy update (the compiled one keeps its changes in U itself)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs, compiled=False)

    def _fold(self, A: FloatArray, U: FloatArray, rank: int) -> int:
        return super()._fold(A, _NONE, 0)


class Eager(EkfSlam):
    """The classic filter with every P -= A^T A applied at once (nothing pending)."""

    def _fold(self, A: FloatArray, U: FloatArray, rank: int) -> int:
        return super()._fold(A, _NONE, 0)


def _current(slam: EkfSlam) -> tuple[FloatArray, FloatArray | None]:
    """P - U^T U from the stored P and the pending factor (not folding anything)."""
    P, U = slam.deferred_covariance()
    return (P if U is None else P - U.T @ U), U


def _close(got: FloatArray, expected: FloatArray, rel: float = 1e-11) -> None:
    scale = max(1.0, float(np.abs(expected).max()))
    np.testing.assert_allclose(got, expected, rtol=0, atol=rel * scale)


def _run(deferred: EkfSlam, eager: EkfSlam, *, drive: bool, seed: int, steps: int = 260) -> int:
    """The same random run through both filters: predicts (or drives), scans of known
    and new landmarks, removals; after every event the current P of the deferred filter
    (read without folding), its records and its gating are compared with the eager
    one's. Returns how many events were compared with changes pending."""
    rng = np.random.default_rng(seed)
    truth: dict[int, FloatArray] = {}
    next_id = 1
    pending = 0
    pose = np.zeros(3)

    def scan(k_new: int, k_known: int) -> None:
        nonlocal next_id
        known = [int(i) for i in deferred.landmark_ids]
        seen = [int(i) for i in rng.choice(known, size=min(k_known, len(known)), replace=False)]
        new = []
        for _ in range(k_new):
            truth[next_id] = pose[:2] + rng.uniform(-25.0, 25.0, 2)
            new.append(next_id)
            next_id += 1
        ids = seen + new
        rng.shuffle(ids)
        z = np.array([SENSOR.measure(pose, truth[i]) for i in ids])
        z += rng.normal(0.0, [0.01, 0.05], size=z.shape)
        got, expected = deferred.observe(ids, z), eager.observe(ids, z)
        _close(got.nis, expected.nis, 1e-9)
        _close(got.S, expected.S)

    scan(DEFER_MIN_DIM // 2 + 4, 0)  # a map past DEFER_MIN_DIM at once
    for step in range(steps):
        roll = rng.uniform()
        if roll < 0.45:
            if drive:
                segments = np.column_stack(
                    [rng.uniform(2.0, 4.0, 5), rng.uniform(-0.2, 0.2, 5), np.full(5, 0.025)]
                )
                deferred.drive(segments)  # type: ignore[attr-defined]
                eager.drive(segments)  # type: ignore[attr-defined]
            else:
                d, alpha = rng.uniform(0.0, 1.0), rng.uniform(-0.2, 0.2)
                deferred.predict(d, alpha)
                eager.predict(d, alpha)
            pose = deferred.x[:3].copy()
        elif roll < 0.92:
            scan(int(rng.integers(0, 3)), int(rng.integers(1, 9)))
        else:
            ids = [int(i) for i in deferred.landmark_ids]
            # never below DEFER_MIN_DIM here; the small-map test crosses it
            room = (deferred.dim - DEFER_MIN_DIM) // 2
            if room > 0:
                doomed = rng.choice(ids, size=min(room, int(rng.integers(1, 4))), replace=False)
                deferred.remove_landmarks([int(i) for i in doomed])
                eager.remove_landmarks([int(i) for i in doomed])
        P, U = _current(deferred)
        pending += U is not None
        _close(deferred.x, eager.x)
        _close(P, eager.P)
        # what the covariance checks read: the same P, exactly symmetric, nothing folded
        checked, _ = current_covariance(deferred)
        _close(checked, P)
        assert np.array_equal(checked, checked.T)
        assert deferred.landmark_ids == eager.landmark_ids
        # the state parts correct their pose block and marginals without folding
        got, expected = deferred.state_parts(), eager.state_parts()
        _close(got.pose_cov, expected.pose_cov)
        _close(got.landmark_covs, expected.landmark_covs)
        assert np.array_equal(got.pose_cov, got.pose_cov.T)
        assert np.array_equal(got.landmark_covs, np.swapaxes(got.landmark_covs, 1, 2))
        assert (deferred.deferred_covariance()[1] is None) == (U is None)  # nothing folded
        if step % 50 == 49:  # the whole P: folded, the same
            _close(deferred.P, eager.P)
            assert deferred.deferred_covariance()[1] is None
            assert np.array_equal(deferred.P, deferred.P.T)
    return pending


@pytest.mark.parametrize("compiled", [False, True] if HAVE_KERNEL else [False])
@pytest.mark.parametrize("init", few_by_default(list(LandmarkInit)))
def test_the_deferred_model_filter_is_the_fold_at_once_one(
    init: LandmarkInit, compiled: bool
) -> None:
    """The model filter's deferred update, numpy's or the kernel's (model_update)."""
    params = FilterParams(landmark_init=init)
    vehicle = Ackermann()
    deferred = ModelEkfSlam(params, vehicle=vehicle, sensor=SENSOR, compiled=compiled)
    eager = EagerModel(params, vehicle=vehicle, sensor=SENSOR)
    pending = _run(deferred, eager, drive=True, seed=3)
    assert pending > 100  # most events are compared with changes pending


@pytest.mark.parametrize("compiled", [False, True] if HAVE_KERNEL else [False])
def test_the_deferred_classic_filter_is_the_fold_at_once_one(compiled: bool) -> None:
    """The classic filter's predict (the compiled kernel's or numpy's) carries the
    pending changes too; the map stays past KERNEL_MAX_DIM's reach here for the kernel's
    update and goes through the numpy one either way."""
    global SENSOR
    saved, SENSOR = SENSOR, RangeBearing()  # the classic filter's sensor at the origin
    try:
        deferred = EkfSlam(compiled=compiled)
        eager = Eager(compiled=compiled)
        pending = _run(deferred, eager, drive=False, seed=5)
    finally:
        SENSOR = saved
    assert pending > 100


def test_a_map_shrunk_below_the_deferred_size_folds_what_is_pending() -> None:
    """Removals that take the map below DEFER_MIN_DIM: the next update folds first."""
    rng = np.random.default_rng(11)
    deferred = ModelEkfSlam(sensor=SENSOR)
    eager = EagerModel(sensor=SENSOR)
    n = DEFER_MIN_DIM // 2 + 2
    xy = rng.uniform(-20.0, 20.0, (n, 2))
    pose = np.zeros(3)
    z = np.array([SENSOR.measure(pose, p) for p in xy])
    for slam in (deferred, eager):
        slam.observe(list(range(1, n + 1)), z)
        slam.observe([1, 2, 3], z[:3] + 0.01)
    assert deferred.deferred_covariance()[1] is not None
    for slam in (deferred, eager):
        slam.remove_landmarks(list(range(4, 20)))
        slam.observe([1, 2, 3], z[:3] - 0.01)
    assert deferred.dim < DEFER_MIN_DIM
    assert deferred.deferred_covariance()[1] is None
    _close(deferred.P, eager.P)
    _close(deferred.x, eager.x)


def test_the_gating_and_joint_covariance_read_the_current_p() -> None:
    """The gating's reads (the pose's rows, the marginals) and the joint covariance of
    JCBB from the stored P and the pending factor: those of the current P."""
    rng = np.random.default_rng(2)
    slam = ModelEkfSlam(sensor=SENSOR)
    n = DEFER_MIN_DIM
    xy = rng.uniform(-20.0, 20.0, (n, 2))
    z = np.array([SENSOR.measure(np.zeros(3), p) for p in xy])
    slam.observe(list(range(1, n + 1)), z)
    for _ in range(3):
        seen = [int(i) for i in rng.choice(n, 6, replace=False) + 1]
        slam.observe(seen, z[np.array(seen) - 1] + rng.normal(0.0, 0.02, (6, 2)))
    P_s, U = slam.deferred_covariance()
    assert U is not None and 0 < U.shape[0] < DEFER_ROWS
    P = P_s - U.T @ U
    R = FilterParams().R
    x = np.array(slam.x)
    covs = slam.landmark_marginals()
    pose_rows = slam.pose_rows()
    _close(covs, np.array([P[j : j + 2, j : j + 2] for j in range(3, slam.dim, 2)]), 1e-12)
    _close(pose_rows, P[:3], 1e-12)
    assert np.array_equal(pose_rows[:, :3], pose_rows[:, :3].T)
    got = predict_landmarks_of(
        x, pose_rows, covs[:, (0, 1), (0, 1)].ravel(), covs[:, 0, 1], SENSOR, R
    )
    expected = predict_landmarks(x, P, SENSOR, R)
    _close(got.S, expected.S, 1e-12)
    assert not np.allclose(predict_landmarks(x, P_s, SENSOR, R).S, expected.S)  # U matters
    rows = np.array([0, 5, 9])
    H = expected.H(rows)
    _close(
        _joint_covariance(P_s, H, state_rows(rows), U),
        _joint_covariance(P, H, state_rows(rows)),
        1e-12,
    )
    # the whole-P readers fold first: the same current P
    full = slam.state_parts(full_cov=True).full_cov
    assert full is not None
    _close(full, P, 1e-12)
    assert slam.deferred_covariance()[1] is None
    _close(slam.buffers[1][: slam.dim, : slam.dim], P, 1e-12)
    assert math.isfinite(float(np.linalg.eigvalsh(slam.P)[0]))


@pytest.mark.parametrize(
    "doomed", [[1], [12], [1, 2], [3, 7, 8, 12], list(range(2, 12)), list(range(1, 13))]
)
def test_removal_keeps_the_principal_submatrix(doomed: list[int]) -> None:
    """Removal moves the kept rows and columns in runs: the principal submatrix of the
    kept ones (first, last, adjacent and all landmarks removed), zeros past the state."""
    rng = np.random.default_rng(len(doomed))
    n_landmarks = 12
    n = 3 + 2 * n_landmarks
    A = rng.normal(size=(n, n))
    P = A @ A.T
    x = rng.normal(size=n)
    ids = list(range(1, n_landmarks + 1))
    slam = EkfSlam.from_state(FilterParams(), x, P, ids)
    slam._reserve(4)  # spare rows and columns past the state, to be left zero
    slam.remove_landmarks(doomed)
    keep = [0, 1, 2] + [3 + 2 * (i - 1) + k for i in ids if i not in doomed for k in (0, 1)]
    assert np.array_equal(slam.P, P[np.ix_(keep, keep)])
    assert np.array_equal(slam.x, x[keep])
    assert slam.landmark_ids == [i for i in ids if i not in doomed]
    x_buffer, P_buffer = slam.buffers
    assert not P_buffer[slam.dim :].any() and not P_buffer[:, slam.dim :].any()
    assert not x_buffer[slam.dim :].any()


@pytest.mark.skipif(not HAVE_KERNEL, reason="the compiled kernel was not built")
@pytest.mark.parametrize("wide", [True, False])
def test_the_compiled_model_update_skips_and_folds_as_the_numpy_one(wide: bool) -> None:
    """_kernel.model_update against ModelEkfSlam's numpy loop on lines of a large map:
    a line longer than U's room (U fills up and is folded mid-line), a landmark predicted
    at the sensor (skipped at zero range) and one whose S is not positive definite
    (skipped): the same table, skipped flags and warnings in file order, and the same
    state to round-off."""
    rng = np.random.default_rng(21)
    n_landmarks = DEFER_ROWS  # more landmarks than U has room for in one line
    n = 3 + 2 * n_landmarks
    x = np.zeros(n)
    x[:3] = (1.0, -2.0, 0.4)
    x[3:] = rng.uniform(-30.0, 30.0, n - 3)
    A = rng.normal(size=(n, n)) * 0.05
    P = A @ A.T + 0.05 * np.eye(n)
    sensor_x, sensor_y, _, _ = SENSOR.sensor(x[:3])
    x[3 + 2 * 5 : 5 + 2 * 5] = (sensor_x, sensor_y)  # landmark 6: at the sensor itself
    P[3 + 2 * 9 : 5 + 2 * 9, :] = P[:, 3 + 2 * 9 : 5 + 2 * 9] = 0.0
    P[3 + 2 * 9 : 5 + 2 * 9, 3 + 2 * 9 : 5 + 2 * 9] = -50.0 * np.eye(2)  # landmark 10: S < 0
    ids = list(range(1, n_landmarks + 1))
    params = FilterParams(sigma_bearing=0.01, sigma_range=0.1)
    filters = []
    for compiled in (True, False):
        slam = ModelEkfSlam.from_state(params, x, P, ids)
        assert isinstance(slam, ModelEkfSlam)
        slam.sensor = SENSOR
        slam._model_kernel = compiled  # from_state's own flag is the classic kernel's
        slam._kernel_wide = wide  # AVX2 and FMA where the CPU has them, or the plain loops
        filters.append(slam)
    for line in range(3):
        order = [int(i) for i in rng.permutation(ids)]
        if line == 0:  # landmark 6 first, while the sensor is where it lies
            order.remove(6)
            order.insert(0, 6)
        pose = filters[1].x[:3]
        z = np.array([SENSOR.measure(pose, filters[1].x[1 + 2 * i : 3 + 2 * i]) for i in order])
        z[:, 1] += rng.normal(0.0, 0.05, len(order))
        got, expected = filters[0].observe(order, z), filters[1].observe(order, z)
        assert filters[0].warnings == filters[1].warnings
        assert np.array_equal(got.skipped, expected.skipped)
        if line == 0:
            assert [w.split(":")[0] for w in filters[0].warnings] == [
                "landmark 6",
                "landmark 10",
            ]
            assert "predicted 0 m from the robot" in filters[0].warnings[0]
        for name in ("z_pred", "innovation", "S", "nis"):
            a, b = getattr(got, name), getattr(expected, name)
            assert np.array_equal(np.isnan(a), np.isnan(b)), name
            _close(np.nan_to_num(a), np.nan_to_num(b), 1e-9)
        _close(filters[0].x, filters[1].x)
        _close(_current(filters[0])[0], _current(filters[1])[0])
