"""Association, its models and the Victoria Park reader, on generated data."""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.association import AssociationParams, Associator, Method
from ekfviz.cli import app
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Drive, Fate, Scan
from ekfviz.core.types import FloatArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.io.victoria import read_victoria
from ekfviz.models.ackermann import Ackermann
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import Scenario, loop
from ekfviz.sim.simulate import Detection

runner = CliRunner()


def numeric_jacobian(
    f: Callable[[FloatArray], FloatArray], x: FloatArray | list[float], eps: float = 1e-6
) -> FloatArray:
    x = np.asarray(x, dtype=float)
    columns = []
    for k in range(len(x)):
        step = np.zeros_like(x)
        step[k] = eps
        diff = f(x + step) - f(x - step)
        diff[0] = math.remainder(diff[0], 2 * math.pi) if len(diff) == 2 else diff[0]
        columns.append(diff / (2 * eps))
    return np.stack(columns, axis=1)


def test_ackermann_jacobians_match_finite_differences() -> None:
    car = Ackermann()
    pose, speed, steering, dt = np.array([1.0, -2.0, 0.7]), 3.0, 0.2, 0.025
    G, W = car.jacobians(pose, speed, steering, dt)
    assert np.allclose(
        G, numeric_jacobian(lambda p: car.motion(p, speed, steering, dt), pose), atol=1e-7
    )
    W_fd = numeric_jacobian(lambda u: car.motion(pose, u[0], u[1], dt), [speed, steering])
    assert np.allclose(W, W_fd, atol=1e-7)


def test_model_drive_equals_a_dense_predict_per_span() -> None:
    """drive() (floats per span, the map's rows once) against P' = F P F^T + F W Q W^T F^T
    with the whole F of each span, on a state with landmarks."""
    from ekfviz.filters.model_ekf import ModelEkfSlam

    car = Ackermann()
    ekf = ModelEkfSlam(vehicle=car, sensor=RangeBearing(3.78, 0.5))
    ekf.observe([1, 2, 3], np.array([[0.3, 12.0], [-0.2, 9.0], [1.0, 20.0]]))
    x, P = ekf.x.copy(), ekf.P.copy()
    spans = np.array([[3.0, 0.2, 0.05], [2.5, -0.1, 0.0], [2.0, 0.3, 0.08], [4.0, 0.0, 0.1]])
    ekf.drive(spans)
    for speed, steering, dt in spans.tolist():
        if dt <= 0.0:
            continue
        G, W = car.jacobians(x[:3], speed, steering, dt)
        F = np.eye(len(x))
        F[:3, :3] = G
        x[:3] = car.motion(x[:3], speed, steering, dt)
        P = F @ P @ F.T
        P[:3, :3] += W @ car.Q @ W.T
    assert np.allclose(ekf.x, x, rtol=0.0, atol=1e-12)
    assert np.allclose(ekf.P, P, rtol=1e-12, atol=1e-12)
    assert np.array_equal(ekf.P, ekf.P.T)


@pytest.mark.parametrize("seed", range(4))
def test_compiled_drive_is_the_python_one(seed: int) -> None:
    """The kernel's ackermann_drive against drive()'s loop of the named operations in
    Python: the same state and covariance to round-off, over spans of every kind (turning
    both ways, standing still, dt of zero)."""
    from ekfviz.filters.ekf import HAVE_KERNEL
    from ekfviz.filters.model_ekf import ModelEkfSlam

    if not HAVE_KERNEL:
        pytest.skip("the compiled kernel was not built")
    rng = np.random.default_rng(seed)
    car = Ackermann(sigma_speed=0.5, sigma_steering=0.03)
    filters = [
        ModelEkfSlam(vehicle=car, sensor=RangeBearing(3.78, 0.5), compiled=compiled)
        for compiled in (True, False)
    ]
    z = np.column_stack([rng.uniform(-1.5, 1.5, 6), rng.uniform(3.0, 30.0, 6)])
    for ekf in filters:
        ekf.observe([1, 2, 3, 4, 5, 6], z)
    for _ in range(50):
        k = int(rng.integers(1, 12))
        spans = np.column_stack(
            [rng.uniform(-1.0, 6.0, k), rng.uniform(-0.5, 0.5, k), rng.uniform(-0.01, 0.1, k)]
        )
        spans[rng.random(k) < 0.2, 0] = 0.0
        for ekf in filters:
            ekf.drive(spans)
        assert np.allclose(filters[0].x, filters[1].x, rtol=1e-13, atol=1e-13)
        assert np.allclose(filters[0].P, filters[1].P, rtol=1e-12, atol=1e-14)
        assert np.array_equal(filters[0].P, filters[0].P.T)


