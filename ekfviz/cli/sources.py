"""What the commands share about the input they open: its source (see
:mod:`ekfviz.sources`), the source options of every format, its truth, the start pose and
the motion-noise model."""

from __future__ import annotations

import enum
import functools
import inspect
import itertools
import typing
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from ekfviz.cli.common import FILTER_NOISE, FILTER_OPTIONS, _option, fail, given, warn
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams, MotionNoise
from ekfviz.core.records import AnyEvent, Control
from ekfviz.core.truth import GroundTruth
from ekfviz.io.text import ProgressCallback
from ekfviz.io.truth import checked_against, read_truth
from ekfviz.sources import (
    OwnTruth,
    Source,
    SourceArgs,
    SourceOption,
    open_source,
    source_options,
)


class MotionNoiseChoice(str, enum.Enum):
    AUTO = "auto"
    PER_STEP = MotionNoise.PER_STEP.value
    PER_SQRT_SECOND = MotionNoise.PER_SQRT_SECOND.value


NoTruthOption = Annotated[
    bool,
    typer.Option("--no-truth", help="Ignore a dataset's own ground-truth files."),
]
InitPoseOption = Annotated[
    tuple[float, float, float] | None,
    _option(
        "The filter's initial pose [default: the true pose at the first event where the"
        " log comes with a timestamped truth (MRCLAM, a bag's --truth-topic), else 0 0 0].",
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
        " (m/sqrt(s), rad/sqrt(s)); auto: what the source implies, per-sqrt-second for"
        " odometry over known times (MRCLAM, ROS 2 bags), else per-step.",
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


Command = TypeVar("Command", bound=Callable[..., Any])
NO_SOURCE_ARGS = SourceArgs()  # the default of a command's source_args (replaced)


def with_source_options(command: Command) -> Command:
    """Give a command every format's options (:func:`ekfviz.sources.source_options`) in
    place of its ``source_args: SourceArgs`` parameter, which receives them.

    A new format's options so reach every command that opens a log without an edit here.
    The options of the main panel (``--robot``) stand where ``source_args`` stands; those
    of a panel of their own come last, so that their panels follow the command's own.
    """
    signature = inspect.signature(command)
    hints = typing.get_type_hints(command, include_extras=True)
    options = source_options()
    parameters: list[inspect.Parameter] = []
    last: list[inspect.Parameter] = []
    for parameter in signature.parameters.values():
        if parameter.name != "source_args":
            parameters.append(parameter.replace(annotation=hints[parameter.name]))
            continue
        for option in options:
            declared = inspect.Parameter(
                option.name, parameter.kind, default=option.default, annotation=_annotated(option)
            )
            (parameters if option.panel is None else last).append(declared)
    parameters += last

    @functools.wraps(command)
    def run(*args: Any, **kwargs: Any) -> Any:
        values = {option.name: kwargs.pop(option.name) for option in options}
        named = frozenset(name for name in values if given(name))
        return command(*args, source_args=SourceArgs(values, named), **kwargs)

    run.__signature__ = signature.replace(parameters=parameters)  # type: ignore[attr-defined]
    run.__annotations__ = {p.name: p.annotation for p in parameters} | {"return": None}
    return typing.cast(Command, run)


def _annotated(option: SourceOption) -> Any:
    """The Typer declaration of a source option."""
    extra: dict[str, Any] = {}
    if option.metavar is not None:
        extra["metavar"] = option.metavar
    if option.min is not None:
        extra["min"] = option.min
    declared = _option(option.help, option.panel, show_default=option.show_default, **extra)
    kind = option.kind if option.default is not None else option.kind | None
    return Annotated[kind, declared]


@dataclass(frozen=True, slots=True)
class OpenedLog:
    """A log opened for a replay: its source, its truth and where that came from.

    :param truth_files: the files the truth was read from (``--truth`` or the source's)
    :param truth_given: the truth is a ``--truth`` file (checked against the events)
    """

    source: Source
    args: SourceArgs
    truth: GroundTruth | None
    truth_files: list[Path]
    truth_given: bool = False

    def events(self, progress: ProgressCallback | None = None) -> Iterator[AnyEvent]:
        """The source's events, checked against a ``--truth`` file's landmarks."""
        events = self.source.events(progress, warn)
        if self.truth is not None and self.truth_given:
            every_id = self.source.names_every_landmark
            return checked_against(events, self.truth, self.truth_files[0], every_id=every_id)
        return events


def open_log(
    data: Path, source_args: SourceArgs, truth_path: Path | None, no_truth: bool
) -> OpenedLog:
    """Open a log's source and its truth (``--truth``, else the source's own unless
    ``--no-truth``).

    :raises InputError: a path that is no log, a truth file that cannot be read
    """
    source = open_source(data, source_args)
    if truth_path is not None:
        return OpenedLog(source, source_args, read_truth(truth_path), [truth_path], True)
    own = None if no_truth else source.own_truth(warn)
    if own is not None:
        return OpenedLog(source, source_args, own.truth, own.files)
    return OpenedLog(source, source_args, None, [])


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
    pose_option: bool = True,
) -> tuple[FilterParams, list[str]]:
    """The filter's start pose and motion-noise model, and notes saying what was chosen
    (``pose_option``: the command has ``--init-pose``, which the notes then name)."""
    notes: list[str] = []
    if motion_noise is MotionNoiseChoice.AUTO:
        model = opened.source.motion_noise
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
                + (" (--init-pose X Y THETA to choose another)" if pose_option else "")
            )
        else:
            notes.append(
                "The first event is outside the true track: the filter starts at 0 0 0"
                + (" (--init-pose X Y THETA to choose)" if pose_option else "")
            )
    return replace(
        params,
        motion_noise=model,
        init_pose=init_pose or params.init_pose,
        gate=params.gate if gate is None else gate,
    ), notes


