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

from ekfviz.core.errors import InputError
from ekfviz.core.records import Control, LogEvent, Sighting, frozen
from ekfviz.core.types import IntArray
from ekfviz.io.text import (
    BearingWrapper,
    NumberBlock,
    ProgressCallback,
    WarningCallback,
    format_number,
    number_blocks,
)


def read_classic(
    path: Path,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[LogEvent]:
    """Stream the events of a classic log; landmark ids are 1..k in pair order.

    The file is read in blocks (:func:`~ekfviz.io.text.number_blocks`), each checked in
    one go; the events of a block up to its first bad line are yielded before that
    line's error is raised, as a line-by-line reader would.

    :param progress: called now and then with the number of bytes read so far
    :param warn: told once when bearings outside (-pi, pi] are wrapped into range
    :raises InputError: for the first bad line met, naming it and what was expected
    """
    blocks = number_blocks(path, progress)
    block = next(blocks, None)
    if block is not None and not block.lines:
        assert block.fault is not None  # a block is yielded with lines or a fault
        raise block.fault
    if block is None:
        raise InputError(
            path, 1, "found no data, expected a first line with the initial observation"
        )
    line, count = block.lines[0], int(block.counts[0])
    k = count // 2
    if count % 2 or k < 2:
        raise InputError(
            path,
            line,
            f"found {_count(count)} on the first line, expected the initial observation"
            " of k >= 2 landmarks: 2k numbers, a bearing and a range per landmark"
            + (
                " (with one landmark, observations could not be told from controls)"
                if k == 1 and not count % 2
                else ""
            ),
        )
    ids = frozen(np.arange(1, k + 1, dtype=np.int64))
    wrap = BearingWrapper(path, warn)
    while block is not None:
        yield from _block_events(path, block, k, ids, wrap)
        block = next(blocks, None)


def _block_events(
    path: Path, block: NumberBlock, k: int, ids: IntArray, wrap: BearingWrapper
) -> Iterator[LogEvent]:
    """The events of one block, in order; then the error of its first bad line, if any."""
    counts, starts, values, lines = block.counts, block.starts, block.values, block.lines
    # the first line whose count fits neither event ends the block's events
    bad = np.flatnonzero((counts != 2) & (counts != 2 * k))
    end = int(bad[0]) if len(bad) else len(lines)
    sightings = np.flatnonzero(counts[:end] == 2 * k)
    # every observation's (bearing, range) pairs at once: (sightings, k, 2)
    z_all = values[starts[sightings, None] + np.arange(2 * k)].reshape(-1, k, 2)
    fault = block.fault
    not_positive = np.flatnonzero((z_all[:, :, 1] <= 0.0).any(axis=1))
    if len(not_positive):  # a range error comes first: it is on an earlier line
        row = int(not_positive[0])
        at = int(sightings[row])
        i = int(np.flatnonzero(z_all[row, :, 1] <= 0.0)[0])
        fault = InputError(
            path,
            lines[at],
            f"found range {z_all[row, i, 1]:g} for landmark {int(ids[i])},"
            " expected a positive range",
        )
        end = at
    elif end < len(lines):
        count = int(counts[end])
        fault = InputError(
            path,
            lines[end],
            f"found {_count(count)}, expected 2 (a control: d alpha) or {2 * k}"
            f" (an observation of the {k} landmarks of the first line)",
        )
    bearings = z_all[:, :, 0]
    outside = ((bearings > math.pi) | (bearings <= -math.pi)).any(axis=1).tolist()
    controls = values[starts[:end, None] + np.arange(2)].tolist() if end else []
    row = 0
    for j, (line, count) in enumerate(zip(lines[:end], counts[:end].tolist(), strict=True)):
        if count == 2:
            d, alpha = controls[j]
            yield Control(line, d, alpha)
        else:
            z = z_all[row]
            if outside[row]:
                z[:, 0] = wrap(line, z[:, 0])
            row += 1
            yield Sighting(line, ids, z)
    if fault is not None:
        raise fault


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