def test_predicted_innovation_covariances_equal_dense_h_p_h_t() -> None:
    """predict_landmarks' S (written out entry by entry) against H P H^T + R with each
    landmark's dense H, on a random covariance."""
    from ekfviz.association.gating import predict_landmarks

    rng = np.random.default_rng(7)
    sensor, R = RangeBearing(3.78, 0.5), np.array([[0.01, 0.002], [0.002, 0.25]])
    n = 3 + 2 * 6
    x = rng.normal(size=n) * 20.0
    A = rng.normal(size=(n, n))
    P = A @ A.T / n
    predictions = predict_landmarks(x, P, sensor, R)
    for i in range(6):
        j = 3 + 2 * i
        z_D_pose, z_D_landmark = sensor.jacobians(x[:3], x[j : j + 2])
        H = np.zeros((2, n))
        H[:, :3], H[:, j : j + 2] = z_D_pose, z_D_landmark
        assert np.allclose(predictions.S[i], H @ P @ H.T + R, rtol=1e-12, atol=1e-14)
        assert np.allclose(predictions.z_pred[i], sensor.measure(x[:3], x[j : j + 2]))
        H_i = predictions.H(np.array([i]))[0]
        assert np.array_equal(H_i, np.concatenate([z_D_pose, z_D_landmark], axis=1))
    assert np.array_equal(predictions.S, predictions.S.transpose(0, 2, 1))


def test_offset_measurement_jacobians_match_finite_differences() -> None:
    sensor = RangeBearing(3.78, 0.5)
    pose, landmark = np.array([1.0, 2.0, 0.4]), np.array([12.0, 9.0])
    z_D_pose, z_D_landmark = sensor.jacobians(pose, landmark)
    assert np.allclose(
        z_D_pose, numeric_jacobian(lambda p: sensor.measure(p, landmark), pose), atol=1e-6
    )
    assert np.allclose(
        z_D_landmark, numeric_jacobian(lambda lm: sensor.measure(pose, lm), landmark), atol=1e-6
    )
    z = sensor.measure(pose, landmark)
    assert np.allclose(sensor.inverse(pose, z), landmark)
    l_D_pose, l_D_z = sensor.inverse_jacobians(pose, z)
    assert np.allclose(l_D_pose, numeric_jacobian(lambda p: sensor.inverse(p, z), pose), atol=1e-6)
    assert np.allclose(l_D_z, numeric_jacobian(lambda q: sensor.inverse(pose, q), z), atol=1e-6)


def test_records_report_the_laser_point_with_its_covariance() -> None:
    """Victoria Park's records report the laser's pose (where the GPS antenna is): the
    point R(theta) (a, b) off the state's origin, its covariance through the point's
    Jacobian (checked against finite differences), the state itself untouched."""
    from ekfviz.filters.model_ekf import ModelEkfSlam

    sensor = RangeBearing(3.78, 0.5)
    filters = [
        ModelEkfSlam(vehicle=Ackermann(), sensor=sensor, reported_point=point)
        for point in ((0.0, 0.0), (sensor.a, sensor.b))
    ]
    for ekf in filters:
        ekf.observe([1, 2], np.array([[0.3, 12.0], [-0.2, 9.0]]))
        ekf.drive(np.array([[3.0, 0.2, 0.5], [3.0, 0.1, 0.5]]))
        ekf.observe([1, 2], np.array([[0.4, 11.0], [-0.3, 7.5]]))
    origin, laser = (f.state_parts(full_cov=True) for f in filters)
    assert np.array_equal(filters[0].x, filters[1].x) and np.array_equal(filters[0].P, filters[1].P)

    def point(pose: FloatArray) -> FloatArray:
        x, y, theta = pose
        c, s = math.cos(theta), math.sin(theta)
        return np.array([x + sensor.a * c - sensor.b * s, y + sensor.a * s + sensor.b * c, theta])

    assert np.allclose(laser.pose, point(origin.pose))
    J = numeric_jacobian(point, origin.pose)
    assert np.allclose(laser.pose_cov, J @ origin.pose_cov @ J.T, atol=1e-12)
    assert laser.full_cov is not None and origin.full_cov is not None
    assert np.allclose(laser.full_cov[:3, :3], laser.pose_cov)
    assert np.allclose(laser.full_cov[:3, 3:], J @ origin.full_cov[:3, 3:])
    assert np.array_equal(laser.full_cov[3:, 3:], origin.full_cov[3:, 3:])
    assert np.array_equal(laser.landmarks_xy, origin.landmarks_xy)


