"""Which kind of log a path is, in one place, and its events and own truth.

A directory holding ``Barcodes.dat`` is an MRCLAM dataset (:mod:`ekfviz.io.mrclam`), one
holding ``inputs.dat`` and ``measurements.dat`` the Victoria Park run
(:mod:`ekfviz.io.victoria`); a
file is an extended log when its first data line starts with a keyword (maybe after a
timestamp), else a classic one.
"""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.records import AnyEvent
from ekfviz.core.truth import GroundTruth
from ekfviz.io import mrclam, victoria
from ekfviz.io.classic import read_classic
from ekfviz.io.errors import InputError
from ekfviz.io.extended import is_extended, read_extended
from ekfviz.io.text import ProgressCallback, WarningCallback


class LogKind(str, enum.Enum):
    CLASSIC = "classic"
    EXTENDED = "extended"
    MRCLAM = "mrclam"
    VICTORIA = "victoria"


@dataclass(frozen=True, slots=True)
class LogSource:
    """A log to replay: its path, its kind and, for a dataset, the robot's files."""

    path: Path
    kind: LogKind
    dataset: mrclam.MrclamDataset | None = None

    @property
    def files(self) -> list[Path]:
        """The files the events are read from."""
        if self.kind is LogKind.VICTORIA:
            return [self.path / victoria.INPUTS, self.path / victoria.MEASUREMENTS]
        return [self.path] if self.dataset is None else self.dataset.log_files

    @property
    def progress_paths(self) -> list[Path]:
        """The files whose bytes read, summed, measure the progress (a dataset's odometry;
        both files of a Victoria Park run, read side by side)."""
        if self.kind is LogKind.VICTORIA:
            return self.files
        return [self.path if self.dataset is None else self.dataset.odometry]

    @property
    def velocity_odometry(self) -> bool:
        """Whether the controls are velocities held over known times (time-scaled noise)."""
        return self.kind is LogKind.MRCLAM

    @property
    def name(self) -> str:
        """A short name for recordings: the file's stem, or ``<dataset>_robot<R>``."""
        if self.dataset is None:
            return self.path.stem
        return f"{self.path.resolve().name}_robot{self.dataset.robot}"

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        """Stream the events (see each format's reader)."""
        if self.dataset is not None:
            return mrclam.read_mrclam(self.dataset, progress, warn)
        if self.kind is LogKind.VICTORIA:
            return victoria.read_victoria(self.path, progress)
        if self.kind is LogKind.EXTENDED:
            return read_extended(self.path, progress, warn)
        return read_classic(self.path, progress, warn)

    def own_truth(self) -> GroundTruth | None:
        """The truth the log comes with (an MRCLAM dataset's ground-truth files), if any."""
        if self.dataset is None or not self.dataset.has_truth:
            return None
        return mrclam.read_truth(self.dataset)


def open_source(path: Path, robot: int | None = None) -> LogSource:
    """Tell what ``path`` is.

    :param robot: the robot of a dataset directory (default 1); refused for a file
    :raises InputError: a directory that is not a dataset, a dataset without that robot,
        ``robot`` given for a file
    """
    if victoria.is_victoria(path):
        if robot is not None:
            raise InputError(path, 0, "--robot is for an MRCLAM dataset directory")
        return LogSource(path, LogKind.VICTORIA)
    if path.is_dir():
        if not mrclam.is_mrclam(path):
            raise InputError(
                path, 0, f"is a directory without {mrclam.BARCODES}, expected a log file,"
                " an MRCLAM dataset directory or a Victoria Park directory"
                f" ({victoria.INPUTS}, {victoria.MEASUREMENTS}, {victoria.GPS})"
            )  # fmt: skip
        return LogSource(
            path, LogKind.MRCLAM, mrclam.open_dataset(path, 1 if robot is None else robot)
        )
    if robot is not None:
        raise InputError(path, 0, "--robot is for an MRCLAM dataset directory, not a log file")
    return LogSource(path, LogKind.EXTENDED if is_extended(path) else LogKind.CLASSIC)


def read_log(
    path: Path,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
    robot: int | None = None,
) -> Iterator[AnyEvent]:
    """Stream the events of a log of any kind (see :func:`open_source`)."""
    return open_source(path, robot).events(progress, warn)
