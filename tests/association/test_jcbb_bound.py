"""JCBB bounded in time per scan: the work of a scan is capped by construction,
a scan cut short falls back (best complete pairing, else nearest neighbour), and the
fallback is counted in the report and logged in the recording."""

from __future__ import annotations

import itertools
import json
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.association import AssociationParams, Associator, Method
from ekfviz.association.jcbb import (
    FALLBACK_BEST,
    FALLBACK_NN,
    HAVE_SEARCH,
    MAX_JOINT,
    jcbb,
    joint_threshold,
)
from ekfviz.association.nn import nearest_neighbour
from ekfviz.association.params import DEFAULT_BUDGET, DEFAULT_WORK_BUDGET
from ekfviz.cli import app
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Scan
from ekfviz.core.types import FloatArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.models.range_bearing import RangeBearing

runner = CliRunner()


def _problem(
    rng: np.random.Generator, m: int, k: int, spread: float = 1.0
) -> tuple[FloatArray, FloatArray, np.ndarray, FloatArray, FloatArray]:
    """A random scan against ``k`` candidates with correlated predictions (a shared pose)."""
    pose_part = rng.normal(size=(2 * k, 3)) * 0.3
    own = rng.normal(size=(2 * k, 2 * k)) * 0.05
    C = pose_part @ pose_part.T + own @ own.T + 0.01 * np.eye(2 * k)
    C = 0.5 * (C + C.T)
    R = np.diag([0.02, 0.05])
    nu = rng.normal(size=(m, k, 2)) * spread
    S = np.array([C[2 * j : 2 * j + 2, 2 * j : 2 * j + 2] + R for j in range(k)])
    d2 = np.einsum("mki,kij,mkj->mk", nu, np.linalg.inv(S), nu)
    return nu, d2, d2 < 9.21, C, R


def _joint_d2(pairs: list[tuple[int, int]], nu: FloatArray, C: FloatArray, R: FloatArray) -> float:
    """The joint Mahalanobis distance squared of a pairing, from scratch (dense solve)."""
    cols = [2 * k + t for _, k in pairs for t in (0, 1)]
    S = C[np.ix_(cols, cols)] + np.kron(np.eye(len(pairs)), R)
    v = np.concatenate([nu[i, k] for i, k in pairs])
    return float(v @ np.linalg.solve(S, v))


def _brute_force(
    nu: FloatArray, d2: FloatArray, ok: np.ndarray, C: FloatArray, R: FloatArray, p: float
) -> tuple[int, float]:
    """Pairs and joint distance of the best pairing whose every prefix (in measurement
    order) is jointly compatible: what JCBB's search defines, by enumeration."""
    m = ok.shape[0]
    best = (0, 0.0)
    choices = [[-1, *np.flatnonzero(ok[i]).tolist()] for i in range(m)]
    for combo in itertools.product(*choices):
        used = [c for c in combo if c >= 0]
        if len(used) != len(set(used)):
            continue
        pairs: list[tuple[int, int]] = []
        fine = True
        for i, c in enumerate(combo):
            if c < 0:
                continue
            pairs.append((i, c))
            if not _joint_d2(pairs, nu, C, R) < joint_threshold(p, 2 * len(pairs)):
                fine = False
                break
        if not fine or not pairs:
            continue
        dist = _joint_d2(pairs, nu, C, R)
        if len(pairs) > best[0] or (len(pairs) == best[0] and dist < best[1]):
            best = (len(pairs), dist)
    return best


@pytest.mark.parametrize("seed", range(12))
def test_jcbb_finds_the_pairing_exhaustive_search_finds(seed: int) -> None:
    rng = np.random.default_rng(seed)
    nu, d2, ok, C, R = _problem(rng, m=4, k=4, spread=0.6)
    result = jcbb(nu, d2, ok, C, R, 0.99)
    pairs, dist = _brute_force(nu, d2, ok, C, R, 0.99)
    assert not result.exhausted and result.fallback == ""
    found = [(i, int(k)) for i, k in enumerate(result.pairing.tolist()) if k >= 0]
    assert len(found) == pairs
    if pairs:
        assert result.joint_d2 == pytest.approx(dist, rel=1e-9)
        assert _joint_d2(found, nu, C, R) == pytest.approx(dist, rel=1e-9)


def _two_bearing_scan(m: int, k: int) -> tuple[FloatArray, FloatArray, np.ndarray, FloatArray]:
    """The hang that bound prevents: every measurement of a scan on two rays, every one in the
    gate of every candidate, all strongly correlated through the pose."""
    rng = np.random.default_rng(7)
    pose_part = np.tile(np.array([[0.0, 0.0, 0.4], [0.05, 0.0, 0.0]]), (k, 1))
    C = pose_part @ pose_part.T + 1e-4 * np.eye(2 * k)
    nu = rng.normal(size=(m, k, 2)) * 0.05
    d2 = np.abs(rng.normal(size=(m, k)))
    return nu, d2, np.ones((m, k), dtype=bool), C


