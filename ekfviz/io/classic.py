"""Reader of the classic EKF-SLAM log format.

The first line is the initial observation of all k landmarks (2k numbers: bearing and
range per landmark, landmark i being the i-th pair); after it, a line of 2 numbers is a
control (d, alpha) and a line of 2k numbers an observation of the same k landmarks.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.core.types import IntArray
from ekfviz.io.errors import InputError
from ekfviz.io.text import (
    BearingWrapper,
    ProgressCallback,
    WarningCallback,
    format_number,
    numeric_lines,
)


def read_classic(
    path: Path,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[LogEvent]:
    """Stream the events of a classic log; landmark ids are 1..k in pair order.

    :param progress: called now and then with the number of bytes read so far
    :param warn: told once when bearings outside (-pi, pi] are wrapped into range
    :raises InputError: for the first bad line met, naming it and what was expected
    """
    lines = numeric_lines(path, progress)
    first = next(lines, None)
    if first is None:
        raise InputError(
            path, 1, "found no data, expected a first line with the initial observation"
        )
    line, values = first
    k = len(values) // 2
    if len(values) % 2 or k < 2:
        raise InputError(
            path,
            line,
            f"found {_count(len(values))} on the first line, expected the initial observation"
            " of k >= 2 landmarks: 2k numbers, a bearing and a range per landmark"
            + (
                " (with one landmark, observations could not be told from controls)"
                if k == 1 and not len(values) % 2
                else ""
            ),
        )
    ids = np.arange(1, k + 1, dtype=np.int64)
    wrap = BearingWrapper(path, warn)
    yield _sighting(path, line, ids, values, wrap)
    for line, values in lines:
        if len(values) == 2:
            yield Control(line=line, d=values[0], alpha=values[1])
        elif len(values) == 2 * k:
            yield _sighting(path, line, ids, values, wrap)
        else:
            raise InputError(
                path,
                line,
                f"found {_count(len(values))}, expected 2 (a control: d alpha) or {2 * k}"
                f" (an observation of the {k} landmarks of the first line)",
            )


def _sighting(
    path: Path, line: int, ids: IntArray, values: list[float], wrap: BearingWrapper
) -> Sighting:
    # checks on the floats first: numpy's per-call cost would dominate on a short line
    if min(values[1::2]) <= 0.0:
        i = next(i for i, r in enumerate(values[1::2]) if r <= 0.0)
        raise InputError(
            path,
            line,
            f"found range {values[2 * i + 1]:g} for landmark {int(ids[i])},"
            " expected a positive range",
        )
    z = np.array(values, dtype=np.float64).reshape(-1, 2)
    bearings = values[0::2]
    if max(bearings) > math.pi or min(bearings) <= -math.pi:
        z[:, 0] = wrap(line, z[:, 0])
    return Sighting(line=line, ids=ids, z=z)


def _count(n: int) -> str:
    return f"{n} number" + ("" if n == 1 else "s")


def format_classic(events: Iterable[LogEvent], precision: int | None = 6) -> str:
    """Write events in the classic format, tab separated, one event a line.

    :param precision: decimals, or None for the shortest text that reads back exactly
    :raises ValueError: when the events do not fit the format: the first must be an
        observation of k >= 2 landmarks with ids 1..k, and every later one of the same
    """
    lines: list[str] = []
    for event in events:
        if isinstance(event, Control):
            values = [event.d, event.alpha]
        else:
            k = len(event.ids)
            if (
                (lines and len(lines[0].split("\t")) != 2 * k)
                or k < 2
                or (event.ids.tolist() != list(range(1, k + 1)))
            ):
                raise ValueError(
                    f"event of line {event.line} does not fit the classic format: it needs"
                    " every landmark 1..k seen at every observation, in order"
                )
            values = event.z.ravel().tolist()
        if not lines and isinstance(event, Control):
            raise ValueError("the classic format starts with an observation, not a control")
        lines.append("\t".join(format_number(v, precision) for v in values))
    return "\n".join(lines) + "\n"