def test_remove_landmarks_keeps_the_rest_and_p_symmetric_psd() -> None:
    ekf = EkfSlam()
    ekf.observe([1, 2, 3], np.array([[0.1, 5.0], [0.5, 7.0], [-0.4, 6.0]]))
    ekf.predict(1.0, 0.1)
    ekf.observe([1, 2, 3], np.array([[0.0, 4.1], [0.4, 6.2], [-0.5, 5.2]]))
    x, P = ekf.x.copy(), ekf.P.copy()
    ekf.remove_landmarks([2])
    keep = [0, 1, 2, 3, 4, 7, 8]
    assert ekf.landmark_ids == [1, 3]
    assert np.array_equal(ekf.x, x[keep])
    assert np.array_equal(ekf.P, P[np.ix_(keep, keep)])
    assert np.array_equal(ekf.P, ekf.P.T)
    assert np.linalg.eigvalsh(ekf.P).min() > -1e-12


def matched(world: Scenario) -> FilterParams:
    """The filter told the world's true noise and prior."""
    noise = world.noise
    return FilterParams(
        sigma_x=noise.sigma_x, sigma_y=noise.sigma_y, sigma_alpha=noise.sigma_alpha,
        sigma_bearing=noise.sigma_bearing, sigma_range=noise.sigma_range,
        init_pose_sigma=world.init_pose_sigma,
    )  # fmt: skip


def _loop_events(detection: Detection):  # type: ignore[no-untyped-def]
    world = loop(steps=200, landmarks=60, seed=4)
    return world, world.run(seed=4, detection=detection)


def test_association_without_clutter_equals_known() -> None:
    world, known = _loop_events(Detection())
    _, unknown = _loop_events(Detection(unknown_ids=True))
    params = matched(world)
    associator = Associator(
        # every landmark paired on its own too, however wide its gate (as known ids are)
        AssociationParams(gate_probability=0.999999, confirm=1, single_gate_area=math.inf),
        RangeBearing(),
        params.R,
    )
    a = every_event(replay(known.events, params))
    assert unknown.scan_events is not None
    b = every_event(replay(unknown.scan_events, params, associator=associator))
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        assert np.array_equal(ra.pose, rb.pose)
        assert np.array_equal(ra.landmarks_xy, rb.landmarks_xy)


def test_tentative_landmarks_are_removed_unless_confirmed() -> None:
    params = FilterParams()
    associator = Associator(
        AssociationParams(confirm=2, confirm_window=2), RangeBearing(), params.R
    )
    events = [
        Scan(line=1, z=np.array([[0.0, 5.0]])),
        Scan(line=2, z=np.array([[0.0, 5.0], [1.0, 8.0]])),  # 1 confirmed, 2 new
        Scan(line=3, z=np.array([[0.0, 5.0]])),  # 2 not seen again in its window: removed
    ]
    records = every_event(replay(events, params, associator=associator))
    assert records[1].association is not None
    assert records[1].association.confirmed.tolist() == [1]
    assert records[2].association is not None
    assert records[2].association.removed.tolist() == [2]
    assert records[-1].landmark_ids.tolist() == [1]


def _victoria(tmp_path: Path, measurements: str) -> Path:
    (tmp_path / "inputs.dat").write_text("0.0 2.0 0.0\n0.5 2.0 0.1\n1.2 2.0 0.1\n")
    (tmp_path / "measurements.dat").write_text(measurements)
    (tmp_path / "gps.dat").write_text("0.0 0.0 0.0\n1.0 2.0 0.0\n")
    return tmp_path


