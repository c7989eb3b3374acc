"""The text log (``log``): a line per step saying what it did, one per warning, and
the notes of a run (why it stopped).

A step's line, e.g. ``step 12 predict line 23: d 0.100, alpha 0.0100; update line 24:
2 landmarks (1 new), NIS 3.14``: its predict's (line, control), then its update's (line,
landmarks observed, first sightings, NIS summed over the landmarks used), or ``N
landmarks in the map`` for an update without observations. A batch's lines are made a
``%`` format each, the formats chosen by what the lines have and their values read from
the batch's columns: a long log has a line per step, and building each piece by piece
cost more than the rest of its logging.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.tables import utf8
from ekfviz.core.types import BoolArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.layers.arrow import INFO, WARN, column
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Canvas

# What a line has: a predict's variant is 2 * (has a line) + (has a control), an update's
# 5 * (has a line) + 4 without observations, else 2 * (new landmarks) + (some NIS).
_PREDICT_VARIANTS = 4
_UPDATE_VARIANTS = 10
Part = tuple[str, tuple[str, ...]]  # a format and the columns of its arguments


def _predict_part(variant: int) -> Part:
    """A predict's part of a line."""
    line, control = divmod(variant, 2)
    text = "step %d predict"
    names: tuple[str, ...] = ("step",)
    if line:
        text, names = text + " line %d", (*names, "line")
    if control:
        text, names = text + ": d %.3f, alpha %.4f", (*names, "d", "alpha")
    return text, names


def _update_part(variant: int) -> Part:
    """An update's part of a line, after its step."""
    line, what = divmod(variant, 5)
    text = "%s"
    names: tuple[str, ...] = ("kind",)
    if line:
        text, names = text + " line %d", (*names, "line")
    if what == 4:
        return text + ": %d landmarks in the map", (*names, "landmarks")
    text, names = text + ": %d landmarks", (*names, "landmarks")
    if what & 2:
        text, names = text + " (%d new)", (*names, "new")
    if what & 1:
        text, names = text + ", NIS %.2f", (*names, "nis")
    return text, names


def _line(predict: int, update: int) -> tuple[str, tuple[tuple[bool, str], ...]]:
    """The format of a line of a predict's variant and an update's (-1: none), and its
    arguments: (of the predict, column) each."""
    if update < 0:
        text, names = _predict_part(predict)
        return text, tuple((True, name) for name in names)
    body, update_names = _update_part(update)
    if predict < 0:
        return "step %d " + body, ((False, "step"), *((False, name) for name in update_names))
    head, predict_names = _predict_part(predict)
    return head + "; " + body, (
        *((True, name) for name in predict_names),
        *((False, name) for name in update_names),
    )


_LINES = {
    (predict + 1) * (_UPDATE_VARIANTS + 1) + update + 1: _line(predict, update)
    for predict in range(-1, _PREDICT_VARIANTS)
    for update in range(-1, _UPDATE_VARIANTS)
    if predict >= 0 or update >= 0
}


