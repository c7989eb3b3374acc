"""The filter protocol: what any EKF-SLAM filter must offer to run through ekfviz.

A filter class is constructed as ``Class(params)`` with ekfviz's
:class:`~ekfviz.core.params.FilterParams` (noise sigmas, ``Q``, ``R``, the initial pose and
its sigmas). It then takes the log's events one by one and shows its state in the classic
layout; ekfviz derives everything it records (predicted measurements, innovations, S,
NIS, landmark marginals, health checks) from that state, before and after each event,
with its own models (:mod:`ekfviz.core.observe`). The built-in
:class:`~ekfviz.filters.ekf.EkfSlam` is one implementation; a user's class loaded with
``--filter PATH.py:Class`` is another.

A minimal filter::

    class MyFilter:
        def __init__(self, params):
            self.x = np.array(params.init_pose, dtype=float)
            self.P = np.diag(np.square(params.init_pose_sigma))
            self.landmark_ids = []
            self.Q, self.R = params.Q, params.R

        def predict(self, d, alpha): ...          # x, P after the control
        def update(self, ids, z): ...             # new ids are new landmarks
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ekfviz.core.types import FloatArray, IntArray


@runtime_checkable
class SlamFilter(Protocol):
    """An EKF-SLAM filter over the state x = [x, y, theta, l1x, l1y, ...] (3+2N).

    ``x`` is the (3+2N,) mean, ``P`` the (3+2N, 3+2N) covariance and ``landmark_ids``
    the N landmark ids in state order; each may be an attribute or a property.
    """

    @property
    def x(self) -> FloatArray | Sequence[float]: ...

    @property
    def P(self) -> FloatArray | Sequence[Sequence[float]]: ...

    @property
    def landmark_ids(self) -> Sequence[int] | IntArray: ...

    def predict(self, d: float, alpha: float) -> None:
        """Apply the control: drive ``d`` metres along the heading, then turn ``alpha``."""

    def update(self, ids: IntArray, z: FloatArray) -> None:
        """Fold in an observation: ``ids`` (m,) landmark ids, ``z`` (m, 2) (bearing,
        range) in file order. Ids not seen before are new landmarks, which the filter
        initialises itself."""


def state_of(slam: SlamFilter) -> tuple[FloatArray, FloatArray, IntArray]:
    """The filter's state as fresh float64 / int64 arrays (x, P, landmark ids), unchecked."""
    x = np.array(slam.x, dtype=np.float64).reshape(-1)
    P = np.array(slam.P, dtype=np.float64)
    ids = np.array(list(slam.landmark_ids), dtype=np.int64).reshape(-1)
    return x, P, ids


@dataclass(frozen=True, slots=True)
class Capabilities:
    """What a filter offers beyond the protocol, where it says so itself (a filter in a
    worker process, whose methods are all present on this side).

    :param takes_dt: ``predict(d, alpha, dt)`` takes the time the control spans
    :param removes_landmarks: it has ``remove_landmarks(ids)``
    :param offline: it has ``finish()`` (a batch smoother)
    """

    takes_dt: bool = False
    removes_landmarks: bool = False
    offline: bool = False


@runtime_checkable
class DeclaresCapabilities(Protocol):
    """A filter that says what it offers (:class:`Capabilities`) instead of being asked."""

    @property
    def capabilities(self) -> Capabilities: ...
