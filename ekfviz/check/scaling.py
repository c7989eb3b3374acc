"""The factor of a scaled noise read off a filter's result: k of ``k R`` or ``k Q``.

A mutation of the ``scale`` family (:func:`ekfviz.check.operators.scaled_noise`) uses a
noise matrix k times what it is; its re-run is a smooth function of k, which
:func:`fit_scale` fits to the filter's result by Gauss-Newton on log k (a predict's
covariance is linear in k, an update's goes as (B + k R)^-1), the residual scaled as the
comparison scales its differences (:func:`ekfviz.check.search.scaled_distance`). A fit
that stops closing in gives up after a few re-runs: most sets the search tries reproduce
nothing, whatever k.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ekfviz.check.rerun import State
from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle

# Gauss-Newton steps at most, and the share of the residual a step must leave at most
# (else it is halved once, then the fit gives up: k does not explain the result)
MAX_STEPS = 12
PROGRESS = 0.7
# log k's finite difference, the largest step (a factor e^3 = 20), and the range of k
STEP = 1e-6
LARGEST_STEP = 3.0
LOG_RANGE = math.log(1e6)
# a factor within 1% of 1 is round-off, not a noise used scaled
SAME = 0.01


def fit_scale(
    run: Callable[[float], State | None], target: State, close: float, start: float = 1.0
) -> tuple[float, State] | None:
    """The factor k (and the re-run with it) that brings ``run(k)`` nearest ``target``,
    starting from ``start``; None where none comes within ``close`` (the largest scaled
    difference) or the one that does is 1 to within :data:`SAME`."""
    u = math.log(start) if start > 0 else 0.0
    state = run(math.exp(u))
    r = None if state is None else residual(state, target)
    if state is None or r is None:
        return None
    polished = False
    for _ in range(MAX_STEPS):
        if float(np.max(np.abs(r), initial=0.0)) <= close:
            if abs(u) < SAME:
                return None
            if polished:  # (one step more, for a factor to more digits than close's)
                return math.exp(u), state
            polished = True
        moved = run(math.exp(u + STEP))
        r_moved = None if moved is None else residual(moved, target)
        if r_moved is None:
            return None
        slope = (r_moved - r) / STEP
        curvature = float(slope @ slope)
        if curvature == 0.0 or not math.isfinite(curvature):
            return None
        step = float(np.clip(-(slope @ r) / curvature, -LARGEST_STEP, LARGEST_STEP))
        taken = _step(run, target, u, step, float(np.linalg.norm(r)))
        if taken is None:
            return (math.exp(u), state) if polished else None
        u, state, r = taken
    return (math.exp(u), state) if polished else None


def _step(
    run: Callable[[float], State | None], target: State, u: float, step: float, norm: float
) -> tuple[float, State, FloatArray] | None:
    """The step (or half of it) from log k ``u`` that leaves at most :data:`PROGRESS` of
    the residual's ``norm``; None where neither does."""
    for fraction in (1.0, 0.5):
        new_u = float(np.clip(u + fraction * step, -LOG_RANGE, LOG_RANGE))
        state = run(math.exp(new_u))
        r = None if state is None else residual(state, target)
        if state is not None and r is not None and np.linalg.norm(r) <= PROGRESS * norm:
            return new_u, state, r
    return None


def residual(result: State, target: State) -> FloatArray | None:
    """``result - target`` over x (the heading wrapped) and P, each difference divided by
    max(1, |target|); None where the landmarks differ or a number is not finite."""
    if np.array_equal(result.ids, target.ids):
        x, P = result.x, result.P
    elif sorted(result.ids.tolist()) != sorted(target.ids.tolist()):
        return None
    else:
        x, P = result.in_order_of(target.ids)
    if x.shape != target.x.shape:
        return None
    dx = x - target.x
    dx[2] = wrap_angle(float(dx[2]))
    dP = (P - target.P) / np.maximum(1.0, np.abs(target.P))
    values = np.concatenate([dx / np.maximum(1.0, np.abs(target.x)), dP.ravel()])
    return values if np.isfinite(values).all() else None
