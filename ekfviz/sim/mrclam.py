"""A simulated robot in the layout of the UTIAS MRCLAM datasets (numpy only).

One robot (robot 1) drives a smooth random route inside a rectangular arena among
``landmarks`` landmarks (subjects 6, 7, ...) and four other robots (subjects 2-5, parked),
each subject with its own barcode. Its odometry, at a fixed rate, reports the commanded
forward and angular velocity; the true robot moves by the filter's motion model with
noise per square-root second (Q = diag(sigma^2) dt over each span dt). Its camera, at
its own rate and time stamps, sees every subject within range and field of view with
noisy (bearing, range), and now and then a barcode no subject has. The Vicon-like truth
holds the true pose at every odometry and measurement time, and the surveyed landmarks.

Times are whole milliseconds after a Unix time, written with 3 decimals as in MRCLAM,
so that the reader's spans are the simulator's. Everything is deterministic in the seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.io.mrclam import BARCODES, LANDMARKS
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import motion

START_TIME_S = 1_248_444_000.0  # a Unix time, as MRCLAM's (July 2009)
UNKNOWN_BARCODE = 99  # seen now and then, belongs to no subject
ROBOTS = 5


@dataclass(frozen=True, slots=True)
class MrclamNoise:
    """True noise of the simulated robot: motion per sqrt(s), measurement per reading."""

    sigma_x: float = 0.03  # m / sqrt(s), along the heading
    sigma_y: float = 0.01  # m / sqrt(s), sideways
    sigma_alpha: float = 0.03  # rad / sqrt(s)
    sigma_bearing: float = 0.02  # rad
    sigma_range: float = 0.05  # m
    # systematic odometry errors (as FilterParams.corrected takes them out): the robot
    # truly drives k_d v dt and turns k_alpha omega dt + b v dt when its odometry reads
    # (v, omega) over dt; (1, 1) and 0: an odometry without them
    odometry_scale: tuple[float, float] = (1.0, 1.0)
    turn_bias: float = 0.0  # b, rad per metre driven


@dataclass(frozen=True, slots=True)
class MrclamWorld:
    """What the simulated dataset looks like.

    :param duration_s: length of the run
    :param odometry_ms: odometry period (20 ms: 50 Hz)
    :param measurement_ms: camera period, offset from the odometry's by 7 ms
    """

    landmarks: int = 15
    arena_xy: tuple[float, float] = (8.0, 10.0)
    duration_s: float = 120.0
    odometry_ms: int = 20
    measurement_ms: int = 200
    max_range: float = 5.0
    fov: float = math.radians(120.0)
    speed: float = 0.15  # m/s


def _barcodes(rng: np.random.Generator, subjects: int) -> list[int]:
    """Distinct barcodes in 1..98 for subjects 1..subjects (99 is the unknown one)."""
    return [int(b) for b in rng.choice(np.arange(1, UNKNOWN_BARCODE), subjects, replace=False)]


def simulate_mrclam(
    *,
    seed: int = 0,
    world: MrclamWorld = MrclamWorld(),
    noise: MrclamNoise = MrclamNoise(),
) -> dict[str, str]:
    """Simulate robot 1 and return the dataset's files by name, as text."""
    rng = np.random.default_rng(seed)
    width, height = world.arena_xy
    n_subjects = ROBOTS + world.landmarks
    barcodes = _barcodes(rng, n_subjects)
    subject_xy = np.column_stack(
        [rng.uniform(0.5, width - 0.5, n_subjects), rng.uniform(0.5, height - 0.5, n_subjects)]
    )
    pose = np.array([width / 2, height / 2, rng.uniform(-math.pi, math.pi)])
    wander = rng.uniform(-0.4, 0.4, int(world.duration_s) + 1)  # rad/s, one a second
    total_ms = int(world.duration_s * 1000)
    odometry_ms = np.arange(0, total_ms, world.odometry_ms)
    measurement_ms = np.arange(7, total_ms, world.measurement_ms)
    times_ms = np.union1d(odometry_ms, measurement_ms)
    is_odometry = np.isin(times_ms, odometry_ms)
    is_measurement = np.isin(times_ms, measurement_ms)

    odometry: list[str] = []
    measurements: list[str] = []
    track: list[str] = []
    v = omega = 0.0
    q = np.array([noise.sigma_x, noise.sigma_y, noise.sigma_alpha])
    previous_ms = int(times_ms[0])
    for t_ms, odo, meas in zip(times_ms.tolist(), is_odometry, is_measurement, strict=True):
        dt = (t_ms - previous_ms) / 1000.0
        if dt > 0:  # the true motion over the span, with the velocities in force
            e_x, e_y, e_a = rng.normal(0.0, 1.0, 3) * q * math.sqrt(dt)
            theta = pose[2]
            k_d, k_alpha = noise.odometry_scale
            d_true = k_d * v * dt
            alpha_true = k_alpha * omega * dt + noise.turn_bias * v * dt
            moved = motion(pose, d_true + e_x, alpha_true + e_a)
            moved[:2] += e_y * np.array([-math.sin(theta), math.cos(theta)])
            pose = moved
        previous_ms = t_ms
        stamp = f"{START_TIME_S + t_ms / 1000.0:.3f}"
        track.append(f"{stamp}\t{pose[0]:.8f}\t{pose[1]:.8f}\t{pose[2]:.8f}")
        if odo:
            v, omega = _command(pose, world, float(wander[t_ms // 1000]))
            odometry.append(f"{stamp}\t{v:.6f}\t{omega:.6f}")
        if meas:
            measurements += _sightings(stamp, pose, subject_xy, barcodes, world, noise, rng)
    subjects = "\n".join(f"{i + 1}\t{b}" for i, b in enumerate(barcodes))
    landmarks = "\n".join(
        f"{i + 1}\t{subject_xy[i, 0]:.8f}\t{subject_xy[i, 1]:.8f}\t0.00010000\t0.00010000"
        for i in range(ROBOTS, n_subjects)
    )
    head = f"# ekfviz simulate --layout mrclam --seed {seed} (the UTIAS MRCLAM layout)\n"
    return {
        BARCODES: head + "# Subject #    Barcode #\n" + subjects + "\n",
        LANDMARKS: head + "# Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]\n"
        + landmarks + "\n",
        "Robot1_Odometry.dat": head
        + "# Time [s]    forward velocity [m/s]    angular velocity[rad/s]\n"
        + "\n".join(odometry) + "\n",
        "Robot1_Measurement.dat": head + "# Time [s]    Subject #    range [m]    bearing [rad]\n"
        + "\n".join(measurements) + "\n",
        "Robot1_Groundtruth.dat": head + "# Time [s]    x [m]    y [m]    orientation [rad]\n"
        + "\n".join(track) + "\n",
    }  # fmt: skip


def _command(pose: FloatArray, world: MrclamWorld, wander: float) -> tuple[float, float]:
    """Forward and angular velocity: ``wander``, turning back towards the arena's
    middle near its walls."""
    width, height = world.arena_xy
    x, y, theta = pose.tolist()
    margin = 1.5
    near_wall = x < margin or y < margin or x > width - margin or y > height - margin
    if near_wall:
        to_middle = math.atan2(height / 2 - y, width / 2 - x)
        omega = float(np.clip(2.0 * wrap_angle(to_middle - theta), -0.8, 0.8))
        return world.speed * 0.5, omega
    return world.speed, wander


def _sightings(
    stamp: str,
    pose: FloatArray,
    subject_xy: FloatArray,
    barcodes: list[int],
    world: MrclamWorld,
    noise: MrclamNoise,
    rng: np.random.Generator,
) -> list[str]:
    """Measurement lines (time barcode range bearing) of the subjects in view, skipping
    robot 1 itself; now and then one of the unknown barcode."""
    d = subject_xy - pose[:2]
    ranges = np.hypot(d[:, 0], d[:, 1])
    bearings = np.arctan2(d[:, 1], d[:, 0]) - pose[2]
    bearings = np.remainder(bearings + math.pi, 2 * math.pi) - math.pi
    n_range = rng.normal(0.0, noise.sigma_range, len(ranges))
    n_bearing = rng.normal(0.0, noise.sigma_bearing, len(ranges))
    seen = (ranges <= world.max_range) & (np.abs(bearings) <= world.fov / 2)
    seen[0] = False  # robot 1 does not see itself
    lines = []
    for i in np.flatnonzero(seen).tolist():
        measured_bearing = wrap_angle(float(bearings[i] + n_bearing[i]))
        lines.append(
            f"{stamp}\t{barcodes[i]}\t{abs(ranges[i] + n_range[i]):.6f}\t{measured_bearing:.6f}"
        )
    if rng.uniform() < 0.02:
        lines.append(f"{stamp}\t{UNKNOWN_BARCODE}\t{rng.uniform(1.0, 4.0):.6f}\t0.100000")
    return lines
