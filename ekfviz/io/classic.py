"""Reader of the classic EKF-SLAM log format.

The first line is the initial observation of all k landmarks (2k numbers: bearing and
range per landmark, landmark i being the i-th pair); after it, a line of 2 numbers is a
control (d, alpha) and a line of 2k numbers an observation of the same k landmarks.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.io.errors import InputError
from ekfviz.io.text import ProgressCallback, numeric_lines


def read_classic(path: Path, progress: ProgressCallback | None = None) -> Iterator[LogEvent]:
    """Stream the events of a classic log; landmark ids are 1..k in pair order.

    :param progress: called now and then with the number of bytes read so far
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
    yield _sighting(path, line, ids, values)
    for line, values in lines:
        if len(values) == 2:
            yield Control(line=line, d=values[0], alpha=values[1])
        elif len(values) == 2 * k:
            yield _sighting(path, line, ids, values)
        else:
            raise InputError(
                path,
                line,
                f"found {_count(len(values))}, expected 2 (a control: d alpha) or {2 * k}"
                f" (an observation of the {k} landmarks of the first line)",
            )


def _sighting(path: Path, line: int, ids: np.ndarray, values: list[float]) -> Sighting:
    z = np.array(values, dtype=np.float64).reshape(-1, 2)
    bad = np.flatnonzero(z[:, 1] <= 0.0)
    if bad.size:
        i = int(bad[0])
        raise InputError(
            path,
            line,
            f"found range {values[2 * i + 1]:g} for landmark {int(ids[i])},"
            " expected a positive range",
        )
    return Sighting(line=line, ids=ids, z=z)


def _count(n: int) -> str:
    return f"{n} number" + ("" if n == 1 else "s")


def format_classic(events: list[LogEvent] | tuple[LogEvent, ...], precision: int = 6) -> str:
    """Write events in the classic format, tab separated, one event a line.

    Every observation must list the same landmarks in the same order as the first line.
    """
    lines = []
    for event in events:
        values = [event.d, event.alpha] if isinstance(event, Control) else event.z.ravel().tolist()
        lines.append("\t".join(f"{v:.{precision}f}" for v in values))
    return "\n".join(lines) + "\n"
