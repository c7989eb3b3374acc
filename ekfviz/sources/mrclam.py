"""One robot of a UTIAS MRCLAM dataset directory (see :mod:`ekfviz.io.mrclam`).

Its controls are velocities held over known times: the motion noise is time-scaled by
default. It comes with its own truth (the surveyed landmarks and the Vicon track),
which a ``--truth`` file replaces. ``--robot`` chooses the robot (1 by default).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.params import MotionNoise
from ekfviz.core.records import AnyEvent
from ekfviz.io import mrclam
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.sources.base import OwnTruth, Source, SourceArgs, SourceOption, register

ROBOT = SourceOption("robot", int, "The robot of an MRCLAM dataset directory [default: 1].")


@register
@dataclass(frozen=True, slots=True)
class MrclamSource(Source):
    """The files of one robot of an MRCLAM dataset."""

    kind = "mrclam"
    description = "an MRCLAM dataset directory"
    marker = mrclam.BARCODES
    options = (ROBOT,)
    motion_noise = MotionNoise.PER_SQRT_SECOND
    ids_only = True

    path: Path
    dataset: mrclam.MrclamDataset

    @classmethod
    def detect(cls, path: Path) -> bool:
        return mrclam.is_mrclam(path)

    @classmethod
    def open(cls, path: Path, args: SourceArgs) -> MrclamSource:
        robot = args.value(ROBOT)
        return cls(path, mrclam.open_dataset(path, 1 if robot is None else int(robot)))

    @property
    def name(self) -> str:
        return f"{self.path.resolve().name}_robot{self.dataset.robot}"

    @property
    def files(self) -> list[Path]:
        return self.dataset.log_files

    @property
    def progress_paths(self) -> list[Path]:
        return [self.dataset.odometry]  # read alongside the measurements, far longer

    def file_of(self, motion: bool) -> Path | None:
        return self.dataset.odometry if motion else self.dataset.measurement

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        return mrclam.read_mrclam(self.dataset, progress, warn)

    def own_truth(self, warn: WarningCallback) -> OwnTruth | None:
        if self.dataset.has_truth:
            return OwnTruth(mrclam.read_truth(self.dataset), self.dataset.truth_files)
        missing = [p.name for p in self.dataset.truth_files if not p.is_file()]
        warn(
            f"{self.path}: no {' or '.join(missing)}, replaying without the dataset's truth"
            " (expected both truth files beside Barcodes.dat; --no-truth to go without)"
        )
        return None
