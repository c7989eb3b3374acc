"""The input a command opens: its source (see :mod:`ekfviz.sources`) with the options of
every format, its truth, the start pose and the motion-noise model it implies; an input
given through a pipe, read ahead so that it reads as a file.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from ekfviz.app.settings import MotionNoiseChoice
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams, MotionNoise
from ekfviz.core.records import AnyEvent, Control
from ekfviz.core.truth import GroundTruth
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.io.truth import checked_against, read_truth
from ekfviz.sources import OwnTruth, Source, SourceArgs, SourceOption, open_source, source_options

__all__ = [
    "OpenedLog",
    "SourceArgs",
    "SourceOption",
    "StudyInput",
    "first_time",
    "open_log",
    "read_piped",
    "resolve",
    "source_events",
    "source_options",
    "study_input",
]


def read_piped(given: str, stdin_taken: bool) -> str:
    """The path to read an input given as ``given`` by (see :mod:`ekfviz.io.piped`): a
    pipe (``-``, ``<(zcat log.gz)``) read to its end first, so that it reads as a file.

    :param stdin_taken: another input of the command is standard input already
    :raises UsageError: ``-`` twice or on a terminal, a pipe too long to hold
    :raises Interrupted: SIGINT or SIGTERM while the pipe has not ended
    """
    from ekfviz.io.piped import read_ahead

    return read_ahead(given, stdin_taken=stdin_taken)


def source_events(
    source: Source,
    truth: GroundTruth | None,
    truth_path: Path | None,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[AnyEvent]:
    """The events of a source, checked against the landmarks of a ``--truth`` file."""
    events = source.events(progress, warn)
    if truth is not None and truth_path is not None:
        every_id = source.names_every_landmark
        events = checked_against(events, truth, truth_path, every_id=every_id)
    return events


@dataclass(frozen=True, slots=True)
class OpenedLog:
    """A log opened for a replay: its source, its truth and where that came from.

    :param truth_files: the files the truth was read from (``--truth`` or the source's)
    :param truth_given: the truth is a ``--truth`` file (checked against the events)
    :param warn: told what the reader lets pass
    """

    source: Source
    args: SourceArgs
    truth: GroundTruth | None
    truth_files: list[Path]
    truth_given: bool = False
    warn: WarningCallback | None = None

    def events(self, progress: ProgressCallback | None = None) -> Iterator[AnyEvent]:
        """The source's events, checked against a ``--truth`` file's landmarks."""
        truth_path = self.truth_files[0] if self.truth_given else None
        return source_events(self.source, self.truth, truth_path, progress, self.warn)


def open_log(
    data: Path,
    source_args: SourceArgs,
    truth_path: Path | None,
    no_truth: bool,
    warn: WarningCallback | None = None,
) -> OpenedLog:
    """Open a log's source and its truth (``--truth``, else the source's own unless
    ``no_truth``).

    :raises InputError: a path that is no log, a truth file that cannot be read
    """
    source = open_source(data, source_args)
    if truth_path is not None:
        return OpenedLog(source, source_args, read_truth(truth_path), [truth_path], True, warn)
    own = None if no_truth else source.own_truth(warn or _unsaid)
    if own is not None:
        return OpenedLog(source, source_args, own.truth, own.files, warn=warn)
    return OpenedLog(source, source_args, None, [], warn=warn)


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
    warn: WarningCallback | None = None,
) -> StudyInput:
    """The source's defaults applied to ``params`` for a study or a check, and the
    source's own truth, so that a study or a check of a dataset runs the filter a replay of
    it runs and is judged against the same truth: ``replay --motion-noise auto`` where
    ``motion_noise``, the start at the true pose unless ``init_pose`` (``pose_option``: the
    command has ``--init-pose``, which its note then names). A log that cannot be opened
    is left to the study's own reading to refuse in its own words.

    :raises InputError: the source's own truth cannot be read
    """
    if data is None:
        return StudyInput(params)
    try:
        source = open_source(data, source_args)
    except InputError:
        return StudyInput(params)
    own = None if truth_path is not None or no_truth else source.own_truth(warn or _unsaid)
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
