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

from ekfviz.core.records import AnyEvent, Control, LogEvent, Scan, Sighting
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


# Where a sensor of unlimited range puts its clutter: within this many metres.
CLUTTER_RANGE_UNLIMITED = 20.0


@dataclass(frozen=True, slots=True)
class Detection:
    """What the sensor misses and invents, and whether the log names the landmarks.

    :param unknown_ids: write id-less scans (the truth keeps each measurement's id)
    :param clutter: mean number of false alarms per observation (Poisson), uniform over
        the sensor's field (its area)
    :param probability: of detecting a landmark in reach
    """

    unknown_ids: bool = False
    clutter: float = 0.0
    probability: float = 1.0


@dataclass(frozen=True, slots=True)
class Simulation:
    """A simulated run: the log's events and the truth behind them.

    :param events: the first observation, then control and observation alternately
    :param poses_xytheta: (T+1, 3) true poses, at the start and after every control
    :param landmark_ids: (N,) ids of the true landmarks
    :param landmarks_xy: (N, 2) true landmark positions
    :param scan_ids: with unknown ids, per scan the true id of each measurement (None
        for clutter)
    """

    events: tuple[LogEvent, ...]
    poses_xytheta: FloatArray
    landmark_ids: IntArray
    landmarks_xy: FloatArray
    scan_ids: tuple[tuple[int | None, ...], ...] | None = None
    scan_events: tuple[AnyEvent, ...] | None = None  # with unknown ids: the events, id-less


def simulate(
    controls: FloatArray,
    landmarks_xy: FloatArray,
    noise: Noise = Noise(),
    seed: int = 0,
    start_xytheta: tuple[float, float, float] | FloatArray = (0.0, 0.0, 0.0),
    sensor: Sensor = Sensor(),
    landmark_ids: IntArray | None = None,
    detection: Detection = Detection(),
) -> Simulation:
    """Drive the controls from ``start_xytheta`` and observe after the start and each control.

    :param controls: (T, 2) commanded (d, alpha)
    :param landmarks_xy: (N, 2) true landmark positions
    :param landmark_ids: (N,) their ids; default 1..N
    :param detection: misses, clutter and id-less scans; drawn from a random stream of
        their own, so that without them the run is the same draw for draw
    """
    rng = np.random.default_rng(seed)
    rng_detection = np.random.default_rng([seed, 0xC1077E])
    scan_ids: list[tuple[int | None, ...]] = []
    landmarks_xy = np.asarray(landmarks_xy, dtype=np.float64).reshape(-1, 2)
    if landmark_ids is None:
        landmark_ids = np.arange(1, len(landmarks_xy) + 1, dtype=np.int64)
    pose = np.array(start_xytheta, dtype=np.float64)
    poses = [pose]
    line = 1

    def sight() -> Sighting | Scan:
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
        ids = landmark_ids[seen]
        if detection.probability < 1.0:
            detected = rng_detection.random(len(ranges))[seen] < detection.probability
            z, ids = z[detected], ids[detected]
        if not detection.unknown_ids:
            return Sighting(line=line, ids=ids, z=z)
        truth: list[int | None] = [int(i) for i in ids]
        if detection.clutter > 0.0:
            # false alarms uniform over the field's area, each at a random place in the scan
            count = int(rng_detection.poisson(detection.clutter))
            reach = sensor.max_range if math.isfinite(sensor.max_range) else CLUTTER_RANGE_UNLIMITED
            half = min(sensor.fov, 2 * math.pi) / 2
            rows = list(z)
            for _ in range(count):
                bearing, u, at = rng_detection.random(3).tolist()
                rng_clutter = reach * math.sqrt(u)
                place = int(at * (len(rows) + 1))
                rows.insert(place, np.array([(2 * bearing - 1) * half, max(rng_clutter, 1e-3)]))
                truth.insert(place, None)
            z = np.array(rows).reshape(-1, 2)
        scan_ids.append(tuple(truth))
        return Scan(line=line, z=z)

    events: list[AnyEvent] = [sight()]
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
    with_ids = tuple(e for e in events if isinstance(e, Control | Sighting))
    return Simulation(
        with_ids
        if not detection.unknown_ids
        else tuple(e for e in with_ids if isinstance(e, Control)),
        np.array(poses),
        landmark_ids.copy(),
        landmarks_xy.copy(),
        tuple(scan_ids) if detection.unknown_ids else None,
        tuple(events) if detection.unknown_ids else None,
    )