def test_victoria_reader_streams_drives_and_scans(tmp_path: Path) -> None:
    path = _victoria(tmp_path, "1.0 10.0 1.5707963 0.3\n1.0 12.0 1.0 0.4\n")
    events = list(read_victoria(path))
    assert isinstance(events[0], Drive) and isinstance(events[1], Scan)
    assert np.allclose(events[0].segments, [[2.0, 0.0, 0.5], [2.0, 0.1, 0.5]])
    assert np.allclose(events[1].z, [[0.0, 10.0], [1.0 - math.pi / 2, 12.0]], atol=1e-6)
    assert isinstance(events[2], Drive)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1.0 10.0 1.5\n", "measurements.dat:1: found 3 numbers, expected 4"),
        ("1.0 -1.0 1.5 0.2\n", "measurements.dat:1: found range -1"),
        ("1.0 5.0 4.0 0.2\n", "measurements.dat:1: found bearing 4"),
        ("2.0 5.0 1.0 0.2\n1.0 5.0 1.0 0.2\n", "measurements.dat:2: found time 1"),
    ],
)
def test_victoria_reader_refuses_malformed_lines(tmp_path: Path, text: str, message: str) -> None:
    path = _victoria(tmp_path, text)
    with pytest.raises(InputError, match=message.replace(".", r"\.")):
        list(read_victoria(path))


@pytest.mark.parametrize(
    "fault", ["range", *(pytest.param(f, marks=pytest.mark.slow) for f in (None, "time"))]
)
def test_victoria_scans_span_blocks_and_a_late_fault_keeps_the_scans_before(
    tmp_path: Path, fault: str | None
) -> None:
    """Measurements over several of the reader's blocks (it converts a block at once):
    every scan comes out whole, in order, even one whose lines straddle two blocks; a bad
    line far into the file ends the stream with its line named, after every scan that
    ended before it (the one it belongs to is not yielded)."""
    from ekfviz.io.text import BLOCK_BYTES

    rows: list[tuple[float, float, float, float]] = []
    k = 0
    while 30 * len(rows) < 3 * BLOCK_BYTES:  # some 30 bytes a line: three blocks and more
        rows += [(0.25 * k, 5.0 + j + 0.001 * k, 0.5 + 0.1 * j, 0.1 + 0.01 * j) for j in range(3)]
        k += 1
    bad = len(rows) - 40  # a line well past the first blocks, the second of its scan
    if fault == "range":
        rows[bad] = (rows[bad][0], -2.0, 1.0, 0.2)
    elif fault == "time":
        rows[bad] = (rows[bad][0] - 10.0, 2.0, 1.0, 0.2)
    path = _victoria(tmp_path, "".join(f"{t!r} {r!r} {b!r} {d!r}\n" for t, r, b, d in rows))
    scans: list[Scan] = []
    with contextlib.ExitStack() as stack:
        if fault is not None:
            stack.enter_context(
                pytest.raises(InputError, match=rf"measurements\.dat:{bad + 1}: found {fault}")
            )
        scans.extend(e for e in read_victoria(path) if isinstance(e, Scan))
    expected = k if fault is None else bad // 3
    assert len(scans) == expected
    for i, scan in enumerate(scans):
        assert scan.time == 0.25 * i and scan.line == 3 * i + 1
        assert scan.diameters is not None
        assert np.array_equal(scan.diameters, [0.1 + 0.01 * j for j in range(3)])
        assert np.allclose(scan.z[:, 1], [5.0 + 0.001 * i, 6.0 + 0.001 * i, 7.0 + 0.001 * i])


def _z_of(pose: tuple[float, float, float], points: list[tuple[float, float]]) -> FloatArray:
    x, y, theta = pose
    return np.array(
        [[math.atan2(py - y, px - x) - theta, math.hypot(px - x, py - y)] for px, py in points]
    )


@pytest.mark.parametrize("method", [Method.NN, Method.JCBB])
def test_jcbb_beats_nn_on_two_close_landmarks(method: Method) -> None:
    # two landmarks 1.2 m apart, known well; the pose then uncertain sideways by 1 m, and
    # truly 0.9 m to the right: both measurements appear shifted left by 0.9 m. Nearest
    # neighbour pairs the right landmark's measurement with the left landmark (and the
    # left one's with nothing); only the joint pairing of both explains the common shift.
    left, right = (10.0, 0.6), (10.0, -0.6)
    params = FilterParams(
        sigma_x=0.05, sigma_y=1.0, sigma_alpha=0.001, sigma_bearing=0.002, sigma_range=0.02,
        init_pose_sigma=(0.01, 0.01, 0.001),
    )  # fmt: skip
    ekf = EkfSlam(params)
    ekf.observe([1, 2], _z_of((0.0, 0.0, 0.0), [left, right]))
    ekf.predict(0.0, 0.0)
    associator = Associator(AssociationParams(method=method, confirm=1), RangeBearing(), params.R)
    _, association = associator.process(ekf, Scan(line=1, z=_z_of((0.0, -0.9, 0.0), [left, right])))
    if method is Method.JCBB:
        assert association.landmark.tolist() == [1, 2]
        assert association.fate.tolist() == [Fate.MATCHED, Fate.MATCHED]
        assert abs(ekf.x[1] - -0.9) < 0.05
    else:
        assert association.landmark.tolist() == [-1, 1]  # the wrong landmark
        assert association.fate.tolist() == [Fate.REJECTED, Fate.MATCHED]
        assert ekf.x[1] > 0.0  # pulled the wrong way