def test_an_adversarial_scan_stays_within_its_work_budget_and_falls_back() -> None:
    nu, d2, ok, C = _two_bearing_scan(120, 120)
    R = np.diag([0.01**2, 0.08**2])
    started = time.process_time()
    result = jcbb(nu, d2, ok, C, R, 0.99)
    seconds = time.process_time() - started
    assert result.exhausted and result.fallback in (FALLBACK_BEST, FALLBACK_NN)
    assert result.hypotheses <= DEFAULT_BUDGET
    assert result.work <= DEFAULT_WORK_BUDGET
    paired = result.pairing[result.pairing >= 0]
    assert len(set(paired.tolist())) == len(paired)  # each landmark once
    assert ok[np.flatnonzero(result.pairing >= 0), paired].all()
    print(f"adversarial scan 120 x 120: {seconds:.3f} s of CPU, {result.hypotheses} hypotheses")


def test_a_search_that_completes_no_pairing_falls_back_to_nearest_neighbour() -> None:
    nu, d2, ok, C = _two_bearing_scan(60, 60)
    R = np.diag([0.01**2, 0.08**2])
    result = jcbb(nu, d2, ok, C, R, 0.99, work_budget=1000)
    assert result.exhausted and result.fallback == FALLBACK_NN
    assert result.work <= 1000
    np.testing.assert_array_equal(result.pairing, nearest_neighbour(d2, ok))


def test_a_scan_with_too_many_gated_measurements_is_not_searched() -> None:
    m = MAX_JOINT + 1
    nu, d2, ok, C = _two_bearing_scan(m, 3)
    result = jcbb(nu, d2, ok, C, np.eye(2), 0.99)
    assert result.exhausted and result.fallback == FALLBACK_NN and result.hypotheses == 0
    np.testing.assert_array_equal(result.pairing, nearest_neighbour(d2, ok))