@dataclass(frozen=True, slots=True)
class StudyInput:
    """What a study or a check takes from its log's source, as a replay of it does.

    :param params: the filter's parameters, with the source's motion-noise model (a
        study's) and the true pose of the first event where the source's own truth is
        timed (MRCLAM's Vicon track, a bag's truth topic)
    :param own_truth: the source's own truth, where no ``--truth`` file replaces it and
        ``--no-truth`` does not drop it
    :param notes: what was chosen, for the user (the start pose)
    :param files: the files the source and its own truth are read from, none of which an
        output may replace
    """

    params: FilterParams
    own_truth: OwnTruth | None = None
    notes: tuple[str, ...] = ()
    files: tuple[Path, ...] = ()  # what the source reads (a dataset directory's files)


def study_input(
    params: FilterParams,
    data: Path | None,
    source_args: SourceArgs,
    truth_path: Path | None,
    no_truth: bool,
    *,
    motion_noise: bool = True,
    init_pose: tuple[float, float, float] | None = None,
    pose_option: bool = False,
) -> StudyInput:
    """The source's defaults applied to ``params`` for a study or a check, and the
    source's own truth, so that a study or a check of a dataset runs the filter a replay of
    it runs and is judged against the same truth: ``replay --motion-noise auto`` where
    ``motion_noise``, the start at the true pose unless ``init_pose`` (``pose_option``: the
    command has ``--init-pose``, which its note then names). A log that cannot be opened
    is left to the command to refuse in its own words."""
    if data is None:
        return StudyInput(params)
    try:
        source = open_source(data, source_args)
    except InputError:
        return StudyInput(params)
    try:  # read here only: its errors are this command's
        own = None if truth_path is not None or no_truth else source.own_truth(warn)
    except InputError as error:
        fail(str(error))
    truth, files = (own.truth, own.files) if own is not None else (None, [])
    read = (*source.files, *files)
    start = None
    if own is not None and own.truth.track_times is not None and init_pose is None:
        try:  # the first event's time (its warnings are said where the log is read whole)
            start, _ = first_time(source.events(None, _unsaid))
        except InputError:
            return StudyInput(params, files=read)
    opened = OpenedLog(source, source_args, truth, files)
    kept = MotionNoiseChoice(params.motion_noise.value)
    choice = MotionNoiseChoice.AUTO if motion_noise else kept
    resolved, notes = resolve(params, opened, start, init_pose, choice, pose_option=pose_option)
    return StudyInput(resolved, own, tuple(notes), read)


def _unsaid(message: str) -> None:
    """A reader's warning on a read whose events are read again (and warned of) later."""
