"""What ``replay`` needs for id-less scans and the Victoria Park run: options, the filter
and its models, the associator, the GPS reference and the association report."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer
from typer._click.core import ParameterSource

from ekfviz.association import AssociationParams, Associator, Method
from ekfviz.association.evaluation import AssociationTally
from ekfviz.cli.common import _option, out, warn
from ekfviz.cli.sources import OpenedLog
from ekfviz.core.records import AnyEvent, EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.reference import JUMP_M, ReferenceFit, fit_reference
from ekfviz.filters.ekf import EkfSlam, FilterParams
from ekfviz.filters.model_ekf import ModelEkfSlam
from ekfviz.io.detect import LogKind
from ekfviz.io.errors import InputError
from ekfviz.io.text import ProgressCallback
from ekfviz.io.victoria import GPS, read_gps
from ekfviz.models.ackermann import Ackermann
from ekfviz.models.range_bearing import RangeBearing

if TYPE_CHECKING:
    from ekfviz.viz.run import RunLogger

ASSOCIATION_PANEL = "Association (id-less scans)"
VICTORIA_PANEL = "Victoria Park"

AssociationOption = Annotated[
    Method | None,
    _option(
        "known: the log's ids; nn or jcbb for id-less scans"
        " [default: known for logs with ids, jcbb for logs with scans].",
        ASSOCIATION_PANEL,
        show_default=False,
    ),
]
GateProbability = Annotated[
    float,
    _option(
        "Probability of the chi-square gates (individual and joint).",
        ASSOCIATION_PANEL,
        min=0.5,
        max=0.999999,
    ),
]
Confirm = Annotated[
    int,
    _option(
        "Sightings (the first included) that confirm a new landmark.", ASSOCIATION_PANEL, min=1
    ),
]
ConfirmWindow = Annotated[
    int,
    _option("Scans from a new landmark's first in which to confirm it.", ASSOCIATION_PANEL, min=1),
]


def association_params(
    association: Method | None, gate_probability: float, confirm: int, confirm_window: int
) -> AssociationParams | None:
    """The association the options ask for: none for ``known``, else the method (jcbb
    by default) with its gate and confirmation."""
    if association is Method.KNOWN:
        return None
    return AssociationParams(
        method=Method.JCBB if association is None else association,
        gate_probability=gate_probability,
        confirm=confirm,
        confirm_window=confirm_window,
    )


def study_association(
    data: Path,
    association: Method | None,
    gate_probability: float,
    confirm: int,
    confirm_window: int,
) -> AssociationParams | None:
    """The association of a study's runs (sweep, compare), as a replay's: none for
    ``known``, else the method asked for (jcbb by default) for the log's id-less scans.
    Victoria Park is refused in one line: its vehicle and sensor models are the replay's.
    """
    from ekfviz.io.detect import open_source

    try:
        kind = open_source(data, None).kind
    except InputError:
        kind = None  # the study's own reading says what is wrong with it
    if kind is LogKind.VICTORIA:
        raise InputError(
            data, 0, "the Victoria Park run is replayed on its own (ekfviz replay DIR), not in"
            " a sweep or comparison",
        )  # fmt: skip
    return association_params(association, gate_probability, confirm, confirm_window)


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
DEFAULT_ASSOCIATION = AssociationParams()

SigmaSpeed = Annotated[
    float, _option("Sigma of the encoder speed (m/s) per input.", VICTORIA_PANEL, min=0.0)
]
SigmaSteering = Annotated[
    float,
    _option(
        "Sigma of the steering angle (rad) per input \\[default: 0.0262, 1.5 degrees].",
        VICTORIA_PANEL,
        min=0.0,
        show_default=False,
    ),
]


@dataclass(slots=True)
class ReplaySetup:
    """One replay's filter (the built-in one, with its models), associator and reference;
    ``slam`` is None for a protocol filter (which cannot replay scans)."""

    data: Path
    params: FilterParams
    truth: GroundTruth | None
    slam: EkfSlam | None
    sensor: RangeBearing  # the sensor seen from the records' pose (the laser's, at Victoria Park)
    associator: Associator | None
    victoria: bool
    parameters: dict[str, object]
    tally: AssociationTally
    _track: list[tuple[float, int, float, float]] = field(default_factory=list)
    _scans: bool = False
    _last: EventRecord | None = None

    def events(self, opened: OpenedLog, progress: ProgressCallback | None) -> Iterator[AnyEvent]:
        """The log's events; for Victoria Park without the detections beyond the range used."""
        if self.victoria:
            return _far_dropped(opened.events(progress), VICTORIA.max_range)
        return opened.events(progress)

    def add(self, record: EventRecord) -> None:
        self._last = record
        if record.association is not None:
            self._scans = True
            self.tally.add(record)
        if self.victoria and record.time is not None:
            self._track.append(
                (record.time, record.step, float(record.pose[0]), float(record.pose[1]))
            )

    def truth_of(self, last: EventRecord) -> GroundTruth | None:
        """The truth under the estimate's ids (the association's pairing for scans)."""
        if self.truth is None or not self._scans:
            return self.truth
        return self.tally.relabelled_truth(last.landmark_ids)

    def truth_of_last(self) -> GroundTruth | None:
        """The truth as the evaluation of the last record saw it."""
        return self.truth if self._last is None else self.truth_of(self._last)

    def finish(self, logger: RunLogger) -> dict[str, object]:
        """The association report and, for Victoria Park, the GPS reference (logged too)."""
        extra: dict[str, object] = {}
        last = self._last
        if last is None:
            return extra
        if self._scans:
            extra["association"] = self.tally.report(last.landmark_ids)
        if self.victoria:
            fit = self.gps_fit()
            if fit is not None:
                from ekfviz.viz.association import log_reference

                track = np.array(self._track)
                steps = np.interp(fit.times, track[:, 0], track[:, 1])
                recorder = logger.recorder
                log_reference(recorder._rec.rec, recorder._rec.path, fit, np.round(steps))
                extra["gps"] = {
                    "rmse_m": fit.rmse,
                    "max_error_m": float(fit.errors.max()),
                    "points": len(fit.times),
                    "jumps": int(fit.jumps.sum()),
                    "rmse_without_jumps_m": fit.rmse_without_jumps,
                }
        if extra:  # for ekfviz info
            logger.add_results(extra)
        return extra

    def gps_fit(self) -> ReferenceFit | None:
        try:
            gps_t, gps_xy = read_gps(self.data)
        except InputError as error:
            warn(f"no GPS reference: {error}")
            return None
        if len(self._track) < 2:
            return None
        track = np.array(self._track)
        try:
            return fit_reference(track[:, 0], track[:, 2:4], gps_t, gps_xy)
        except ValueError as error:
            warn(f"no GPS reference: {error}")
            return None

    def print_summary(self, extra: dict[str, object]) -> None:
        association = extra.get("association")
        if isinstance(association, dict):
            text = ", ".join(f"{k} {_fmt(v)}" for k, v in association.items())
            out.print(f"Association: {text}", soft_wrap=True)
        gps = extra.get("gps")
        if isinstance(gps, dict):
            count = gps.get("jumps", 0)
            without = (
                f" ({gps['rmse_without_jumps_m']:.2f} m without the {count} fix"
                f"{'es' if count != 1 else ''} over {JUMP_M:g} m off"
                f" {'their' if count != 1 else 'its'} neighbours' line)"
                if count
                else ""
            )
            out.print(
                f"GPS reference (fitted rigidly): RMSE {gps['rmse_m']:.2f} m{without},"
                f" largest error {gps['max_error_m']:.2f} m over {gps['points']} fixes",
                soft_wrap=True,
            )