def test_the_associator_records_the_fallback_of_a_scan() -> None:
    params = FilterParams(sigma_bearing=0.01, sigma_range=0.08)
    slam = EkfSlam(params)
    associator = Associator(
        AssociationParams(method=Method.JCBB, confirm=1, work_budget=500),
        RangeBearing(),
        params.R,
    )
    rays = [(0.3 if j % 2 else -0.3, 2.0 + 0.05 * (j // 2)) for j in range(40)]
    z = np.array(rays, dtype=np.float64)
    _, first = associator.process(slam, Scan(line=1, z=z))
    assert not first.exhausted  # nothing mapped yet: nothing to search
    _, second = associator.process(slam, Scan(line=1, z=z))
    assert second.exhausted and second.fallback == FALLBACK_NN


def _two_bearing_log(path: Path, scans: int, per_scan: int) -> Path:
    lines = ["# ekfviz extended log: control d alpha | observe id bearing range ..."]
    for _ in range(scans):
        lines.append("control 0.01 0.0")
        cells = []
        for j in range(per_scan):
            cells += [f"{0.3 if j % 2 == 0 else -0.3:.4f}", f"{2.0 + 0.01 * (j // 2):.4f}"]
        lines.append("scan " + " ".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.slow
def test_a_replay_of_two_bearing_scans_reports_and_logs_its_fallbacks(tmp_path: Path) -> None:
    # the first scan maps its rays, the second is searched until its budget runs out
    log = _two_bearing_log(tmp_path / "rays.txt", scans=2, per_scan=120)
    rrd, report = tmp_path / "rays.rrd", tmp_path / "rays.json"
    result = runner.invoke(
        app,
        ["replay", str(log), "--association", "jcbb", "--save", str(rrd), "--report", str(report)],
    )
    assert result.exit_code == 0, result.output
    association = json.loads(report.read_text())["association"]
    exhausted = association["jcbb_budget_exhausted_scans"]
    assert exhausted >= 1
    assert association["jcbb_hypotheses"] <= DEFAULT_BUDGET * association["scans"]
    assert "jcbb_budget_exhausted_scans" in result.output  # said in the summary
    rows = entity_rows(rrd, "/metrics/association/fell_back")
    assert len(rows) == association["scans"]  # one value per scan
    assert sum(row["Scalars:scalars"][0] for row in rows) == exhausted  # type: ignore[index]
    lines = [str(row) for row in entity_rows(rrd, "/log")]
    assert sum("fell back to" in line for line in lines) == exhausted


def assert_same_search(
    nu: np.ndarray,
    d2: np.ndarray,
    ok: np.ndarray,
    C: np.ndarray,
    R: np.ndarray,
    budget: int,
    work_budget: int = DEFAULT_WORK_BUDGET,
) -> None:
    """The compiled search and the Python one: the same pairing, hypotheses, work and
    fallback, the joint distance to round-off."""
    fast = jcbb(nu, d2, ok, C, R, 0.99, budget, work_budget)
    slow = jcbb(nu, d2, ok, C, R, 0.99, budget, work_budget, compiled=False)
    np.testing.assert_array_equal(fast.pairing, slow.pairing)
    assert (fast.hypotheses, fast.work, fast.exhausted, fast.fallback) == (
        slow.hypotheses, slow.work, slow.exhausted, slow.fallback
    )  # fmt: skip
    assert fast.joint_d2 == pytest.approx(slow.joint_d2, rel=1e-12, abs=1e-12)


@pytest.mark.skipif(not HAVE_SEARCH, reason="the compiled search was not built")
@pytest.mark.parametrize("seed", range(40))
def test_the_compiled_search_explores_the_nodes_the_python_one_does(seed: int) -> None:
    """_search.c against jcbb.py's search on random scans, some cut short by the budgets:
    the same pairing, hypotheses, work and fallback; the joint distance to round-off."""
    rng = np.random.default_rng(100 + seed)
    m, k = int(rng.integers(1, 9)), int(rng.integers(1, 9))
    nu, d2, ok, C, R = _problem(rng, m=m, k=k, spread=float(rng.choice([0.3, 0.6, 1.2])))
    budgets = [
        (DEFAULT_BUDGET, DEFAULT_WORK_BUDGET),
        (int(rng.integers(1, 40)), DEFAULT_WORK_BUDGET),
        (DEFAULT_BUDGET, int(rng.integers(4, 400))),
    ]
    for budget, work_budget in budgets:
        assert_same_search(nu, d2, ok, C, R, budget, work_budget)


@pytest.mark.skipif(not HAVE_SEARCH, reason="the compiled search was not built")
def test_the_compiled_search_keeps_to_the_budgets_on_the_adversarial_scan() -> None:
    nu, d2, ok, C = _two_bearing_scan(60, 60)
    R = np.diag([0.01**2, 0.08**2])
    for work_budget in (1000, 200_000):
        fast = jcbb(nu, d2, ok, C, R, 0.99, work_budget=work_budget)
        slow = jcbb(nu, d2, ok, C, R, 0.99, work_budget=work_budget, compiled=False)
        np.testing.assert_array_equal(fast.pairing, slow.pairing)
        assert (fast.hypotheses, fast.work, fast.fallback) == (
            slow.hypotheses, slow.work, slow.fallback
        )  # fmt: skip


@pytest.mark.skipif(not HAVE_SEARCH, reason="the compiled search was not built")
@pytest.mark.parametrize("seed", range(10))
def test_the_compiled_preparation_orders_ties_as_the_stable_sort_does(seed: int) -> None:
    """_search.c orders each measurement's candidates itself: equal distances (here every
    candidate of a measurement at one of two values) keep their column order, as numpy's
    stable argsort does, so the same nodes are explored in the same order."""
    rng = np.random.default_rng(300 + seed)
    m, k = int(rng.integers(2, 8)), int(rng.integers(2, 8))
    nu, _, _, C, R = _problem(rng, m=m, k=k, spread=0.3)
    d2 = rng.choice([0.5, 2.0], size=(m, k))
    ok = rng.random((m, k)) < 0.7
    ok[0] = False  # a measurement in no gate is left out of the search
    for budget in (DEFAULT_BUDGET, int(rng.integers(1, 20))):
        assert_same_search(nu, d2, ok, C, R, budget)


@pytest.mark.skipif(not HAVE_SEARCH, reason="the compiled search was not built")
def test_the_compiled_jcbb_falls_back_past_max_joint_as_the_python_one() -> None:
    m = MAX_JOINT + 1
    nu = np.zeros((m, 1, 2))
    d2 = np.linspace(0.1, 5.0, m)[:, None]
    ok = np.ones((m, 1), dtype=bool)
    C = np.eye(2) * 0.1
    R = np.diag([0.01, 0.02])
    fast = jcbb(nu, d2, ok, C, R, 0.99)
    slow = jcbb(nu, d2, ok, C, R, 0.99, compiled=False)
    np.testing.assert_array_equal(fast.pairing, slow.pairing)
    assert fast.pairing.tolist() == [0] + [-1] * (m - 1)  # nearest neighbour: the closest
    assert (fast.hypotheses, fast.exhausted, fast.fallback) == (0, True, FALLBACK_NN)
    assert (slow.hypotheses, slow.exhausted, slow.fallback) == (0, True, FALLBACK_NN)
