"""Simulate a robot that drives by controls and sees the landmarks its sensor reaches.

Numpy only. The true robot moves by the noisy motion model and the sensor returns the
noisy (bearing, range) of every landmark within its range and field of view: exactly
the models of the filter. The log records the commanded controls, as a real robot's
would, and the truth keeps the poses the robot really took.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.angles import wrap_angles
from ekfviz.models.classic import motion

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
class Sensor:
    """What the sensor reaches: landmarks within ``max_range`` metres and within
    ``fov`` radians centred on the heading (2 pi: all around)."""

    max_range: float = math.inf
    fov: float = 2 * math.pi

    def sees_all(self) -> bool:
        return math.isinf(self.max_range) and self.fov >= 2 * math.pi


@dataclass(frozen=True, slots=True)
class Simulation:
    """A simulated run: the log's events and the truth behind them.

    :param events: the first observation, then control and observation alternately
    :param poses_xytheta: (T+1, 3) true poses, at the start and after every control
    :param landmark_ids: (N,) ids of the true landmarks
    :param landmarks_xy: (N, 2) true landmark positions
    """

    events: tuple[LogEvent, ...]
    poses_xytheta: FloatArray
    landmark_ids: IntArray
    landmarks_xy: FloatArray


def simulate(
    controls: FloatArray,
    landmarks_xy: FloatArray,
    noise: Noise = Noise(),
    seed: int = 0,
    start_xytheta: tuple[float, float, float] | FloatArray = (0.0, 0.0, 0.0),
    sensor: Sensor = Sensor(),
    landmark_ids: IntArray | None = None,
) -> Simulation:
    """Drive the controls from ``start_xytheta`` and observe after the start and each control.

    :param controls: (T, 2) commanded (d, alpha)
    :param landmarks_xy: (N, 2) true landmark positions
    :param landmark_ids: (N,) their ids; default 1..N
    """
    rng = np.random.default_rng(seed)
    landmarks_xy = np.asarray(landmarks_xy, dtype=np.float64).reshape(-1, 2)
    if landmark_ids is None:
        landmark_ids = np.arange(1, len(landmarks_xy) + 1, dtype=np.int64)
    pose = np.array(start_xytheta, dtype=np.float64)
    poses = [pose]
    line = 1

    def sight() -> Sighting:
        d_xy = landmarks_xy - pose[:2]
        ranges = np.hypot(d_xy[:, 0], d_xy[:, 1])
        bearings = wrap_angles(np.arctan2(d_xy[:, 1], d_xy[:, 0]) - pose[2])
        seen = (ranges <= sensor.max_range) & (np.abs(bearings) <= sensor.fov / 2)
        m = int(seen.sum())
        # draw the noise for every landmark, seen or not, so that a run's noise does not
        # depend on the sensor's reach
        n_bearing = rng.normal(0.0, 1.0, len(ranges)) * noise.sigma_bearing
        n_range = rng.normal(0.0, 1.0, len(ranges)) * noise.sigma_range
        z = np.empty((m, 2))
        z[:, 0] = wrap_angles(bearings[seen] + n_bearing[seen])
        z[:, 1] = np.abs(ranges[seen] + n_range[seen])  # a range is never negative
        return Sighting(line=line, ids=landmark_ids[seen], z=z)

    events: list[LogEvent] = [sight()]
    for d, alpha in controls:
        e_x, e_y, e_a = rng.normal(0.0, 1.0, 3) * [noise.sigma_x, noise.sigma_y, noise.sigma_alpha]
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
    return Simulation(tuple(events), np.array(poses), landmark_ids.copy(), landmarks_xy.copy())
