"""Laws of the filter: agreement with a dense textbook EKF, symmetry, recovery, growth."""

from __future__ import annotations

import itertools
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from ekfviz.core.params import FilterParams, LandmarkInit, UpdateMode
from ekfviz.core.records import Control, EventKind, EventRecord, Sighting
from ekfviz.filters.ekf import HAVE_KERNEL, KERNEL_MAX_DIM, EkfSlam
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import measure, measurement_jacobians
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import classic
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, Noise, classic_controls, simulate

sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))
from textbook_ekf import TextbookEkfSlam


def run_textbook(events: tuple[Control | Sighting, ...], params: FilterParams) -> TextbookEkfSlam:
    first = events[0]
    assert isinstance(first, Sighting)
    ekf = TextbookEkfSlam(
        len(first.ids),
        params.Q,
        params.R,
        params.init_pose_sigma,
        correlated_init=params.landmark_init is LandmarkInit.CORRELATED,
    )
    ekf.run(events)
    return ekf


def final_state(
    events: tuple[Control | Sighting, ...], params: FilterParams, *, compiled: bool = True
) -> EkfSlam:
    ekf = EkfSlam(params, compiled=compiled)
    first = events[0]
    assert isinstance(first, Sighting)
    ekf.observe(first.ids, first.z)
    for event in events[1:]:
        if isinstance(event, Control):
            ekf.predict(event.d, event.alpha)
        else:
            ekf.observe(event.ids, event.z)
    return ekf


@pytest.mark.parametrize("landmark_init", list(LandmarkInit))
@pytest.mark.parametrize("seed", [1, 4, 9])
def test_sparse_filter_equals_dense_textbook_filter(
    landmark_init: LandmarkInit, seed: int, compiled: bool
) -> None:
    params = FilterParams(landmark_init=landmark_init)
    events = classic().run(seed=seed).events
    ours = final_state(events, params, compiled=compiled)
    theirs = run_textbook(events, params)
    np.testing.assert_allclose(ours.x, theirs.x, atol=1e-9)
    np.testing.assert_allclose(ours.P, theirs.P, atol=1e-9)


def partially_seen(n_landmarks: int, seen: int, steps: int, seed: int) -> list[Control | Sighting]:
    """Landmarks scattered around a circling robot; all seen first, then ``seen`` of them
    per line in a random order."""
    rng = np.random.default_rng(seed)
    landmarks_xy = rng.uniform(-15.0, 15.0, size=(n_landmarks, 2))
    controls = np.tile([[1.0, 0.2]], (steps, 1))
    run = simulate(controls, landmarks_xy, Noise(), seed=seed)
    events: list[Control | Sighting] = [run.events[0]]
    for event in run.events[1:]:
        if isinstance(event, Sighting):
            pick = rng.choice(n_landmarks, size=seen, replace=False)
            events.append(Sighting(event.line, event.ids[pick], event.z[pick]))
        else:
            events.append(event)
    return events


@pytest.mark.parametrize(
    ("n_landmarks", "seen"),
    # 30: the kernel (dim 63) or numpy's per-landmark update; 40: the deferred update,
    # flushed mid-line when all are seen
    [(6, 3), (30, 30), (40, 7), (40, 40)],
)
def test_sparse_filter_equals_dense_filter_with_partial_observations(
    n_landmarks: int, seen: int, compiled: bool
) -> None:
    events = tuple(partially_seen(n_landmarks, seen, steps=12, seed=n_landmarks + seen))
    params = FilterParams()
    ours = final_state(events, params, compiled=compiled)
    theirs = run_textbook(events, params)
    np.testing.assert_allclose(ours.x, theirs.x, atol=1e-9)
    np.testing.assert_allclose(ours.P, theirs.P, atol=1e-9)
    assert np.array_equal(ours.P, ours.P.T)


def test_known_answer_on_bundled_sample() -> None:
    """Pinned values of the bundled sample (seed 2), guarding against silent changes."""
    last = every_event(replay(classic().run(seed=2).events))[-1]
    np.testing.assert_allclose(last.pose, [4.10656991, -3.85389548, -1.13451898], atol=1e-6)
    np.testing.assert_allclose(last.landmarks_xy[0], [2.7044278, 6.15974949], atol=1e-6)
    assert last.step == 29 and last.event == 58