def _fmt(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def _far_dropped(events: Iterator[AnyEvent], max_range: float) -> Iterator[AnyEvent]:
    """Scans without their detections beyond ``max_range``."""
    from ekfviz.core.records import Scan

    for event in events:
        if isinstance(event, Scan):
            near = event.z[:, 1] <= max_range
            if not near.all():
                diameters = None if event.diameters is None else event.diameters[near]
                event = replace(event, z=event.z[near], diameters=diameters)
        yield event


def replay_setup(
    ctx: typer.Context,
    opened: OpenedLog,
    params: FilterParams,
    builtin: bool,
    truth: GroundTruth | None,
    association: Method | None,
    gate_probability: float,
    confirm: int,
    confirm_window: int,
    sigma_speed: float,
    sigma_steering: float,
) -> ReplaySetup:
    """The filter, its models and the associator for this input."""
    data = opened.source.path
    victoria = opened.source.kind is LogKind.VICTORIA
    parameters: dict[str, Any] = {}

    def default(name: str) -> bool:
        return ctx.get_parameter_source(name) in (ParameterSource.DEFAULT, None)

    sensor = RangeBearing()
    recorded_sensor = sensor  # the sensor as seen from the records' pose
    if victoria and not builtin:
        raise InputError(data, 0, "the Victoria Park run needs the built-in filter (--filter ekf)")
    if victoria:
        if (data / GPS).exists():  # optional, but a bad one is refused before any work
            read_gps(data)
        v = VictoriaDefaults()
        changes: dict[str, Any] = {
            name: getattr(v, name)
            for name in ("sigma_bearing", "sigma_range", "init_pose_sigma")
            if default(name)
        }
        params = replace(params, **changes)
        sensor = RangeBearing(v.laser_ahead, v.laser_left)
        vehicle = Ackermann(sigma_speed=sigma_speed, sigma_steering=sigma_steering)
        # the records report the laser's pose: the GPS antenna sits above it (fitted to
        # the data, the antenna is 4.0 m ahead and 0.75 m left of the rear axle), so
        # the path compared with GPS is the laser's, and the scans start at the pose
        slam: EkfSlam = ModelEkfSlam(
            params, vehicle=vehicle, sensor=sensor, reported_point=(sensor.a, sensor.b)
        )
        parameters.update(
            sigma_speed=sigma_speed, sigma_steering=sigma_steering,
            wheelbase=vehicle.wheelbase, encoder_offset=vehicle.encoder_offset,
            laser_ahead=sensor.a, laser_left=sensor.b, max_range=v.max_range,
            reported_point="laser",
        )  # fmt: skip
    else:
        for name in ("sigma_speed", "sigma_steering"):
            if not default(name):
                raise InputError(
                    data, 0, f"--{name.replace('_', '-')} is for Victoria Park runs only"
                )
        slam = EkfSlam(params)
    associator: Associator | None = None
    assoc = association_params(association, gate_probability, confirm, confirm_window)
    if assoc is not None:
        Associator.check_filter(slam, assoc)
        associator = Associator(
            assoc, sensor, params.R, scan_truth=None if truth is None else truth.scan_ids
        )
        # only where it applies: a classic log or an MRCLAM dataset has ids, never scans
        with_ids = opened.source.kind in (LogKind.CLASSIC, LogKind.MRCLAM)
        if not with_ids or not default("association"):
            parameters.update(assoc.as_dict())
    return ReplaySetup(
        data=data, params=params, truth=truth, slam=slam if builtin else None,
        sensor=recorded_sensor, associator=associator, victoria=victoria,
        parameters=parameters, tally=AssociationTally(truth, recorded_sensor),
    )  # fmt: skip
