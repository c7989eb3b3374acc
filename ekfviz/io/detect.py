"""Which kind of log a path is, in one place, and its events and own truth.

A directory holding ``Barcodes.dat`` is an MRCLAM dataset (:mod:`ekfviz.io.mrclam`); a
file is an extended log when its first data line starts with a keyword (maybe after a
timestamp), else a classic one.
"""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.records import LogEvent
from ekfviz.core.truth import GroundTruth
from ekfviz.io import mrclam
from ekfviz.io.classic import read_classic
from ekfviz.io.errors import InputError
from ekfviz.io.extended import is_extended, read_extended
from ekfviz.io.text import ProgressCallback, WarningCallback


class LogKind(str, enum.Enum):
    CLASSIC = "classic"
    EXTENDED = "extended"
    MRCLAM = "mrclam"


@dataclass(frozen=True, slots=True)
class LogSource:
    """A log to replay: its path, its kind and, for a dataset, the robot's files."""

    path: Path
    kind: LogKind
    dataset: mrclam.MrclamDataset | None = None

    @property
    def files(self) -> list[Path]:
        """The files the events are read from."""
        return [self.path] if self.dataset is None else self.dataset.log_files

    @property
    def progress_path(self) -> Path:
        """The file whose bytes read measure the progress (a dataset's odometry)."""
        return self.path if self.dataset is None else self.dataset.odometry

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
    ) -> Iterator[LogEvent]:
        """Stream the events (see each format's reader)."""
        if self.dataset is not None:
            return mrclam.read_mrclam(self.dataset, progress, warn)
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
    if path.is_dir():
        if not mrclam.is_mrclam(path):
            raise InputError(
                path, 0, f"is a directory without {mrclam.BARCODES}, expected a log file"
                " or an MRCLAM dataset directory"
            )  # fmt: skip
        return LogSource(path, LogKind.MRCLAM, mrclam.open_dataset(path, robot or 1))
    if robot is not None:
        raise InputError(path, 0, "--robot is for an MRCLAM dataset directory, not a log file")
    return LogSource(path, LogKind.EXTENDED if is_extended(path) else LogKind.CLASSIC)


def read_log(
    path: Path,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
    robot: int | None = None,
) -> Iterator[LogEvent]:
    """Stream the events of a log of any kind (see :func:`open_source`)."""
    return open_source(path, robot).events(progress, warn)