def test_covariance_stays_exactly_symmetric_and_psd_over_a_long_run() -> None:
    controls = np.tile(classic_controls(), (20, 1))  # 580 controls
    events = simulate(controls, CLASSIC_LANDMARKS_XY, Noise(), seed=3).events
    for update, compiled in itertools.product(UpdateMode, (True, False)):
        ekf = final_state(events, FilterParams(update=update), compiled=compiled)
        P = np.array(ekf.P)
        assert np.array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > -1e-12


def test_noise_free_run_recovers_the_true_landmarks() -> None:
    run = simulate(classic_controls(), CLASSIC_LANDMARKS_XY, Noise.none(), seed=0)
    for update in UpdateMode:
        last = every_event(replay(run.events, FilterParams(update=update)))[-1]
        np.testing.assert_allclose(last.landmarks_xy, CLASSIC_LANDMARKS_XY, atol=1e-9)
        np.testing.assert_allclose(last.pose, run.poses_xytheta[-1], atol=1e-9)


@pytest.mark.parametrize("n_landmarks", [6, 40])  # 40: P -= A^T A by strips
def test_joint_update_equals_the_dense_stacked_update(n_landmarks: int) -> None:
    events = partially_seen(n_landmarks, 6, steps=2, seed=2) if n_landmarks > 6 else None
    events = list(classic().run(seed=2).events) if events is None else events
    ekf = final_state(tuple(events[:2]), FilterParams(update=UpdateMode.JOINT))
    x, P = np.array(ekf.x), np.array(ekf.P)
    sighting = events[2]
    assert isinstance(sighting, Sighting)
    H = np.zeros((12, len(x)))
    nu = np.zeros(12)
    for i, landmark_id in enumerate(sighting.ids.tolist()):
        j = 1 + 2 * landmark_id  # ids 1..N in state order
        z_pred = measure(x[:3], x[j : j + 2])
        z_D_pose, z_D_landmark = measurement_jacobians(x[:3], x[j : j + 2])
        H[2 * i : 2 * i + 2, :3], H[2 * i : 2 * i + 2, j : j + 2] = z_D_pose, z_D_landmark
        nu[2 * i : 2 * i + 2] = [
            wrap_angle(sighting.z[i, 0] - z_pred[0]),
            sighting.z[i, 1] - z_pred[1],
        ]
    S = H @ P @ H.T + np.kron(np.eye(6), ekf.params.R)
    K = P @ H.T @ np.linalg.inv(S)
    ekf.observe(sighting.ids, sighting.z)
    np.testing.assert_allclose(ekf.x, x + K @ nu, atol=1e-12)
    np.testing.assert_allclose(ekf.P, (np.eye(len(x)) - K @ H) @ P, atol=1e-12)
    assert np.array_equal(ekf.P, ekf.P.T)


def test_joint_and_sequential_updates_differ_only_by_linearisation() -> None:
    # a tenth of the classic noise: the innovations, and so the linearisation
    # differences between folding landmarks one by one or all at once, stay small
    quiet = Noise(0.025, 0.01, 0.01, 0.001, 0.008)
    events = classic().run(quiet, seed=2, init_pose_sigma=(0.0, 0.0, 0.0)).events[:3]
    sequential = final_state(events, FilterParams(update=UpdateMode.SEQUENTIAL))
    joint = final_state(events, FilterParams(update=UpdateMode.JOINT))
    np.testing.assert_allclose(joint.x, sequential.x, atol=0.01)
    assert not np.allclose(joint.x, sequential.x, atol=1e-9)


def test_predict_changes_only_the_robot_rows_and_columns() -> None:
    ekf = final_state(classic().run(seed=2).events[:3], FilterParams())
    before = np.array(ekf.P)
    ekf.predict(2.0, 0.3)
    after = np.array(ekf.P)
    np.testing.assert_array_equal(after[3:, 3:], before[3:, 3:])
    assert not np.allclose(after[:3, :], before[:3, :])


def test_correlated_init_has_cross_covariances_independent_has_none() -> None:
    first = classic().run(seed=2).events[0]
    assert isinstance(first, Sighting)
    for landmark_init in LandmarkInit:
        ekf = EkfSlam(FilterParams(landmark_init=landmark_init))
        ekf.observe(first.ids, first.z)
        cross = np.array(ekf.P)[:3, 3:]
        if landmark_init is LandmarkInit.CORRELATED:
            # every landmark is tied to the pose it was measured from, and so to the others
            blocks = np.abs(cross).reshape(3, 6, 2).sum(axis=(0, 2))
            assert (blocks > 1e-4).all()
            assert abs(ekf.P[3, 5]) > 1e-4
        else:
            assert not cross.any()


