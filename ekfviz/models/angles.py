"""Angles on the circle: every heading and bearing ekfviz keeps lies in (-pi, pi]."""

from __future__ import annotations

import math

import numpy as np

from ekfviz.core.types import FloatArray


def wrap_angle(angle: float) -> float:
    """Wrap an angle to (-pi, pi].

    :return: the angle plus a multiple of 2 pi, in (-pi, pi]
    """
    wrapped = math.remainder(angle, 2.0 * math.pi)  # [-pi, pi], exact
    return math.pi if wrapped == -math.pi else wrapped


def wrap_angles(angles: FloatArray) -> FloatArray:
    """Vectorised :func:`wrap_angle`.

    :return: array of the same shape, every element in (-pi, pi]
    """
    wrapped = np.remainder(angles + np.pi, 2.0 * np.pi) - np.pi  # [-pi, pi)
    return np.where(wrapped == -np.pi, np.pi, wrapped)
