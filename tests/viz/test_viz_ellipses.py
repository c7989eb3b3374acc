"""Laws of the ellipse outlines: on the 3-sigma contour, closed, vectorised."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ekfviz.viz.ellipses import ellipse_outlines, outline_points


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.0, np.pi),
    st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0),
    st.tuples(st.floats(-50.0, 50.0), st.floats(-50.0, 50.0)),
)
def test_every_point_is_at_mahalanobis_3(
    angle: float, log_a: float, log_b: float, mean: tuple[float, float]
) -> None:
    c, s = np.cos(angle), np.sin(angle)
    V = np.array([[c, -s], [s, c]])
    cov = V @ np.diag([10.0**log_a, 10.0**log_b]) @ V.T
    (outline,) = ellipse_outlines(np.array([mean]), cov[None])
    e = outline - np.array(mean)
    d2 = np.einsum("ni,ni->n", e, np.linalg.solve(cov, e.T).T)
    np.testing.assert_allclose(np.sqrt(d2), 3.0, rtol=1e-6)
    np.testing.assert_array_equal(outline[0], outline[-1])


def test_many_at_once_match_one_at_a_time() -> None:
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 2, 2))
    covs = A @ A.transpose(0, 2, 1) + 1e-3 * np.eye(2)
    means = rng.normal(size=(50, 2))
    batch = ellipse_outlines(means, covs, n_points=32)
    assert batch.shape == (50, 32, 2)
    for k in range(50):
        np.testing.assert_allclose(batch[k], ellipse_outlines(means[k], covs[k], n_points=32)[0])


def test_degenerate_covariance_gives_a_flat_outline_not_nan() -> None:
    cov = np.array([[[1.0, 1.0], [1.0, 1.0 - 1e-17]]])  # rank 1, a tiny negative eigenvalue
    outline = ellipse_outlines(np.zeros((1, 2)), cov)
    assert np.isfinite(outline).all()
    np.testing.assert_allclose(outline[0, :, 0], outline[0, :, 1], atol=1e-6)


def test_point_budget() -> None:
    assert outline_points(6) == 32
    assert outline_points(512) == 32
    assert outline_points(5000) == 16