def test_state_grows_when_landmarks_are_first_seen_mid_run() -> None:
    """Landmarks arrive in three batches; the result equals seeing them all at once."""
    run = simulate(classic_controls()[:6], CLASSIC_LANDMARKS_XY, Noise.none(), seed=0)
    events: list[Control | Sighting] = []
    for event in run.events:
        if isinstance(event, Sighting):
            seen = min(6, 2 + 2 * sum(isinstance(e, Sighting) for e in events))
            events.append(Sighting(event.line, event.ids[:seen][::-1], event.z[:seen][::-1]))
        else:
            events.append(event)
    records = every_event(replay(events))
    assert [r.n_landmarks for r in records if r.kind is not EventKind.PREDICT] == [
        2,
        4,
        6,
        6,
        6,
        6,
        6,
    ]
    update = records[2]
    assert update.observations is not None
    np.testing.assert_array_equal(update.observations.initialised, [True, True, False, False])
    assert np.isnan(update.observations.nis[:2]).all() and (update.observations.nis[2:] >= 0).all()
    np.testing.assert_allclose(
        records[-1].landmarks_xy[np.argsort(records[-1].landmark_ids)],
        CLASSIC_LANDMARKS_XY,
        atol=1e-9,
    )


def test_steps_and_events_do_not_rely_on_alternation() -> None:
    run = classic().run(seed=2)
    c1, s1 = run.events[1], run.events[2]
    events = [run.events[0], c1, c1, s1, s1, c1, s1]
    records = every_event(replay(events))
    assert [(r.event, r.step, r.kind.value) for r in records] == [
        (0, 0, "init"),
        (1, 1, "predict"),
        (2, 2, "predict"),
        (3, 2, "update"),
        (4, 3, "update"),
        (5, 4, "predict"),
        (6, 4, "update"),
    ]


def test_a_log_that_starts_with_a_control_starts_from_the_prior() -> None:
    run = classic().run(seed=2)
    records = every_event(replay(run.events[1:3]))
    assert records[0].kind is EventKind.INIT and records[0].n_landmarks == 0
    assert records[1].kind is EventKind.PREDICT and records[2].n_landmarks == 6


def test_records_are_immutable_and_hold_no_full_covariance_by_default() -> None:
    records = every_event(replay(classic().run(seed=2).events[:3]))
    record: EventRecord = records[-1]
    assert record.full_cov is None
    with pytest.raises(ValueError):
        record.pose[0] = 1.0
    full = every_event(replay(classic().run(seed=2).events[:3], full_cov=True))[-1]
    assert full.full_cov is not None and full.full_cov.shape == (15, 15)
    np.testing.assert_array_equal(full.full_cov[:3, :3], record.pose_cov)
    np.testing.assert_array_equal(full.full_cov[5:7, 5:7], record.landmark_covs[1])


def test_update_records_carry_predictions_innovations_and_nis() -> None:
    records = every_event(replay(classic().run(seed=2).events[:3]))
    obs = records[2].observations
    assert obs is not None and len(obs.ids) == 6 and not obs.initialised.any()
    np.testing.assert_allclose(obs.innovation[:, 1], obs.z[:, 1] - obs.z_pred[:, 1])
    manual = [nu @ np.linalg.solve(S, nu) for nu, S in zip(obs.innovation, obs.S, strict=True)]
    np.testing.assert_allclose(obs.nis, manual, rtol=1e-9)


# -- the compiled kernel of small maps ---------------------------------------------------


def test_the_kernel_is_built_wherever_a_c_compiler_is() -> None:
    """`pip install` builds it when it can; elsewhere the numpy code stands in."""
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler here: the numpy code stands in for the kernel")
    assert HAVE_KERNEL and EkfSlam()._compiled
    assert not EkfSlam(compiled=False)._compiled


