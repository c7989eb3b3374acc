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
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ekfviz.core.errors import InputError
from ekfviz.core.records import AnyEvent, Drive, Scan
from ekfviz.core.types import FloatArray
from ekfviz.io.text import ProgressCallback, first_bad_time, numeric_blocks, time_error

INPUTS = "inputs.dat"
MEASUREMENTS = "measurements.dat"
GPS = "gps.dat"
LASER_BEARING_AHEAD = math.pi / 2  # the laser's bearing of straight ahead


def is_victoria(path: Path) -> bool:
    """Whether ``path`` is a directory holding the Victoria Park logs (there, whether they
    read or not: a broken link is then named by the reader, not taken for no file)."""
    return path.is_dir() and os.path.lexists(path / INPUTS) and os.path.lexists(path / MEASUREMENTS)


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


def _blocks(
    path: Path, count: int, what: str, progress: ProgressCallback | None
) -> Iterator[tuple[list[int], FloatArray]]:
    """Blocks of numeric lines of ``count`` values (line numbers, (k, count)) whose first
    column (time) never decreases: a block is converted at once (see
    :func:`~ekfviz.io.text.numeric_blocks`); the rows before a bad line are yielded
    before its error is raised."""
    last = -math.inf
    rows = 0
    for lines, table in numeric_blocks(path, count, what, progress):
        times = table[:, 0]
        bad = first_bad_time(times, last)
        if bad is not None:
            k, previous = bad
            if k:
                yield lines[:k], table[:k]
            if previous is None:  # a time a recording cannot hold (see MAX_TIME_S)
                raise time_error(path, lines[k], float(times[k]))
            raise InputError(
                path,
                lines[k],
                f"found time {times[k]:g} after {previous:g}, expected times in order",
            )
        rows += len(lines)
        last = float(times[-1])
        yield lines, table
    if not rows:
        raise InputError(path, 0, f"found no data, expected '{what}' lines")


def _rows(
    path: Path, count: int, what: str, progress: ProgressCallback | None
) -> Iterator[tuple[int, list[float]]]:
    """Numeric lines of ``count`` values with a first column (time) that never decreases."""
    for lines, table in _blocks(path, count, what, progress):
        yield from zip(lines, table.tolist(), strict=True)


def _scans(path: Path, progress: ProgressCallback | None) -> Iterator[Scan]:
    """The detections grouped by time: one Scan per time stamp.

    Checked and grouped a block of lines at a time; a bad line ends the stream with its
    error once the scans complete before it are yielded (the scan it belongs to is not).
    """
    pending: list[FloatArray] = []  # the rows of the scan in progress, in pieces
    first_line = 0
    for lines, table in _blocks(path, 4, "time range bearing diameter", progress):
        rng, bearing, diameter = table[:, 1], table[:, 2], table[:, 3]
        bad = ~(rng > 0) | ~((bearing >= 0.0) & (bearing <= math.pi)) | (diameter < 0)
        faults = np.flatnonzero(bad)
        good = int(faults[0]) if faults.size else len(lines)
        times = table[:good, 0]
        # the rows where a new scan starts: a time other than the row's before
        starts = (np.flatnonzero(times[1:] != times[:-1]) + 1).tolist()
        for begin, end in zip([0, *starts], [*starts, good], strict=True):
            if begin == end:
                continue
            if pending and float(times[begin]) != float(pending[0][0, 0]):
                yield _scan(pending, first_line)
                pending = []
            if not pending:
                first_line = lines[begin]
            pending.append(table[begin:end])
        if faults.size:
            k, line = int(faults[0]), lines[int(faults[0])]
            if not rng[k] > 0:
                raise InputError(path, line, f"found range {rng[k]:g}, expected a positive range")
            if not 0.0 <= bearing[k] <= math.pi:
                raise InputError(
                    path, line, f"found bearing {bearing[k]:g}, expected the laser's 0 to pi (rad)"
                )
            raise InputError(path, line, f"found diameter {diameter[k]:g}, expected >= 0")
    if pending:
        yield _scan(pending, first_line)


def _scan(pieces: list[FloatArray], line: int) -> Scan:
    table = pieces[0] if len(pieces) == 1 else np.concatenate(pieces)
    z = np.column_stack([table[:, 2] - LASER_BEARING_AHEAD, table[:, 1]])
    return Scan(line=line, z=z, time=float(table[0, 0]), diameters=table[:, 3].copy())


def read_gps(path: Path) -> tuple[FloatArray, FloatArray]:
    """The GPS reference: times (K,) and positions (K, 2), in its own frame.

    :param path: the run's directory or its gps.dat
    :raises InputError: a missing file or a bad line
    """
    if path.is_dir():
        path = path / GPS
    table = np.concatenate([block for _, block in _blocks(path, 3, "time x y", None)])
    return table[:, 0], table[:, 1:3]
