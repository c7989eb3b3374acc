"""Central finite differences, the yardstick of every analytic Jacobian in the tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle


def numerical_jacobian(
    f: Callable[[FloatArray], FloatArray], at: FloatArray, wrap_rows: tuple[int, ...] = ()
) -> FloatArray:
    """Central differences; rows in ``wrap_rows`` are angles whose residual is wrapped."""
    h = 1e-6
    columns = []
    for i in range(len(at)):
        step = np.zeros_like(at)
        step[i] = h
        diff = f(at + step) - f(at - step)
        for row in wrap_rows:
            diff[row] = wrap_angle(diff[row])
        columns.append(diff / (2 * h))
    return np.column_stack(columns)
