"""Simulate a robot that drives by controls and sees every landmark at every step.

Numpy only. The true robot moves by the noisy motion model and the sensor returns the
noisy (bearing, range) of every landmark, exactly the models of the filter; the log
records the commanded controls, as a real robot's would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.models import measure, motion
from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.core.types import FloatArray

CLASSIC_LANDMARKS_XY = np.array(
    [[3.0, 6.0], [3.0, 12.0], [7.0, 8.0], [7.0, 14.0], [11.0, 6.0], [11.0, 12.0]]
)


def classic_controls() -> FloatArray:
    """The classic pentagon: [5 x (3.0, 0), (1.0, 1.2566)] four times, then 5 x (3.0, 0).

    :return: (29, 2) controls (d, alpha)
    """
    lap = [(3.0, 0.0)] * 5 + [(1.0, 1.2566)]
    return np.array(lap * 4 + [(3.0, 0.0)] * 5)


@dataclass(frozen=True, slots=True)
class Noise:
    """True noise standard deviations of the simulated robot and sensor."""

    sigma_x: float = 0.25
    sigma_y: float = 0.1
    sigma_alpha: float = 0.1
    sigma_bearing: float = 0.01
    sigma_range: float = 0.08

    @staticmethod
    def none() -> Noise:
        return Noise(0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class Simulation:
    """A simulated run: the log's events and the truth behind them.

    :param events: the first observation, then control and observation alternately
    :param poses_xytheta: (T+1, 3) true poses, at the start and after every control
    :param landmarks_xy: (N, 2) true landmark positions, landmark i has id i+1
    """

    events: tuple[LogEvent, ...]
    poses_xytheta: FloatArray
    landmarks_xy: FloatArray


def simulate(
    controls: FloatArray,
    landmarks_xy: FloatArray,
    noise: Noise = Noise(),
    seed: int = 0,
    start_xytheta: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Simulation:
    """Drive the controls from ``start_xytheta`` and observe every landmark after each.

    :param controls: (T, 2) commanded (d, alpha)
    :param landmarks_xy: (N, 2) true landmark positions
    """
    rng = np.random.default_rng(seed)
    ids = np.arange(1, len(landmarks_xy) + 1, dtype=np.int64)
    pose = np.array(start_xytheta, dtype=np.float64)
    poses = [pose]
    line = 1

    def sight() -> Sighting:
        z = np.array([measure(pose, landmark) for landmark in landmarks_xy])
        z[:, 0] += rng.normal(0.0, noise.sigma_bearing, len(z)) if noise.sigma_bearing else 0.0
        z[:, 1] += rng.normal(0.0, noise.sigma_range, len(z)) if noise.sigma_range else 0.0
        z[:, 0] = (z[:, 0] + math.pi) % (2 * math.pi) - math.pi
        return Sighting(line=line, ids=ids, z=z)

    events: list[LogEvent] = [sight()]
    for d, alpha in controls:
        e_x, e_y, e_a = rng.normal(0.0, [noise.sigma_x, noise.sigma_y, noise.sigma_alpha])
        theta = pose[2]
        # the noise acts in the robot frame, as in the filter's motion model
        moved = motion(pose, d + e_x, alpha + e_a)
        moved[:2] += e_y * np.array([-math.sin(theta), math.cos(theta)])
        pose = moved
        poses.append(pose)
        line += 1
        events.append(Control(line=line, d=float(d), alpha=float(alpha)))
        line += 1
        events.append(sight())
    return Simulation(tuple(events), np.array(poses), np.array(landmarks_xy, dtype=np.float64))
