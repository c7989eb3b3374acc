"""The Victoria Park run (Guivant and Nebot 2001) in its text form: a directory of three files.

- ``inputs.dat``: ``time speed steering`` per line: the speed (m/s) of the encoder on the
  rear-left wheel and the steering angle (rad);
- ``measurements.dat``: ``time range bearing diameter`` per detection: range (m), bearing
  (rad) in the laser's frame, from 0 to pi with pi/2 straight ahead, and the trunk's
  diameter (m); all detections of one scan share its time;
- ``gps.dat`` (optional): ``time x y`` in a frame of its own, the reference.

The reader streams both logs at once in time order: before each scan, one
:class:`~ekfviz.core.records.Drive` with the controls held since the previous scan (each
input held until the next input or the scan), then the :class:`~ekfviz.core.records.Scan`
with bearings in the vehicle's frame (bearing - pi/2). Times never decrease within a
file; an error names the file and its line.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ekfviz.core.records import AnyEvent, Drive, Scan
from ekfviz.core.types import FloatArray
from ekfviz.io.errors import InputError
from ekfviz.io.text import ProgressCallback, numeric_lines

INPUTS = "inputs.dat"
MEASUREMENTS = "measurements.dat"
GPS = "gps.dat"
LASER_BEARING_AHEAD = math.pi / 2  # the laser's bearing of straight ahead


def is_victoria(path: Path) -> bool:
    """Whether ``path`` is a directory holding the Victoria Park logs."""
    return path.is_dir() and (path / INPUTS).exists() and (path / MEASUREMENTS).exists()


def read_victoria(path: Path, progress: ProgressCallback | None = None) -> Iterator[AnyEvent]:
    """Stream the run's events: a Drive before every scan, then the Scan.

    :param progress: called now and then with the bytes read so far of both files
    :raises InputError: naming the file and line of the first bad line
    """
    if not is_victoria(path):
        raise InputError(path, 0, f"expected a directory with {INPUTS} and {MEASUREMENTS}")
    read = {INPUTS: 0, MEASUREMENTS: 0}

    def tracker(name: str) -> ProgressCallback | None:
        if progress is None:
            return None

        def report(done: int) -> None:
            read[name] = done
            progress(sum(read.values()))

        return report

    inputs = _rows(path / INPUTS, 3, "time speed steering", tracker(INPUTS))
    scans = _scans(path / MEASUREMENTS, tracker(MEASUREMENTS))
    held = (0.0, 0.0)  # speed and steering before the first input
    clock: float | None = None
    segments: list[tuple[float, float, float]] = []
    next_input = next(inputs, None)
    line = 0
    for scan in scans:
        assert scan.time is not None
        while next_input is not None and next_input[1][0] <= scan.time:
            line, (time, speed, steering) = next_input
            if clock is not None:
                segments.append((*held, time - clock))
            clock, held = time, (speed, steering)
            next_input = next(inputs, None)
        if clock is not None:
            segments.append((*held, scan.time - clock))
        clock = scan.time
        yield Drive(line=line, segments=np.array(segments).reshape(-1, 3), time=scan.time)
        segments = []
        yield scan
    if next_input is not None and clock is not None:  # the inputs after the last scan
        while next_input is not None:
            line, (time, speed, steering) = next_input
            segments.append((*held, time - clock))
            clock, held = time, (speed, steering)
            next_input = next(inputs, None)
        yield Drive(line=line, segments=np.array(segments).reshape(-1, 3), time=clock)


def _rows(
    path: Path, count: int, what: str, progress: ProgressCallback | None
) -> Iterator[tuple[int, list[float]]]:
    """Numeric lines of ``count`` values with a first column (time) that never decreases."""
    last = -math.inf
    rows = 0
    for line, values in numeric_lines(path, progress):
        rows += 1
        if len(values) != count:
            raise InputError(path, line, f"found {len(values)} numbers, expected {count}: {what}")
        if values[0] < last:
            raise InputError(
                path, line, f"found time {values[0]:g} after {last:g}, expected times in order"
            )
        last = values[0]
        yield line, values
    if not rows:
        raise InputError(path, 0, f"found no data, expected '{what}' lines")


def _scans(path: Path, progress: ProgressCallback | None) -> Iterator[Scan]:
    """The detections grouped by time: one Scan per time stamp."""
    rows: list[list[float]] = []
    first_line = 0
    for line, values in _rows(path, 4, "time range bearing diameter", progress):
        _, rng, bearing, diameter = values
        if not rng > 0:
            raise InputError(path, line, f"found range {rng:g}, expected a positive range")
        if not 0.0 <= bearing <= math.pi:
            raise InputError(
                path, line, f"found bearing {bearing:g}, expected the laser's 0 to pi (rad)"
            )
        if diameter < 0:
            raise InputError(path, line, f"found diameter {diameter:g}, expected >= 0")
        if rows and values[0] != rows[0][0]:
            yield _scan(rows, first_line)
            rows = []
        if not rows:
            first_line = line
        rows.append(values)
    if rows:
        yield _scan(rows, first_line)


def _scan(rows: list[list[float]], line: int) -> Scan:
    table = np.array(rows)
    z = np.column_stack([table[:, 2] - LASER_BEARING_AHEAD, table[:, 1]])
    return Scan(line=line, z=z, time=float(table[0, 0]), diameters=table[:, 3].copy())


def read_gps(path: Path) -> tuple[FloatArray, FloatArray]:
    """The GPS reference: times (K,) and positions (K, 2), in its own frame.

    :param path: the run's directory or its gps.dat
    :raises InputError: a missing file or a bad line
    """
    if path.is_dir():
        path = path / GPS
    rows = [values for _, values in _rows(path, 3, "time x y", None)]
    table = np.array(rows)
    return table[:, 0], table[:, 1:3]
