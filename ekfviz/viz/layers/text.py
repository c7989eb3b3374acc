"""The text log (``log``): a line per step saying what it did, one per warning, and
the notes of a run (why it stopped)."""

from __future__ import annotations

import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.records import EventKind, EventRecord
from ekfviz.viz import style
from ekfviz.viz.layers.arrow import INFO, WARN, column
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Canvas

_KIND = {kind: kind.value for kind in EventKind}  # (an enum's value is a slow lookup)


def describe(record: EventRecord, seen: int, new: int, nis: float, nis_used: int) -> str:
    """The log line of a record; for an update, ``seen`` observations of which ``new``
    first sightings, and the NIS summed over the ``nis_used`` landmarks it used."""
    kind = record.kind
    where = f"step {record.step} {_KIND[kind]}"
    if record.line:
        where += f" line {record.line}"
    if kind is EventKind.PREDICT:
        control = record.control
        if control is None:
            return where
        return f"{where}: d {control[0]:.3f}, alpha {control[1]:.4f}"
    if record.observations is None:
        return f"{where}: {record.n_landmarks} landmarks in the map"
    text = f"{where}: {seen} landmarks"
    if new:
        text += f" ({new} new)"
    if nis_used:
        text += f", NIS {nis:.2f}"
    return text


def describe_predict(step: int, line: int, control: tuple[float, float] | None) -> str:
    """:func:`describe` of a predict given as columns (see
    :class:`~ekfviz.viz.layers.batch.Batch`)."""
    where = f"step {step} predict line {line}" if line else f"step {step} predict"
    if control is None:
        return where
    return f"{where}: d {control[0]:.3f}, alpha {control[1]:.4f}"


class TextLayer:
    """The lines of the text log."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas

    def send(self, batch: Batch) -> None:
        """A line per step: a predict's goes into the line of the update that follows it in
        the same step, both at the update; then one per warning at the same event."""
        records, observed = batch.records, batch.observed
        steps = batch.rows.steps.tolist()
        text: list[str] = []
        level: list[str] = []
        line_of: list[int] = []
        held: tuple[str, tuple[str, ...]] | None = None  # a predict's line and warnings
        count = len(records)
        no_warnings: tuple[str, ...] = ()
        for k, (record, is_predict, seen, new, nis_sum, nis_used) in enumerate(
            zip(
                records,
                batch.is_predict.tolist(),
                observed.seen.tolist(),
                observed.new.tolist(),
                observed.nis_sum.tolist(),
                observed.nis_used.tolist(),
                strict=True,
            )
        ):
            if record is None:  # a predict of a segment: its line and control in columns
                line = describe_predict(steps[k], batch.lines[k], batch.controls[k])
                warnings = no_warnings
            else:
                line = describe(record, seen, new, nis_sum, nis_used)
                warnings = record.warnings
            if (
                is_predict
                and k + 1 < count
                and (following := records[k + 1]) is not None
                and following.kind is EventKind.UPDATE
                and steps[k + 1] == steps[k]
            ):
                held = (line, warnings)
                continue
            if held is not None:
                line = f"{held[0]}; {line.split(' ', 2)[2]}"  # "step N predict ...; update ..."
                warnings = held[1] + warnings
                held = None
            text.append(line)
            level.append(INFO)
            line_of.append(k)
            for warning in warnings:
                assert record is not None  # a predict of a segment has no warnings
                text.append(f"step {record.step} line {record.line}: {warning}")
                level.append(WARN)
                line_of.append(k)
        self._canvas.send(
            style.LOG,
            batch.rows.pick(line_of),
            [
                column(rr.TextLog.descriptor_text(), pa.array(text, pa.utf8())),
                column(rr.TextLog.descriptor_level(), pa.array(level, pa.utf8())),
            ],
        )

    def note(self, step: int, event: int, text: str, level: str | rr.TextLogLevel) -> None:
        """A line at ``step`` and ``event``, at the latest time logged."""
        self._canvas.set_times(step, event, self._canvas.clock.last)
        self._canvas.entities.log(style.LOG, rr.TextLog(text, level=level))
