"""The Victoria Park run (Guivant and Nebot 2001): a car with a laser among trees.

Its reader (:mod:`ekfviz.io.victoria`) gives speed-and-steering controls and id-less
scans of trunks. The source implies the car's models: the Ackermann vehicle driven by
the rear-left encoder, the laser mounted ahead and to the left of the rear axle, its own
noise defaults, detections beyond the laser's useful range dropped; and the GPS track
(``gps.dat``, optional) as the reference the estimated path is fitted to at the end.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ekfviz.core.batch import EventBatch
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent, Scan
from ekfviz.core.types import FloatArray
from ekfviz.evaluation.reference import JUMP_M, fit_reference
from ekfviz.filters.model_ekf import ModelEkfSlam
from ekfviz.io import victoria
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.models.ackermann import Ackermann
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.sources.base import (
    FittedReference,
    Given,
    Models,
    Source,
    SourceArgs,
    SourceOption,
    register,
)

PANEL = "Victoria Park"


@dataclass(frozen=True, slots=True)
class VictoriaDefaults:
    """The defaults of a Victoria Park replay (every option left at its classic default)."""

    sigma_speed: float = 0.5  # m/s, per input
    sigma_steering: float = math.radians(1.5)  # 3 degrees: 5.48 m RMSE against GPS, 1.5: 5.24
    sigma_bearing: float = math.radians(1.0)
    sigma_range: float = 0.5
    init_pose_sigma: tuple[float, float, float] = (0.1, 0.1, math.radians(1.0))
    laser_ahead: float = 3.78  # a, metres ahead of the rear axle
    laser_left: float = 0.50  # b, metres to the left
    max_range: float = 30.0  # detections farther than this are not used (laser range, trunk size)


VICTORIA = VictoriaDefaults()
SIGMA_SPEED = SourceOption(
    "sigma_speed",
    float,
    "Sigma of the encoder speed (m/s) per input.",
    default=VICTORIA.sigma_speed,
    show_default=True,
    panel=PANEL,
    min=0.0,
)
SIGMA_STEERING = SourceOption(
    "sigma_steering",
    float,
    "Sigma of the steering angle (rad) per input \\[default: 0.0262, 1.5 degrees].",
    default=VICTORIA.sigma_steering,
    panel=PANEL,
    min=0.0,
)


@register
@dataclass(frozen=True, slots=True)
class VictoriaSource(Source):
    """A Victoria Park directory: ``inputs.dat``, ``measurements.dat``, maybe ``gps.dat``."""

    kind = "victoria"
    description = (
        f"a Victoria Park directory ({victoria.INPUTS}, {victoria.MEASUREMENTS}, {victoria.GPS})"
    )
    marker = f"{victoria.INPUTS} and {victoria.MEASUREMENTS}"
    options = (SIGMA_SPEED, SIGMA_STEERING)
    study_refusal = (
        "the Victoria Park run is replayed on its own (ekfviz replay DIR), not in a sweep or"
        " comparison"
    )

    path: Path
    sigma_speed: float = VICTORIA.sigma_speed
    sigma_steering: float = VICTORIA.sigma_steering

    @classmethod
    def detect(cls, path: Path) -> bool:
        return victoria.is_victoria(path)

    @classmethod
    def open(cls, path: Path, args: SourceArgs) -> VictoriaSource:
        speed, steering = args.value(SIGMA_SPEED), args.value(SIGMA_STEERING)
        assert isinstance(speed, float) and isinstance(steering, float)
        return cls(path, speed, steering)

    @property
    def files(self) -> list[Path]:
        return [self.path / victoria.INPUTS, self.path / victoria.MEASUREMENTS]

    def file_of(self, motion: bool) -> Path | None:
        return self.path / (victoria.INPUTS if motion else victoria.MEASUREMENTS)

    @property
    def progress_paths(self) -> list[Path]:
        return self.files  # read side by side

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        """The run's events, without the detections beyond the range used."""
        return _far_dropped(victoria.read_victoria(self.path, progress), VICTORIA.max_range)

    def models(self, params: FilterParams, given: Given) -> Models:
        """The Ackermann vehicle and the laser's offset.

        :raises InputError: an option of the (d, alpha) motion model given (the vehicle
            takes speed and steering: it would be ignored), a ``gps.dat`` that is there
            but does not read
        """
        for name, flag in _D_ALPHA_OPTIONS:
            if given(name):
                raise InputError(
                    self.path, 0, f"{flag} is for logs of (d, alpha) controls, not a"
                    " Victoria Park directory: its vehicle takes speed and steering"
                    " (--sigma-speed, --sigma-steering)",
                )  # fmt: skip
        if os.path.lexists(self.path / victoria.GPS):  # optional, but a bad one is refused
            victoria.read_gps(self.path)
        v = VICTORIA
        changes: dict[str, Any] = {
            name: getattr(v, name)
            for name in ("sigma_bearing", "sigma_range", "init_pose_sigma")
            if not given(name)
        }
        params = replace(params, **changes)
        sensor = RangeBearing(v.laser_ahead, v.laser_left)
        vehicle = Ackermann(sigma_speed=self.sigma_speed, sigma_steering=self.sigma_steering)
        # the records report the laser's pose: the GPS antenna sits above it (fitted to
        # the data, the antenna is 4.0 m ahead and 0.75 m left of the rear axle), so
        # the path compared with GPS is the laser's, and the scans start at the pose
        slam = ModelEkfSlam(
            params, vehicle=vehicle, sensor=sensor, reported_point=(sensor.a, sensor.b)
        )
        parameters: dict[str, object] = dict(
            sigma_speed=self.sigma_speed, sigma_steering=self.sigma_steering,
            wheelbase=vehicle.wheelbase, encoder_offset=vehicle.encoder_offset,
            laser_ahead=sensor.a, laser_left=sensor.b, max_range=v.max_range,
            reported_point="laser",
        )  # fmt: skip
        return Models(
            params, slam, sensor, RangeBearing(), parameters,
            builtin_only="the Victoria Park run needs the built-in filter (--filter ekf)",
        )  # fmt: skip

    def reference(self) -> GpsReference:
        return GpsReference(self.path)


