"""What ``replay`` and ``calibrate`` share about the log they read: its kind (a file or an
MRCLAM dataset directory), its truth, the start pose and the motion-noise model."""

from __future__ import annotations

import enum
import itertools
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import FILTER_NOISE, FILTER_OPTIONS, _option, log_events, warn
from ekfviz.core.records import AnyEvent, Control
from ekfviz.core.truth import GroundTruth
from ekfviz.filters.ekf import FilterParams, MotionNoise
from ekfviz.io.detect import LogSource, open_source
from ekfviz.io.text import ProgressCallback
from ekfviz.io.truth import checked_against, read_truth


class MotionNoiseChoice(str, enum.Enum):
    AUTO = "auto"
    PER_STEP = MotionNoise.PER_STEP.value
    PER_SQRT_SECOND = MotionNoise.PER_SQRT_SECOND.value


RobotOption = Annotated[
    int | None,
    typer.Option(help="The robot of an MRCLAM dataset directory [default: 1].", show_default=False),
]
NoTruthOption = Annotated[
    bool,
    typer.Option("--no-truth", help="Ignore a dataset's own ground-truth files."),
]
InitPoseOption = Annotated[
    tuple[float, float, float] | None,
    _option(
        "The filter's initial pose [default: the true pose at the first event where the"
        " log comes with a timestamped truth (MRCLAM), else 0 0 0].",
        FILTER_OPTIONS,
        metavar="X Y THETA",
        show_default=False,
    ),
]
MotionNoiseOption = Annotated[
    MotionNoiseChoice,
    _option(
        "What the motion sigmas mean: per-step, Q = diag(sigma^2) per control (m, rad);"
        " per-sqrt-second, Q = diag(sigma^2) * dt for a control spanning dt seconds"
        " (m/sqrt(s), rad/sqrt(s)); auto: per-sqrt-second for velocity odometry (MRCLAM),"
        " else per-step.",
        FILTER_NOISE,
    ),
]


GateOption = Annotated[
    float | None,
    _option(
        "Reject an observation of a known landmark whose NIS (2 dof, against the state"
        " before its line) exceeds this, as an outlier (13.8: the 99.9 % bound) [default:"
        " no gate].",
        FILTER_OPTIONS,
        min=0.0,
        show_default=False,
    ),
]


@dataclass(frozen=True, slots=True)
class OpenedLog:
    """A log opened for a replay: its source, its truth and where that came from.

    :param truth_files: the files the truth was read from (``--truth`` or the dataset's)
    """

    source: LogSource
    truth: GroundTruth | None
    truth_files: list[Path]

    def events(self, progress: ProgressCallback | None = None) -> Iterator[AnyEvent]:
        """The log's events, checked against a ``--truth`` file's landmarks."""
        if self.source.dataset is not None:
            events = self.source.events(progress, warn)
            if self.truth is not None and len(self.truth_files) == 1:  # not the dataset's
                # a --truth file must know every landmark seen, as for a log file
                return checked_against(events, self.truth, self.truth_files[0], every_id=False)
            return events
        if self.truth is not None and self.truth_files:
            return log_events(self.source.path, self.truth, self.truth_files[0], progress)
        return log_events(self.source.path, None, None, progress)


def open_log(data: Path, robot: int | None, truth_path: Path | None, no_truth: bool) -> OpenedLog:
    """Open a log file or dataset directory and its truth (``--truth``, else the dataset's
    own unless ``--no-truth``).

    :raises InputError: a path that is no log, a truth file that cannot be read
    """
    source = open_source(data, robot)
    if truth_path is not None:
        return OpenedLog(source, read_truth(truth_path), [truth_path])
    if not no_truth and source.dataset is not None:
        if source.dataset.has_truth:
            return OpenedLog(source, source.own_truth(), source.dataset.truth_files)
        missing = [p.name for p in source.dataset.truth_files if not p.is_file()]
        warn(
            f"{data}: no {' or '.join(missing)}, replaying without the dataset's truth"
            " (expected both truth files beside Barcodes.dat; --no-truth to go without)"
        )
    return OpenedLog(source, None, [])


def first_time(events: Iterator[AnyEvent]) -> tuple[float | None, Iterator[AnyEvent]]:
    """When the log's first event begins (None untimed), and the events, none lost."""
    first = next(events, None)
    if first is None:
        return None, iter(())
    start = first.time
    if isinstance(first, Control) and start is not None and first.dt is not None:
        start -= first.dt
    return start, itertools.chain([first], events)


def resolve(
    params: FilterParams,
    opened: OpenedLog,
    start: float | None,
    init_pose: tuple[float, float, float] | None,
    motion_noise: MotionNoiseChoice,
    gate: float | None = None,
) -> tuple[FilterParams, list[str]]:
    """The filter's start pose and motion-noise model, and notes saying what was chosen."""
    notes: list[str] = []
    if motion_noise is MotionNoiseChoice.AUTO:
        model = (
            MotionNoise.PER_SQRT_SECOND if opened.source.velocity_odometry else MotionNoise.PER_STEP
        )
    else:
        model = MotionNoise(motion_noise.value)
    if init_pose is None and opened.truth is not None and opened.truth.track_times is not None:
        true_start = None if start is None else opened.truth.pose_at(start)
        if true_start is not None:
            init_pose = (float(true_start[0]), float(true_start[1]), float(true_start[2]))
            notes.append(
                "The filter starts at the true pose of the first event (t = "
                f"{start:.3f} s): x {init_pose[0]:.4f}, y {init_pose[1]:.4f}, theta"
                f" {init_pose[2]:.4f}, so that its errors are in the truth's frame"
                " (--init-pose X Y THETA to choose another)"
            )
        else:
            notes.append(
                "The first event is outside the true track: the filter starts at 0 0 0"
                " (--init-pose X Y THETA to choose)"
            )
    return replace(
        params,
        motion_noise=model,
        init_pose=init_pose or params.init_pose,
        gate=params.gate if gate is None else gate,
    ), notes
