"""Reader of the UTIAS MRCLAM datasets (Leung et al., IJRR 2011): one robot of a directory.

A dataset directory holds, with ``#`` header lines and whitespace-separated numbers::

    Barcodes.dat              subject  barcode
    Landmark_Groundtruth.dat  subject  x  y  std-x  std-y
    Robot<R>_Odometry.dat     time  forward-velocity  angular-velocity
    Robot<R>_Measurement.dat  time  barcode  range  bearing   (a barcode, despite its header)
    Robot<R>_Groundtruth.dat  time  x  y  orientation          (Vicon)

Events: each odometry sample (v, omega) holds from its time until the next sample or
measurement, and becomes a :class:`~ekfviz.core.records.Control` of d = v dt,
alpha = omega dt spanning dt seconds (its ``time`` is the end of the span); the
measurements with one time stamp form one :class:`~ekfviz.core.records.Sighting` at
that time, so that the filter first predicts up to it. Barcodes map to subjects through
``Barcodes.dat``; landmark ids are the subject numbers. Sightings of the robots
(subjects 1 to 5) and of unknown barcodes are skipped, with one summary warning.

Drive-then-turn by (v dt, omega dt) differs from the exact arc of a unicycle by about
d * alpha / 2 sideways per control: at MRCLAM's 67 Hz (d ~ 3 mm, alpha ~ 6 mrad) some
10 micrometres, far below the noise, so the filter keeps its one motion model.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekfviz.core.errors import InputError
from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.io.text import (
    BearingWrapper,
    ProgressCallback,
    WarningCallback,
    check_time,
    first_bad_time,
    numeric_blocks,
    numeric_lines,
    time_error,
)

BARCODES = "Barcodes.dat"
LANDMARKS = "Landmark_Groundtruth.dat"
ROBOT_SUBJECTS = frozenset(range(1, 6))  # MRCLAM's subjects 1-5 are the robots
_ROBOT_FILE = re.compile(r"Robot(\d+)_Odometry\.dat", re.ASCII)


def is_mrclam(path: Path) -> bool:
    """Whether ``path`` is a directory in the MRCLAM layout (it holds ``Barcodes.dat``)."""
    return path.is_dir() and (path / BARCODES).exists()  # a folder there: said on reading


def robots_in(directory: Path) -> list[int]:
    """The robot numbers with an odometry file in a dataset directory, ascending."""
    found = (_ROBOT_FILE.fullmatch(p.name) for p in directory.iterdir())
    return sorted(int(m.group(1)) for m in found if m)


@dataclass(frozen=True, slots=True)
class MrclamDataset:
    """The files of one robot of an MRCLAM dataset directory."""

    directory: Path
    robot: int

    @property
    def barcodes(self) -> Path:
        return self.directory / BARCODES

    @property
    def landmarks(self) -> Path:
        return self.directory / LANDMARKS

    @property
    def odometry(self) -> Path:
        return self.directory / f"Robot{self.robot}_Odometry.dat"

    @property
    def measurement(self) -> Path:
        return self.directory / f"Robot{self.robot}_Measurement.dat"

    @property
    def groundtruth(self) -> Path:
        return self.directory / f"Robot{self.robot}_Groundtruth.dat"

    @property
    def log_files(self) -> list[Path]:
        """What the events are read from (the run's input)."""
        return [self.barcodes, self.odometry, self.measurement]

    @property
    def has_truth(self) -> bool:
        return self.landmarks.is_file() and self.groundtruth.is_file()

    @property
    def truth_files(self) -> list[Path]:
        return [self.landmarks, self.groundtruth]


def open_dataset(directory: Path, robot: int) -> MrclamDataset:
    """The files of robot ``robot``, checked to be there.

    :raises InputError: a missing file, naming it and the robots the directory has
    """
    dataset = MrclamDataset(directory, robot)
    if robot < 1:
        raise InputError(directory, 0, f"found --robot {robot}, expected a robot number from 1")
    # the truth files may be missing (a run without truth), not anything else
    for path in (*dataset.log_files, *dataset.truth_files):
        if path.is_dir():
            raise InputError(path, 0, "is a directory, expected a text file")
        if path.exists() and not path.is_file():  # a FIFO, a device: would block or never end
            raise InputError(path, 0, "is not a regular file, expected a text file")
        if not path.is_file() and path in dataset.log_files:
            robots = robots_in(directory)
            have = ", ".join(map(str, robots)) if robots else "none"
            raise InputError(
                path, 0, f"no such file, expected robot {robot}'s files (robots here: {have})"
            )
    return dataset


def read_barcodes(path: Path) -> dict[int, int]:
    """Barcode -> subject, from ``Barcodes.dat``.

    :raises InputError: a line that is not two integers, a barcode given twice
    """
    subjects: dict[int, int] = {}
    for line, values in numeric_lines(path):
        if len(values) != 2 or not all(v.is_integer() and v >= 0 for v in values):
            raise InputError(
                path, line, f"found {_shown(values)}, expected two integers: subject barcode"
            )
        subject, barcode = int(values[0]), int(values[1])
        if barcode in subjects:
            raise InputError(
                path, line, f"found barcode {barcode} twice, expected each barcode once"
            )
        subjects[barcode] = subject
    if not subjects:
        raise InputError(path, 0, "found no data, expected 'subject barcode' lines")
    return subjects


def read_landmark_truth(path: Path) -> tuple[np.ndarray, FloatArray]:
    """True landmarks from ``Landmark_Groundtruth.dat``: ids (K,) and positions (K, 2)."""
    ids: list[int] = []
    rows: list[list[float]] = []
    for line, values in numeric_lines(path):
        if len(values) != 5 or not (values[0].is_integer() and values[0] >= 0):
            raise InputError(
                path, line, f"found {_shown(values)}, expected 5 numbers: subject x y std-x std-y"
            )
        if int(values[0]) in ids:  # two positions for one landmark: which is true?
            raise InputError(
                path, line, f"found subject {int(values[0])} twice, expected each landmark once"
            )
        ids.append(int(values[0]))
        rows.append(values[1:3])
    if not ids:
        raise InputError(path, 0, "found no data, expected 'subject x y std-x std-y' lines")
    return np.array(ids, dtype=np.int64), np.array(rows, dtype=np.float64).reshape(-1, 2)


def read_track(path: Path) -> tuple[FloatArray, FloatArray]:
    """A robot's Vicon track: times (T,) and poses (T, 3), times never decreasing."""
    blocks: list[FloatArray] = []
    last = -math.inf
    for lines, table in numeric_blocks(path, 4, "time x y orientation"):
        _check_times(path, lines, table[:, 0], last)
        last = float(table[-1, 0])
        blocks.append(table)
    if not blocks:
        raise InputError(path, 0, "found no data, expected 'time x y orientation' lines")
    track = np.concatenate(blocks)
    return np.ascontiguousarray(track[:, 0]), np.ascontiguousarray(track[:, 1:])


def read_truth(dataset: MrclamDataset) -> GroundTruth:
    """The dataset's own truth: the surveyed landmarks and the robot's Vicon track."""
    ids, landmarks_xy = read_landmark_truth(dataset.landmarks)
    times, poses = read_track(dataset.groundtruth)
    return GroundTruth(ids=ids, landmarks_xy=landmarks_xy, track_times=times, track_xytheta=poses)


@dataclass(slots=True)
class _Skipped:
    """Sightings skipped while reading, for the summary warning."""

    robots: dict[int, int]
    unknown: dict[int, int]
    repeated: int = 0

    def summary(self, path: Path) -> str | None:
        parts = []
        if self.robots:
            subjects = ", ".join(f"{s} ({n})" for s, n in sorted(self.robots.items()))
            parts.append(f"{sum(self.robots.values())} of robots, subjects {subjects}")
        if self.unknown:
            codes = ", ".join(f"{b} ({n})" for b, n in sorted(self.unknown.items()))
            parts.append(f"{sum(self.unknown.values())} of unknown barcodes {codes}")
        if self.repeated:
            parts.append(f"{self.repeated} repeating a landmark at the same time stamp")
        if not parts:
            return None
        return f"{path}: skipped sightings: " + "; ".join(parts) + " (count in brackets)"


def read_mrclam(
    dataset: MrclamDataset,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[LogEvent]:
    """Stream the events of one robot (see the module): controls and sightings in time order.

    Control lines are odometry lines and sighting lines measurement lines.

    :param progress: called now and then with the bytes of odometry read so far
    :param warn: told once about bearings wrapped into (-pi, pi] and, at the end, about
        the sightings skipped
    :raises InputError: for the first bad line met, naming its file and line
    """
    subjects = read_barcodes(dataset.barcodes)
    skipped = _Skipped({}, {})
    odometry = _odometry(dataset.odometry, progress)
    sightings = _sightings(dataset.measurement, subjects, skipped, BearingWrapper(
        dataset.measurement, warn
    ))  # fmt: skip
    sample = next(odometry, None)
    sighting = next(sightings, None)
    held: tuple[int, float, float] | None = None  # (line, v, omega) of the sample in force
    now = -math.inf
    while sample is not None or sighting is not None:
        # a measurement at the time of an odometry sample comes first: no time passes
        if sighting is not None and (sample is None or sighting[0] <= sample[1]):
            time = sighting[0]
        else:
            assert sample is not None
            time = sample[1]
        if held is not None and time > now:
            dt = time - now
            yield Control(line=held[0], d=held[1] * dt, alpha=held[2] * dt, time=time, dt=dt)
        now = time
        if sighting is not None and sighting[0] == time:
            yield sighting[1]
            sighting = next(sightings, None)
        else:
            assert sample is not None
            held = (sample[0], sample[2], sample[3])
            sample = next(odometry, None)
    if warn is not None and (text := skipped.summary(dataset.measurement)):
        warn(text)


def _odometry(
    path: Path, progress: ProgressCallback | None
) -> Iterator[tuple[int, float, float, float]]:
    """(line, time, v, omega) of every odometry sample, times never decreasing."""
    last = -math.inf
    what = "time forward-velocity angular-velocity"
    for lines, table in numeric_blocks(path, 3, what, progress):
        # the samples before a bad time first: a run stopped by it keeps all up to it
        bad = _time_fault(path, lines, table[:, 0], last)
        end = len(lines) if bad is None else bad[0]
        for line, (time, v, omega) in zip(lines[:end], table[:end].tolist(), strict=True):
            yield line, time, v, omega
        if bad is not None:
            raise bad[1]
        last = float(table[-1, 0])
    if last == -math.inf:
        raise InputError(path, 0, f"found no data, expected '{what}' lines")


def _sightings(
    path: Path, subjects: dict[int, int], skipped: _Skipped, wrap: BearingWrapper
) -> Iterator[tuple[float, Sighting]]:
    """The measurements, one (time, Sighting) per time stamp with a landmark seen."""
    last = -math.inf
    group_line = 0
    ids: list[int] = []
    z: list[tuple[float, float]] = []

    def sighting() -> tuple[float, Sighting]:
        bearings = wrap(group_line, np.array([b for b, _ in z]))
        return last, Sighting(
            line=group_line,
            ids=np.array(ids, dtype=np.int64),
            z=np.column_stack([bearings, [r for _, r in z]]),
            time=last,
        )

    what = "time barcode range bearing"
    rows = 0
    for line, values in _rows(path, 4, what):
        rows += 1
        time, barcode, rng, bearing = values
        if not (barcode.is_integer() and barcode >= 0):
            raise InputError(path, line, f"found barcode {barcode:g}, expected an integer >= 0")
        if not rng > 0:
            raise InputError(path, line, f"found range {rng:g}, expected a positive range")
        if time < last:
            raise InputError(path, line, _decreasing(time, last))
        if time > last:
            check_time(path, line, time)
            if ids:
                yield sighting()
            ids, z, group_line, last = [], [], line, time
        subject = subjects.get(int(barcode))
        if subject is None:
            skipped.unknown[int(barcode)] = skipped.unknown.get(int(barcode), 0) + 1
        elif subject in ROBOT_SUBJECTS:
            skipped.robots[subject] = skipped.robots.get(subject, 0) + 1
        elif subject in ids:
            skipped.repeated += 1
        else:
            if not ids:
                group_line = line
            ids.append(subject)
            z.append((bearing, rng))
    if ids:
        yield sighting()
    if not rows:
        raise InputError(path, 0, f"found no data, expected '{what}' lines")


def _rows(path: Path, columns: int, what: str) -> Iterator[tuple[int, list[float]]]:
    for lines, table in numeric_blocks(path, columns, what):
        yield from zip(lines, table.tolist(), strict=True)


def _check_times(path: Path, lines: list[int], times: FloatArray, last: float) -> None:
    """Refuse the first bad time of a block (see :func:`_time_fault`)."""
    bad = _time_fault(path, lines, times, last)
    if bad is not None:
        raise bad[1]


def _time_fault(
    path: Path, lines: list[int], times: FloatArray, last: float
) -> tuple[int, InputError] | None:
    """The first time of a block (its row and error) that is earlier than the one before
    it, or that a recording cannot hold (see :data:`~ekfviz.io.text.MAX_TIME_S`); None
    when every time is good."""
    bad = first_bad_time(times, last)
    if bad is None:
        return None
    k, previous = bad
    if previous is None:
        return k, time_error(path, lines[k], float(times[k]))
    return k, InputError(path, lines[k], _decreasing(float(times[k]), previous))


def _decreasing(time: float, last: float) -> str:
    return f"found time {time:.3f} after {last:.3f}, expected times that never decrease"


def _shown(values: list[float]) -> str:
    text = " ".join(f"{v:g}" for v in values)
    return repr(text if len(text) <= 40 else text[:40] + "...")
