"""The scenarios ``ekfviz simulate`` knows: a route, a field of landmarks and a sensor.

- ``classic``: the run of the reference (6 landmarks, the pentagon of 29 controls),
  every landmark seen at every step;
- ``edge``: the classic format's corner cases, every landmark seen at every step: a start
  away from the origin heading nearly pi, landmarks right behind the robot (bearings on
  both sides of +-pi), the heading crossing +-pi, a single turn of over pi, a robot that
  stands still (a control of d = alpha = 0) and one that turns on the spot (d = 0);
- ``loop``: a closed stadium-shaped route of ``steps`` controls through a field of
  ``landmarks`` landmarks, seen by a sensor of limited range and field of view, so that
  landmarks enter and leave view, are first seen mid-run, and the loop closes.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.sim.simulate import (
    CLASSIC_LANDMARKS_XY,
    Detection,
    Noise,
    Sensor,
    Simulation,
    classic_controls,
    simulate,
)


class ScenarioName(str, enum.Enum):
    CLASSIC = "classic"
    EDGE = "edge"
    LOOP = "loop"


@dataclass(frozen=True, slots=True)
class Scenario:
    """A route (controls), the true landmarks with their ids, and the sensor."""

    name: ScenarioName
    controls: FloatArray
    landmark_ids: IntArray
    landmarks_xy: FloatArray
    sensor: Sensor
    noise: Noise  # the scenario's own true noise, used when none is given
    init_pose_sigma: tuple[float, float, float]  # its own prior of the start, likewise
    # the mean of the prior of the start (the filter's init_pose)
    start_xytheta: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def run(
        self,
        noise: Noise | None = None,
        seed: int = 0,
        init_pose_sigma: tuple[float, float, float] | None = None,
        detection: Detection | None = None,
        laps: int = 1,
    ) -> Simulation:
        """Simulate the scenario; the true start is drawn from N(0, diag(init_pose_sigma^2)),
        the prior a filter starting at (0, 0, 0) with that covariance assumes.

        :param noise: the true noise; default the scenario's own
        :param init_pose_sigma: the prior of the start; default the scenario's own
        :param detection: misses, clutter, id-less scans
        :param laps: drive the route this many times
        """
        if init_pose_sigma is None:
            init_pose_sigma = self.init_pose_sigma
        rng = np.random.default_rng([seed, 0x5EED])  # a stream apart from the run's noise
        start = np.asarray(self.start_xytheta, dtype=np.float64) + rng.normal(
            0.0, 1.0, 3
        ) * np.asarray(init_pose_sigma, dtype=np.float64)
        return simulate(
            np.tile(self.controls, (laps, 1)),
            self.landmarks_xy,
            self.noise if noise is None else noise,
            seed=seed,
            start_xytheta=start,
            sensor=self.sensor,
            landmark_ids=self.landmark_ids,
            detection=Detection() if detection is None else detection,
        )


def classic() -> Scenario:
    """The classic run of the reference."""
    return Scenario(
        name=ScenarioName.CLASSIC,
        controls=classic_controls(),
        landmark_ids=np.arange(1, 7, dtype=np.int64),
        landmarks_xy=CLASSIC_LANDMARKS_XY.copy(),
        sensor=Sensor(),
        noise=Noise(),
        init_pose_sigma=(0.02, 0.02, 0.1),
    )


EDGE_START = (4.0, -2.0, math.pi - 0.005)


def edge() -> Scenario:
    """The classic format's corner cases (see the module docstring): 6 landmarks, 26
    controls, the classic noise and prior, a start at :data:`EDGE_START`."""
    controls = np.array(
        [(1.0, 0.0)] * 3  # straight on, landmark 1 right behind: bearings of about +-pi
        + [(1.0, 0.2), (1.0, 0.0), (1.0, 0.0)]  # the heading crosses +-pi
        + [(0.0, 0.0), (0.0, 0.6)]  # standing still, then turning on the spot
        + [(0.5, 3.3)]  # one turn of over pi
        + [(1.0, 0.0)] * 3
        + [(1.0, -1.0), (1.0, -1.0), (1.0, 0.0), (1.0, 0.0)]
        + [(0.8, 2.0), (1.0, 0.0), (1.0, 0.0), (1.0, -0.3)]
        + [(-0.5, 0.0), (1.0, 1.6), (1.0, 1.6), (1.0, 0.0), (1.0, 1.6), (1.0, 0.0)],
        dtype=np.float64,
    )
    landmarks_xy = np.array(
        [(10.0, -2.0), (-6.0, -2.05), (0.0, 3.0), (2.0, -7.0), (-3.0, -6.0), (8.0, 4.0)]
    )
    return Scenario(
        name=ScenarioName.EDGE,
        controls=controls,
        landmark_ids=np.arange(1, 7, dtype=np.int64),
        landmarks_xy=landmarks_xy,
        sensor=Sensor(),
        noise=Noise(),
        init_pose_sigma=(0.02, 0.02, 0.1),
        start_xytheta=EDGE_START,
    )


def loop(
    steps: int = 1000,
    landmarks: int = 200,
    max_range: float = 15.0,
    fov_deg: float = 180.0,
    length: float = 120.0,
    radius: float = 20.0,
    seed: int = 0,
) -> Scenario:
    """A stadium-shaped closed route among landmarks scattered around it.

    :param steps: number of controls for one lap (the route ends where it started)
    :param landmarks: number of landmarks, in a band of +-2 ``radius`` around the route
    :param max_range: sensor range in metres
    :param fov_deg: sensor field of view in degrees, centred on the heading
    :param length: length of each straight in metres
    :param radius: radius of the two half circles in metres
    :param seed: seed of the landmark field (ids are shuffled, so not in sighting order)

    The true noise is that of good wheel odometry and a range-bearing sensor: the motion
    noise grows with the square root of the step length, so that a lap drifts alike
    whatever the number of steps (sigma_x = 0.032 sqrt(d), sigma_y = 0.016 sqrt(d),
    sigma_alpha = 0.0032 sqrt(d), about 2 cm, 1 cm and 0.002 rad for 1000 steps).
    """
    if steps < 4:
        raise ValueError("a loop needs at least 4 steps")
    perimeter = 2 * length + 2 * math.pi * radius
    d = perimeter / steps
    controls = np.empty((steps, 2))
    controls[:, 0] = d
    # the heading turns by pi along each half circle: spread that over the steps that
    # fall on them, so that the route closes on itself
    s = (np.arange(steps) + 0.5) * d  # arc length at the middle of each step
    on_curve = ((s > length) & (s < length + math.pi * radius)) | (
        s > 2 * length + math.pi * radius
    )
    controls[:, 1] = 0.0
    controls[on_curve, 1] = 2 * math.pi / on_curve.sum()
    rng = np.random.default_rng([seed, 0x1A4D])
    # landmarks around the route: a point of the route plus an offset across it
    along = rng.uniform(0.0, perimeter, landmarks)
    across = rng.uniform(-0.5 * radius, 0.5 * radius, landmarks)
    centre_xy, normal_xy = _stadium(along, length, radius)
    landmarks_xy = centre_xy + across[:, None] * normal_xy
    ids = rng.permutation(np.arange(1, landmarks + 1)).astype(np.int64)
    root_d = math.sqrt(d)
    return Scenario(
        name=ScenarioName.LOOP,
        controls=controls,
        landmark_ids=ids,
        landmarks_xy=landmarks_xy,
        sensor=Sensor(max_range=max_range, fov=math.radians(fov_deg)),
        noise=Noise(
            sigma_x=round(0.032 * root_d, 6),
            sigma_y=round(0.016 * root_d, 6),
            sigma_alpha=round(0.0032 * root_d, 6),
            sigma_bearing=0.01,
            sigma_range=0.08,
        ),
        # A tight prior: with the classic 0.1 rad the EKF grows over-confident in its
        # heading long before the loop closes (see ekfviz consistency).
        init_pose_sigma=(0.01, 0.01, 0.005),
    )


def _stadium(s: FloatArray, length: float, radius: float) -> tuple[FloatArray, FloatArray]:
    """Points (K, 2) at arc length ``s`` along the stadium route starting at the origin
    heading +x and turning left, and the unit normals (K, 2) pointing to its left."""
    s = np.mod(s, 2 * length + 2 * math.pi * radius)
    xy = np.empty((len(s), 2))
    heading = np.empty(len(s))
    first = s <= length
    xy[first] = np.column_stack([s[first], np.zeros(first.sum())])
    heading[first] = 0.0
    curve1 = (s > length) & (s <= length + math.pi * radius)
    phi = (s[curve1] - length) / radius
    xy[curve1] = np.column_stack([length + radius * np.sin(phi), radius - radius * np.cos(phi)])
    heading[curve1] = phi
    second = (s > length + math.pi * radius) & (s <= 2 * length + math.pi * radius)
    t = s[second] - length - math.pi * radius
    xy[second] = np.column_stack([length - t, np.full(second.sum(), 2 * radius)])
    heading[second] = math.pi
    curve2 = s > 2 * length + math.pi * radius
    phi = (s[curve2] - 2 * length - math.pi * radius) / radius
    xy[curve2] = np.column_stack([-radius * np.sin(phi), radius + radius * np.cos(phi)])
    heading[curve2] = math.pi + phi
    normal = np.column_stack([-np.sin(heading), np.cos(heading)])
    return xy, normal