def test_association_statistics_read_back_from_the_recording(tmp_path: Path) -> None:
    log, truth = tmp_path / "scans.txt", tmp_path / "scans.json"
    simulated = runner.invoke(app, [
        "simulate", "--scenario", "loop", "--steps", "120", "--landmarks", "60",
        "--unknown-ids", "--clutter", "1", "--detection-probability", "0.9", "--seed", "3",
        "-o", str(log), "--truth-out", str(truth),
    ])  # fmt: skip
    assert simulated.exit_code == 0, simulated.output
    rrd, report = tmp_path / "scans.rrd", tmp_path / "report.json"
    replayed = runner.invoke(app, [
        "replay", str(log), "--truth", str(truth), "--save", str(rrd), "--report", str(report),
    ])  # fmt: skip
    assert replayed.exit_code == 0, replayed.output
    totals = json.loads(report.read_text())["association"]
    scan_ids = json.loads(truth.read_text())["scan_ids"]
    assert totals["scans"] == len(scan_ids)
    recorded = {}
    for name in ("matched", "new", "rejected", "confirmed", "removed", "correct", "wrong"):
        rows = entity_rows(rrd, f"/metrics/association/{name}")
        assert len(rows) == len(scan_ids)  # one value per scan
        recorded[name] = sum(row["Scalars:scalars"][0] for row in rows)  # type: ignore[index]
        assert recorded[name] == totals[name], name
    # every measurement of every scan has one fate
    assert recorded["matched"] + recorded["new"] + recorded["rejected"] == sum(map(len, scan_ids))
    assert recorded["correct"] > 0.9 * recorded["matched"]
    # a first-sighting outline for each confirmed landmark, at its confirmation, none for
    # the tentative ones removed (which would bury the map)
    outlined = [
        int(i)
        for row in entity_rows(rrd, "/world/landmarks/initial")
        for i in row.get("LineStrips2D:class_ids") or []  # type: ignore[attr-defined]
    ]
    assert recorded["removed"] > 0 and len(outlined) == recorded["confirmed"]
    final = [lm["id"] for lm in json.loads(report.read_text())["landmarks"]]
    assert sorted(outlined) == sorted(final)


def test_monte_carlo_trials_pair_scans_like_known_ids_without_clutter() -> None:
    """consistency --unknown-ids: each trial simulates id-less scans and pairs them with
    an associator of its own; with every landmark paired on its own (as known ids are),
    the trial is the known-id trial exactly."""
    from ekfviz.studies.montecarlo import Trials, run_trial

    world = loop(steps=200, landmarks=60, seed=4)
    noise, params = world.noise, matched(world)
    known = Trials(world, noise, world.init_pose_sigma, params)
    pairing = AssociationParams(gate_probability=0.999999, confirm=1, single_gate_area=math.inf)
    unknown = Trials(
        world, noise, world.init_pose_sigma, params,
        detection=Detection(unknown_ids=True), association=pairing,
    )  # fmt: skip
    for seed in (4, 5):
        a, b = run_trial(known, seed), run_trial(unknown, seed)
        np.testing.assert_array_equal(a.nees, b.nees)
        np.testing.assert_array_equal(a.nis, b.nis)
    cluttered = Trials(
        world, noise, world.init_pose_sigma, params,
        detection=Detection(True, 1.0, 0.9), association=AssociationParams(),
    )  # fmt: skip
    c = run_trial(cluttered, 4)
    assert np.isfinite(c.nees).all() and not np.array_equal(c.nis_dof, run_trial(known, 4).nis_dof)