@pytest.mark.parametrize(("n_landmarks", "seen", "mode"), [
    (6, 6, UpdateMode.SEQUENTIAL), (40, 12, UpdateMode.SEQUENTIAL), (6, 6, UpdateMode.JOINT),
])  # fmt: skip
def test_the_filter_is_its_named_operations_in_the_textbook_form(
    n_landmarks: int, seen: int, mode: UpdateMode
) -> None:
    """The built-in filter (its factored update, the pending low-rank changes of a large
    map, the compiled kernel of a small one) against the named operations of
    ekfviz.models composed as the textbook writes them (check's dense re-run: K = P H^T
    S^-1, P - K S K^T), each event from the filter's own state before it."""
    from ekfviz.check.rerun import Form, Rerun, State, Step
    from ekfviz.check.rerun import Noise as RunNoise

    params = FilterParams(update=mode)
    ekf = EkfSlam(params)
    textbook = Rerun(RunNoise(params.Q, params.R), form=Form(joint=mode is UpdateMode.JOINT))
    for event in partially_seen(n_landmarks, seen, steps=30, seed=3):
        before = State(ekf.x.copy(), ekf.P.copy(), np.array(ekf.landmark_ids))
        if isinstance(event, Control):
            ekf.predict(event.d, event.alpha)
            step = Step(d=event.d, alpha=event.alpha)
        else:
            ekf.observe(event.ids, event.z)
            step = Step(ids=np.asarray(event.ids), z=np.asarray(event.z).reshape(-1, 2))
        expected = textbook.run(before, step)
        x, P = State(ekf.x.copy(), ekf.P.copy(), np.array(ekf.landmark_ids)).in_order_of(
            expected.ids
        )
        np.testing.assert_allclose(x, expected.x, rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(P, expected.P, rtol=1e-9, atol=1e-11)


@pytest.mark.skipif(not HAVE_KERNEL, reason="the compiled kernel was not built")
@pytest.mark.parametrize(("n_landmarks", "seen"), [(6, 6), (30, 9)])
def test_kernel_and_numpy_code_give_the_same_records(n_landmarks: int, seen: int) -> None:
    """Line for line, to round-off: the state, P and every observation's figures."""
    events = partially_seen(n_landmarks, seen, steps=40, seed=7)
    kernel, numpy_code = EkfSlam(compiled=True), EkfSlam(compiled=False)
    for event in events:
        if isinstance(event, Control):
            kernel.predict(event.d, event.alpha)
            numpy_code.predict(event.d, event.alpha)
            np.testing.assert_allclose(kernel.P, numpy_code.P, rtol=1e-11, atol=1e-13)
            continue
        ours, theirs = kernel.observe(event.ids, event.z), numpy_code.observe(event.ids, event.z)
        for name in ("z_pred", "innovation", "S", "nis"):
            np.testing.assert_allclose(
                getattr(ours, name), getattr(theirs, name), rtol=1e-10, atol=1e-12, err_msg=name
            )
        assert ours.skipped.tolist() == theirs.skipped.tolist()
        assert np.array_equal(kernel.P, kernel.P.T)
    assert kernel.dim == 3 + 2 * n_landmarks < KERNEL_MAX_DIM
    np.testing.assert_allclose(kernel.x, numpy_code.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(kernel.P, numpy_code.P, rtol=0, atol=1e-12)


@pytest.mark.skipif(not HAVE_KERNEL, reason="the compiled kernel was not built")
def test_kernel_refuses_buffers_of_the_wrong_kind() -> None:
    """A wrong buffer is a ValueError, never a write outside it."""
    from ekfviz.filters import _kernel

    x, P = np.zeros(5), np.eye(5)
    with pytest.raises(ValueError, match="float64"):
        _kernel.predict(x.astype(np.float32), P, 5, 1.0, 0.0, 0.1, 0.1, 0.1)
    with pytest.raises(ValueError, match="P"):
        _kernel.predict(x, np.eye(4), 5, 1.0, 0.0, 0.1, 0.1, 0.1)
    with pytest.raises(ValueError, match="x"):
        _kernel.predict(x, P, 6, 1.0, 0.0, 0.1, 0.1, 0.1)
    slots, table, status = np.array([3]), np.zeros((1, 9)), np.zeros(1, dtype=np.int8)
    with pytest.raises(ValueError, match="z"):
        _kernel.update_sequential(x, P, 5, slots, np.zeros(1), table, status, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="int64"):
        _kernel.update_sequential(
            x,
            P,
            5,
            slots.astype(np.int32),
            np.zeros(2),
            table,
            status,
            1.0,
            1.0,
            0.0,
        )
    assert not x.any()
