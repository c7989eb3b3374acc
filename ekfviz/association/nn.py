"""Nearest neighbour: each measurement to its closest compatible landmark, each landmark
used once per scan (the globally closest pairs first)."""

from __future__ import annotations

import numpy as np

from ekfviz.core.types import BoolArray, FloatArray, IntArray


def nearest_neighbour(d2: FloatArray, compatible: BoolArray) -> IntArray:
    """Greedy pairing by increasing Mahalanobis distance.

    :param d2: (m, N) squared Mahalanobis distances
    :param compatible: (m, N) individual compatibility
    :return: (m,) the landmark index (column) of each measurement, -1 where none
    """
    m = d2.shape[0]
    pairing = np.full(m, -1, dtype=np.int64)
    rows, cols = np.nonzero(compatible)
    if rows.size == 0:
        return pairing
    used: set[int] = set()
    for k in np.argsort(d2[rows, cols], kind="stable").tolist():
        i, j = int(rows[k]), int(cols[k])
        if pairing[i] < 0 and j not in used:
            pairing[i] = j
            used.add(j)
    return pairing