def test_consistency_runs_scans_with_clutter_and_says_how(tmp_path: Path) -> None:
    report = tmp_path / "mc.json"
    base = ["consistency", "--scenario", "loop", "--steps", "120", "--landmarks", "60",
            "--runs", "2", "--workers", "1"]  # fmt: skip
    done = runner.invoke(
        app, [*base, "--unknown-ids", "--clutter", "1", "--detection-probability", "0.9",
              "--association", "nn", "--report", str(report)],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    settings = json.loads(report.read_text())
    assert settings["detection"] == {"unknown_ids": True, "clutter": 1.0, "probability": 0.9}
    assert settings["association"]["association"] == "nn"
    assert settings["nees"]["count"] == 121
    for wrong, message in (
        (["--association", "jcbb"], "add --unknown-ids"),
        (["--unknown-ids", "--association", "known"], "use nn or jcbb"),
        (["--clutter", "1"], "only with --unknown-ids"),
    ):
        done = runner.invoke(app, [*base, *wrong])
        assert done.exit_code == 2 and message in done.output, done.output


def test_joint_covariance_of_candidates_equals_the_dense_h_p_h_t() -> None:
    """JCBB's C (the candidates' predicted measurements' joint covariance) against the
    dense stacked H P H^T, each candidate's H over the pose and its own two rows."""
    from ekfviz.association.associator import _joint_covariance, state_rows

    rng = np.random.default_rng(0)
    n = 3 + 2 * 20
    A = rng.normal(size=(n, n))
    P = A @ A.T
    for k in (1, 2, 7):
        H = rng.normal(size=(k, 2, 5))
        rows = np.sort(rng.choice(20, k, replace=False))
        dense = np.zeros((2 * k, n))
        for j, row in enumerate(rows.tolist()):
            dense[2 * j : 2 * j + 2, :3] = H[j, :, :3]
            dense[2 * j : 2 * j + 2, 3 + 2 * row : 5 + 2 * row] = H[j, :, 3:]
        C = _joint_covariance(P, H, state_rows(rows))
        assert np.allclose(C, dense @ P @ dense.T, rtol=1e-12, atol=1e-9)
        assert np.array_equal(C, C.T)


def test_the_gates_innovation_parts_are_the_innovations() -> None:
    """The associator's gate takes the innovations' bearing and range parts apart: the
    same numbers as innovations() (bearings wrapped across +-pi) and the same distances."""
    from ekfviz.association.gating import (
        innovation_parts,
        innovations,
        mahalanobis2,
        mahalanobis2_of,
    )

    rng = np.random.default_rng(4)
    z = np.column_stack([rng.uniform(-math.pi, math.pi, 5), rng.uniform(1, 30, 5)])
    z_pred = np.column_stack([rng.uniform(-math.pi, math.pi, 9), rng.uniform(1, 30, 9)])
    A = rng.normal(size=(9, 2, 2))
    S = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(2)
    S[3] = [[1.0, 2.0], [2.0, 1.0]]  # not positive definite: infinitely far
    nu = innovations(z, z_pred)
    u, v = innovation_parts(z, z_pred)
    assert np.array_equal(u, nu[:, :, 0]) and np.array_equal(v, nu[:, :, 1])
    assert (np.abs(u) <= math.pi).all()
    d2 = mahalanobis2_of(u, v, S)
    assert np.array_equal(d2, mahalanobis2(nu, S)) and np.isinf(d2[:, 3]).all()
    k = 2
    assert d2[1, k] == pytest.approx(nu[1, k] @ np.linalg.solve(S[k], nu[1, k]), rel=1e-12)


def test_gate_on_a_log_of_scans_is_said_not_silently_ignored(tmp_path: Path) -> None:
    """``--gate`` gates observations by id; on id-less scans it changed nothing, without
    a word. Said once, at the first scan; the run is the one without it."""
    # the bundled log of scans, its first 500 lines (the header with them)
    bundled = Path(__file__).parents[2] / "data" / "scans.txt"
    scans = tmp_path / "scans.txt"
    scans.write_text("".join(bundled.read_text().splitlines(keepends=True)[:500]))
    gated, plain = tmp_path / "gated.json", tmp_path / "plain.json"
    result = runner.invoke(app, ["replay", str(scans), "--gate", "0.5", "--save",
                                 str(tmp_path / "g.rrd"), "--report", str(gated)])  # fmt: skip
    assert result.exit_code == 0, result.output
    said = [line for line in result.output.splitlines() if "--gate 0.5 gates observations" in line]
    assert len(said) == 1 and "(--gate-probability)" in said[0]
    result = runner.invoke(app, ["replay", str(scans), "--save", str(tmp_path / "p.rrd"),
                                 "--report", str(plain)])  # fmt: skip
    assert result.exit_code == 0, result.output
    final = [json.loads(path.read_text())["final_pose"] for path in (gated, plain)]
    assert final[0] == final[1]
