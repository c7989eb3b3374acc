"""The scan's gate in one pass (gating.gate_scan, compiled in _search.c) against its plain
definition: predict_landmarks_of, innovation_parts, mahalanobis2_of and compatible over
the whole map, kept for the landmarks in some gate. The compiled gate does the same
operations in the same order, so the two agree to the last bit: the recordings of the
classic samples do not change with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekfviz.association.gating import (
    HAVE_GATE,
    ScanGate,
    gate_scan,
    gate_threshold,
    marginals_of,
    predict_landmarks,
)
from ekfviz.core.types import FloatArray
from ekfviz.models.range_bearing import RangeBearing

GATE, NEW_GATE = gate_threshold(0.99), gate_threshold(0.9999)


def _map(rng: np.random.Generator, n_landmarks: int, scale: float) -> tuple[FloatArray, FloatArray]:
    """A random state and a correlated covariance of ``n_landmarks`` landmarks."""
    n = 3 + 2 * n_landmarks
    x = rng.normal(size=n) * scale
    x[2] = rng.uniform(-4.0, 4.0)  # wrapped or not: the filter's is, the gate must not care
    A = rng.normal(size=(n, n)) * 0.1
    return x, A @ A.T + 0.01 * np.eye(n)


def _scan(
    rng: np.random.Generator, x: FloatArray, P: FloatArray, sensor: RangeBearing, m: int
) -> FloatArray:
    """m measurements near the predictions of random landmarks, a third of them with a
    bearing a hair either side of +-pi (where the wrapping decides)."""
    predicted = predict_landmarks(x, P, sensor, np.diag([0.02, 0.3])).z_pred
    z = predicted[rng.integers(0, predicted.shape[0], m)] + rng.normal(size=(m, 2)) * [0.2, 0.5]
    edge = rng.random(m) < 0.3
    z[edge, 0] = (
        math.pi * rng.choice([-1.0, 1.0], int(edge.sum())) - rng.normal(size=int(edge.sum())) * 1e-3
    )
    return z


def _assert_same(a: ScanGate, b: ScanGate) -> None:
    for name in ScanGate.__slots__:
        got, expected = getattr(a, name), getattr(b, name)
        assert got.shape == expected.shape, name
        assert got.dtype == expected.dtype, name
        assert np.array_equal(got, expected), name  # bit for bit, inf included


@pytest.mark.skipif(not HAVE_GATE, reason="_search.c was not built")
@pytest.mark.parametrize("seed", range(6))
def test_compiled_gate_equals_its_definition_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    candidates = 0
    for _ in range(60):
        x, P = _map(rng, int(rng.integers(1, 50)), float(rng.choice([1.0, 10.0, 100.0])))
        sensor = RangeBearing(float(rng.choice([0.0, 3.78])), float(rng.choice([0.0, 0.5])))
        R = np.array([[0.02, 0.001], [0.003, 0.3]])  # not symmetric: S takes its mean
        z = _scan(rng, x, P, sensor, int(rng.integers(1, 12)))
        args = (x, P[:3].copy(), marginals_of(P), sensor, R, z, GATE, NEW_GATE)
        compiled, plain = gate_scan(*args), gate_scan(*args, compiled=False)
        _assert_same(compiled, plain)
        candidates += compiled.rows.size
    assert candidates > 100  # the scans do fall in gates


def test_gate_is_the_landmarks_in_some_gate_with_their_predictions() -> None:
    """Known answer from the definitions, whichever gate runs: the candidates are the
    landmarks some measurement is individually compatible with, their values those of
    predict_landmarks, and a measurement far from every landmark is not near."""
    rng = np.random.default_rng(11)
    x, P = _map(rng, 30, 10.0)
    sensor = RangeBearing(3.78, 0.5)
    R = np.diag([0.02, 0.3])
    predictions = predict_landmarks(x, P, sensor, R)
    z = np.vstack([predictions.z_pred[[4, 17]], [[0.1, 1e6]]])  # two exact, one far away
    gate = gate_scan(x, P[:3].copy(), marginals_of(P), sensor, R, z, GATE, NEW_GATE)
    assert {4, 17} <= set(gate.rows.tolist())
    k = gate.rows.tolist().index(17)
    assert gate.d2[1, k] == 0.0 and gate.compatible[1, k]
    assert np.array_equal(gate.z_pred, predictions.z_pred[gate.rows])
    assert np.array_equal(gate.S, predictions.S[gate.rows])
    assert np.array_equal(gate.H, predictions.H(gate.rows))
    assert gate.near.tolist() == [True, True, False]
    assert not gate.compatible[2].any()
    dense = gate.nu[0, k] @ np.linalg.solve(gate.S[k], gate.nu[0, k])
    assert gate.d2[0, k] == pytest.approx(dense, rel=1e-9)


def test_marginals_of_a_covariance_are_its_diagonal_blocks() -> None:
    rng = np.random.default_rng(3)
    _, P = _map(rng, 7, 1.0)
    covs = marginals_of(P)
    for i in range(7):
        assert np.array_equal(covs[i], P[3 + 2 * i : 5 + 2 * i, 3 + 2 * i : 5 + 2 * i])
