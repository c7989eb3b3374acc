"""A Victoria Park run generated in the dataset's layout, for the tests of the park's
reader, its association and its recording: a car with the Ackermann geometry of the real run
drives circles among trees, its laser scans them and a GPS fixes it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ekfviz.models.ackermann import Ackermann

LASER = (3.78, 0.50)


def _laser(pose: np.ndarray) -> np.ndarray:
    x, y, theta = pose
    c, s = math.cos(theta), math.sin(theta)
    return np.array([x + LASER[0] * c - LASER[1] * s, y + LASER[0] * s + LASER[1] * c])


def make_park(folder: Path, seed: int = 0, seconds: float = 90.0) -> dict[str, np.ndarray]:
    """Write inputs.dat, measurements.dat and gps.dat of a generated run; return its truth."""
    rng = np.random.default_rng(seed)
    car = Ackermann()
    angles = rng.uniform(0, 2 * math.pi, 70)
    radii = 30.0 + rng.uniform(-14.0, 14.0, 70)
    trees = np.column_stack([radii * np.sin(angles), 30.0 - radii * np.cos(angles)])
    diameters = rng.uniform(0.2, 0.6, len(trees))
    steering = math.atan(car.wheelbase / 30.0)  # a circle of 30 m through the origin
    pose = np.zeros(3)
    inputs, scans, laser_path, axle_path = [], [], [], []
    gps: list[tuple[float, float, float]] = []
    rotation = np.array([[math.cos(0.7), -math.sin(0.7)], [math.sin(0.7), math.cos(0.7)]])
    dt = 0.025
    for k in range(1, int(seconds / dt) + 1):
        t = 1000.0 + k * dt
        speed = 3.0 + 0.5 * math.sin(0.05 * t)
        pose = car.motion(pose, speed, steering, dt)
        inputs.append((t, speed + rng.normal(0, 0.05), steering + rng.normal(0, 0.002)))
        laser = _laser(pose)
        laser_path.append((t, *laser))
        axle_path.append((t, *pose[:2]))
        if k % 8 == 0:  # a scan at 5 Hz
            d = trees - laser
            ranges = np.hypot(d[:, 0], d[:, 1])
            bearings = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - pose[2])))
            seen = (ranges < 30.0) & (np.abs(bearings) < math.pi / 2 - 0.05)
            for i in np.flatnonzero(seen):
                r = ranges[i] + rng.normal(0, 0.05)
                b = bearings[i] + rng.normal(0, 0.004) + math.pi / 2  # the laser's 0..pi
                scans.append((t, r, b, diameters[i]))
        if k % 40 == 0:  # GPS at 1 Hz, in a frame of its own
            fix = rotation @ laser + (500.0, -200.0) + rng.normal(0, 0.05, 2)
            if len(gps) == 45:  # once, a fix far off for a moment (as in the real run)
                fix += (100.0, 100.0)
            gps.append((t, float(fix[0]), float(fix[1])))
    (folder / "inputs.dat").write_text("".join(f"{t:.3f} {v:.5f} {s:.6f}\n" for t, v, s in inputs))
    (folder / "measurements.dat").write_text(
        "".join(f"{t:.3f} {r:.4f} {b:.6f} {d:.3f}\n" for t, r, b, d in scans)
    )
    (folder / "gps.dat").write_text("".join(f"{t:.3f} {x:.3f} {y:.3f}\n" for t, x, y in gps))
    return {"laser": np.array(laser_path), "axle": np.array(axle_path), "trees": trees}
