"""The correlation matrix of a state covariance, small enough to show, and when to take it.

The correlation of P, ``C_ij = P_ij / sqrt(P_ii P_jj)``, shows question 3.1's answer: how
the pose and the landmarks become correlated as the map is built. A state over
``MAX_SIDE`` dimensions is block-averaged (means of f x f blocks) to at most ``MAX_SIDE``
rows and columns. Taking it costs O(n^2) for a state of dimension n, and every image
costs the recording its size, so a replay takes it at every update while the map holds
at most ``SMALL_MAP`` landmarks and the run is in its first ``EVERY_UPDATE_STEPS``
steps; beyond either, every ``EVERY_STEPS`` steps; and at the last event (as the
recording draws the whole map's ellipses).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray, IntArray

MAX_SIDE = 200  # rows and columns of the largest matrix kept
SMALL_MAP = 32  # up to this many landmarks, at every update
EVERY_UPDATE_STEPS = 1000  # ... and in the first this many steps of a run
EVERY_STEPS = 25  # beyond: every this many steps, and at the last event
# ... or, for timestamped events (high-rate odometry, whose steps are samples), every
# this many seconds of log time (as the recorder's whole map, ekfviz.viz.thinning)
EVERY_S = 5.0


@dataclass(frozen=True, slots=True)
class Correlation:
    """The correlation matrix of a state covariance, maybe block-averaged.

    :param matrix: (m, m) correlations in [-1, 1], NaN where a variance is zero;
        m = ceil(dim / factor)
    :param dim: the state dimension 3 + 2N it was taken from
    :param factor: f: each entry is the mean of an f x f block of the full matrix (1: none)
    :param landmark_ids: (N,) the state's landmark ids, to label the blocks
    """

    matrix: FloatArray
    dim: int
    factor: int
    landmark_ids: IntArray

    @property
    def averaged(self) -> bool:
        return self.factor > 1

    def describe(self) -> str:
        """One sentence on what the matrix shows."""
        text = f"Correlation of P ({self.dim} x {self.dim}: pose, then {len(self.landmark_ids)}"
        text += " landmarks in state order)"
        if self.averaged:
            side = len(self.matrix)
            text += (
                f", block-averaged over {self.factor} x {self.factor} blocks to"
                f" {side} x {side} (at most {MAX_SIDE} x {MAX_SIDE} are shown)"
            )
        return text + "; colours fixed from -1 (blue) through 0 (white) to +1 (red)."


def correlation_matrix(P: FloatArray) -> FloatArray:
    """C = D^-1/2 P D^-1/2 with D = diag(P); rows and columns of a zero variance are NaN.

    :param P: (n, n) covariance
    :return: (n, n) correlations, clipped to [-1, 1] (rounding can step past them)
    """
    variances = np.diagonal(P).copy()
    if variances.min(initial=math.inf) > 0.0:  # as a rule (NaN is not): no errstate to set
        scale = 1.0 / np.sqrt(variances)
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(variances > 0.0, 1.0 / np.sqrt(variances), np.nan)
    # the products in place: one n x n array, not three (the same floats, in the same
    # order); into an array given as ``out``, numpy walks P row by row, where for an
    # output of its own it may walk the broadcast scale's way, column by column (at
    # n = 900, ten times slower)
    C: FloatArray = np.multiply(P, scale[:, None], out=np.empty(P.shape))
    C *= scale[None, :]
    np.clip(C, -1.0, 1.0, out=C)
    return C


def block_average(C: FloatArray, max_side: int = MAX_SIDE) -> tuple[FloatArray, int]:
    """Means of f x f blocks of ``C``, with the smallest f that gives at most ``max_side``
    rows; the last block of a row or column may be smaller. NaN entries are left out of
    a block's mean (a block of NaN only stays NaN).

    :return: (averaged (ceil(n/f), ceil(n/f)), f)
    """
    n = C.shape[0]
    factor = max(1, math.ceil(n / max_side))
    if factor == 1:
        return C, 1
    side = math.ceil(n / factor)
    padded = np.zeros((side * factor, side * factor))
    padded[:n, :n] = C
    finite = np.isfinite(padded)
    if finite.all():  # the common case: a plain sum, and counts from the blocks' sizes
        # the rows' blocks summed, then the columns' (one reduction over the axes
        # (1, 3) of a 4-d view is half as fast)
        along = _block_columns_summed(padded, side, factor)
        sums = along.reshape(side, factor, side).sum(axis=1)
        rows = np.minimum(factor, n - factor * np.arange(side)).astype(np.float64)
        counts = rows[:, None] * rows[None, :]
        averaged: FloatArray = sums / counts
        return averaged, factor
    blocks = padded.reshape(side, factor, side, factor)
    finite[n:, :] = finite[:, n:] = False  # the padding is no entry
    finite_blocks = finite.reshape(side, factor, side, factor)
    block_counts = finite_blocks.sum(axis=(1, 3))
    sums = np.where(finite_blocks, blocks, 0.0).sum(axis=(1, 3))
    with np.errstate(invalid="ignore"):
        averaged = np.where(block_counts > 0, sums / np.maximum(block_counts, 1), np.nan)
    return averaged, factor


# Up to this many terms numpy sums a reduction's terms one after another; from it on, in
# pairs (pairwise summation), which rounds otherwise: see _block_columns_summed.
_IN_ORDER_TERMS = 8


def _block_columns_summed(padded: FloatArray, side: int, factor: int) -> FloatArray:
    """The sums of each row's blocks of ``factor`` columns: (side * factor, side).

    ``sum(axis=2)`` of the (rows, side, factor) view gives them, but numpy reduces its
    short last axis at a high cost per sum (2.4 ms at n = 600, factor 3). Below
    ``_IN_ORDER_TERMS`` terms it adds them in order, as the strided slices added one after
    another here do, ten times faster, to the same floats (tests/test_correlation.py
    holds the two equal); from it on the reduction is kept.
    """
    if factor >= _IN_ORDER_TERMS:
        summed: FloatArray = padded.reshape(side * factor, side, factor).sum(axis=2)
        return summed
    along: FloatArray = padded[:, 0::factor] + padded[:, 1::factor]
    for k in range(2, factor):
        along += padded[:, k::factor]
    return along


def correlation_of(P: FloatArray, landmark_ids: IntArray | list[int]) -> Correlation:
    """The correlation of a state covariance, block-averaged beyond ``MAX_SIDE``."""
    P = np.asarray(P, dtype=np.float64)
    matrix, factor = block_average(correlation_matrix(P))
    matrix.setflags(write=False)
    return Correlation(
        matrix=matrix,
        dim=int(P.shape[0]),
        factor=factor,
        landmark_ids=np.array(landmark_ids, dtype=np.int64).reshape(-1),
    )


class CorrelationCadence:
    """When a replay takes the correlation matrix (see the module): call :meth:`due` at
    every initialisation and update, in order."""

    def __init__(self) -> None:
        self._last_step: int | None = None
        self._last_time: float | None = None

    def due(self, step: int, n_landmarks: int, last: bool, time: float | None = None) -> bool:
        """Whether the record of this update (or the last event) takes the matrix."""
        if last or self._last_step is None:
            due = True
        elif time is not None and self._last_time is not None:
            due = time - self._last_time >= EVERY_S
        else:
            due = (n_landmarks <= SMALL_MAP and step < EVERY_UPDATE_STEPS) or (
                step - self._last_step >= EVERY_STEPS
            )
        if due:
            self._last_step, self._last_time = step, time
        return due