class TextLayer:
    """The lines of the text log."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas

    def send(self, batch: Batch) -> None:
        """A line per step: a predict's goes into the line of the update that follows it in
        the same step, both at the update; then one per warning at the same event."""
        steps = batch.rows.steps
        count = len(steps)
        held = np.zeros(count, dtype=bool)  # a predict whose line joins the update's after it
        held[:-1] = batch.is_predict[:-1] & batch.updating[1:] & (steps[:-1] == steps[1:])
        at = np.flatnonzero(~held)  # the rows of the lines
        text = self._lines(batch, held, at)
        level = [INFO] * len(text)
        line_of: IntArray | list[int] = at
        warned = [
            (k, extra.warnings) for k, extra in sorted(batch.extras.items()) if extra.warnings
        ]
        if warned:  # (a warning may name a file whose name is not UTF-8)
            text, level, line_of = self._with_warnings(batch, held, at, text, warned)
            text = [utf8(line) for line in text]
        self._canvas.send(
            style.LOG,
            batch.rows.pick(line_of),
            [
                column(rr.TextLog.descriptor_text(), pa.array(text, pa.utf8())),
                column(rr.TextLog.descriptor_level(), pa.array(level, pa.utf8())),
            ],
        )

    @staticmethod
    def _lines(batch: Batch, held: BoolArray, at: IntArray) -> list[str]:
        """The line at each row ``at``, made in one ``%`` each (see the module)."""
        count = len(held)
        steps, observed, lines = batch.rows.steps, batch.observed, batch.lines
        has_line = lines != 0  # (as a line number is tested: any but 0)
        predict = 2 * has_line + batch.has_control
        with_observations = np.zeros(count, dtype=bool)
        with_observations[observed.rows] = True
        what = np.where(with_observations, 2 * (observed.new > 0) + (observed.nis_used > 0), 4)
        update = 5 * has_line + what
        landmarks = observed.seen.copy()
        without = batch.corrected[~with_observations[batch.corrected]]
        landmarks[without] = batch.maps.counts[~with_observations[batch.corrected]]
        kinds = np.where(batch.updating, "update", "init")
        # each line's predict (its own row, or the row before an update it joins) and update
        is_predict = batch.is_predict[at]
        joined = ~is_predict & (at > 0) & held[np.maximum(at - 1, 0)]
        predict_at = np.where(is_predict, at, np.where(joined, at - 1, -1))
        update_at = np.where(is_predict, -1, at)
        code = (np.where(predict_at >= 0, predict[predict_at], -1) + 1) * (_UPDATE_VARIANTS + 1)
        code += np.where(update_at >= 0, update[update_at], -1) + 1
        columns = {
            "step": steps, "line": lines, "d": batch.controls[:, 0],
            "alpha": batch.controls[:, 1], "kind": kinds, "landmarks": landmarks,
            "new": observed.new, "nis": observed.nis_sum,
        }  # fmt: skip
        out = np.empty(len(at), dtype=object)
        for key in np.unique(code).tolist():
            picked = np.flatnonzero(code == key)
            p, u = predict_at[picked], update_at[picked]
            text, names = _LINES[key]
            values = [columns[name][p if of_predict else u].tolist() for of_predict, name in names]
            out[picked] = list(map(text.__mod__, zip(*values, strict=True)))
        result: list[str] = out.tolist()
        return result

    @staticmethod
    def _with_warnings(
        batch: Batch,
        held: BoolArray,
        at: IntArray,
        text: list[str],
        warned: list[tuple[int, tuple[str, ...]]],
    ) -> tuple[list[str], list[str], list[int]]:
        """The lines with a line per warning after each, at its row: a joined predict's
        warnings with its update's (as the update's own, by its step and line)."""
        steps, log_lines = batch.rows.steps, batch.lines
        extra: dict[int, list[str]] = {}
        for k, warnings in warned:
            row = k + 1 if held[k] else k  # (the update a predict joins may be a row)
            step, number = int(steps[row]), int(log_lines[row])
            extra.setdefault(row, []).extend(
                f"step {step} line {number}: {warning}" for warning in warnings
            )
        lines, levels, line_of = [], [], []
        for row, line in zip(at.tolist(), text, strict=True):
            lines.append(line)
            levels.append(INFO)
            line_of.append(row)
            for warning in extra.get(row, ()):
                lines.append(warning)
                levels.append(WARN)
                line_of.append(row)
        return lines, levels, line_of

    def note(self, step: int, event: int, text: str, level: str | rr.TextLogLevel) -> None:
        """A line at ``step`` and ``event``, at the latest time logged."""
        self._canvas.set_times(step, event, self._canvas.clock.last)
        self._canvas.entities.log(style.LOG, rr.TextLog(utf8(text), level=level))