# the options of the (d, alpha) motion model (parameter, flag), which the vehicle ignores
_D_ALPHA_OPTIONS = (
    ("sigma_x", "--sigma-x"),
    ("sigma_y", "--sigma-y"),
    ("sigma_alpha", "--sigma-alpha"),
    ("odometry_scale", "--odometry-scale"),
    ("odometry_bias", "--odometry-bias"),
    ("motion_noise", "--motion-noise"),
)


@dataclass(slots=True)
class GpsReference:
    """The GPS track, fitted rigidly to the laser's estimated path at the end."""

    path: Path
    key: str = "gps"
    _track: list[FloatArray] = field(default_factory=list)  # (k, 4): t, step, x, y

    def add(self, events: EventBatch) -> None:
        timed = np.flatnonzero(~np.isnan(events.times))
        if len(timed):
            self._track.append(
                np.column_stack([events.times[timed], events.steps[timed], events.poses[timed, :2]])
            )

    def fit(self, warn: WarningCallback) -> FittedReference | None:
        """The fit and its figures; None (``warn`` says why) without a usable GPS."""
        try:
            gps_t, gps_xy = victoria.read_gps(self.path)
        except InputError as error:
            warn(f"no GPS reference: {error}")
            return None
        track = np.concatenate([np.zeros((0, 4)), *self._track])
        if len(track) < 2:
            return None
        try:
            fit = fit_reference(track[:, 0], track[:, 2:4], gps_t, gps_xy)
        except ValueError as error:
            warn(f"no GPS reference: {error}")
            return None
        steps = np.round(np.interp(fit.times, track[:, 0], track[:, 1]))
        results: dict[str, object] = {
            "rmse_m": fit.rmse,
            "max_error_m": float(fit.errors.max()),
            "points": len(fit.times),
            "jumps": int(fit.jumps.sum()),
            "rmse_without_jumps_m": fit.rmse_without_jumps,
        }
        return FittedReference(fit, steps, results, _summary(results))


def _summary(gps: dict[str, Any]) -> str:
    """The report's line of a fit."""
    count = gps["jumps"]
    without = (
        f" ({gps['rmse_without_jumps_m']:.2f} m without the {count} fix"
        f"{'es' if count != 1 else ''} over {JUMP_M:g} m off"
        f" {'their' if count != 1 else 'its'} neighbours' line)"
        if count
        else ""
    )
    return (
        f"GPS reference (fitted rigidly): RMSE {gps['rmse_m']:.2f} m{without},"
        f" largest error {gps['max_error_m']:.2f} m over {gps['points']} fixes"
    )


def _far_dropped(events: Iterator[AnyEvent], max_range: float) -> Iterator[AnyEvent]:
    """Scans without their detections beyond ``max_range``."""
    for event in events:
        if isinstance(event, Scan):
            near = event.z[:, 1] <= max_range
            if not near.all():
                diameters = None if event.diameters is None else event.diameters[near]
                event = event._replace(z=event.z[near], diameters=diameters)
        yield event
