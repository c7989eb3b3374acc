"""Read back how an ekfviz recording was made: its properties, input and evaluation."""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import pyarrow as pa  # type: ignore[import-untyped]
from rerun.chunk import RrdReader

from ekfviz.viz import style


class NotARecordingError(Exception):
    """A file that is not an ekfviz recording, with a one-line reason."""


@dataclass(frozen=True, slots=True)
class RecordingInfo:
    """What ``ekfviz info`` shows; ``input_text`` is the input exactly as replayed."""

    path: Path
    recording_id: str
    name: str | None
    version: str
    command: str
    parameters: dict[str, object]
    input_name: str
    input_size: int
    input_sha256: str
    truth_name: str | None
    truth_sha256: str | None
    input_text: str | None
    evaluation_markdown: str | None
    compiled_kernel: bool | None = None  # None: made before ekfviz recorded it
    time_span: tuple[float, float] | None = None  # of the time timeline, seconds
    time_kind: str | None = None  # "timestamp" (Unix time) or "duration"

    def summary(self) -> list[tuple[str, str]]:
        """(key, value) rows for a two-column table."""
        rows = [
            ("recording", str(self.path)),
            ("name", self.name or "-"),
            ("recording id", self.recording_id),
            ("ekfviz", self.version),
            ("filter kernel", {True: "compiled", False: "numpy", None: "-"}[self.compiled_kernel]),
            ("command", self.command),
            ("input", f"{self.input_name} ({self.input_size} bytes)"),
            ("input sha256", self.input_sha256),
            ("input embedded", "yes" if self.input_text is not None else "no"),
        ]
        if self.time_span is not None:
            rows.append(("time span", _span(self.time_span, self.time_kind == "timestamp")))
        if self.truth_name is not None:
            rows += [("truth", self.truth_name), ("truth sha256", self.truth_sha256 or "-")]
        rows += [(f"  {key}", json.dumps(value)) for key, value in self.parameters.items()]
        return rows


PROPERTIES = "/__properties"
EKFVIZ_PROPERTIES = "/__properties/ekfviz"
TIME_PROPERTIES = "/__properties/time"


def read_recording_info(path: Path) -> RecordingInfo:
    """Read the properties, the embedded input and the evaluation of a recording.

    Only the chunks of the properties and the run documents are decoded.

    :raises NotARecordingError: when ``path`` is not an ``.rrd`` written by ekfviz
    """
    if not path.is_file():
        raise NotARecordingError(f"{path}: no such file")
    wanted = [
        PROPERTIES,
        EKFVIZ_PROPERTIES,
        TIME_PROPERTIES,
        f"/{style.RUN_INPUT}",
        f"/{style.RUN_EVALUATION}",
    ]
    latest: dict[str, dict[str, object]] = {}
    try:
        reader = RrdReader(path)
        recordings = reader.recordings()
        if not recordings:
            raise NotARecordingError(f"{path}: a Rerun file without a recording")
        for chunk in reader.stream(store=recordings[0]).filter(content=wanted):
            latest.setdefault(chunk.entity_path, {}).update(_last_values(chunk.to_record_batch()))
    except (RuntimeError, ValueError, OSError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise NotARecordingError(f"{path}: not a Rerun recording (.rrd): {reason}") from None
    properties = latest.get(EKFVIZ_PROPERTIES)
    if properties is None or "version" not in properties:
        raise NotARecordingError(f"{path}: a Rerun recording, but not one written by ekfviz")
    documents = {key: values.get("TextDocument:text") for key, values in latest.items()}
    embedded = bool(properties.get("input_embedded", False))
    return RecordingInfo(
        path=path,
        recording_id=recordings[0].recording_id,
        name=_optional(latest.get(PROPERTIES, {}).get("RecordingInfo:name")),
        version=str(properties["version"]),
        command=str(properties.get("command", "")),
        parameters=json.loads(str(properties.get("parameters", "{}"))),
        input_name=str(properties.get("input_name", "")),
        input_size=int(str(properties.get("input_size", 0))),
        input_sha256=str(properties.get("input_sha256", "")),
        truth_name=_optional(properties.get("truth_name")),
        truth_sha256=_optional(properties.get("truth_sha256")),
        input_text=_optional(documents.get(f"/{style.RUN_INPUT}")) if embedded else None,
        evaluation_markdown=_optional(documents.get(f"/{style.RUN_EVALUATION}")),
        compiled_kernel=(
            None if "compiled_kernel" not in properties else bool(properties["compiled_kernel"])
        ),
        time_span=_time_span(latest.get(TIME_PROPERTIES, {})),
        time_kind=_optional(latest.get(TIME_PROPERTIES, {}).get("kind")),
    )


def _time_span(values: dict[str, object]) -> tuple[float, float] | None:
    start, end = values.get("start"), values.get("end")
    if not isinstance(start, (int, float)) or not isinstance(end, (int, float)):
        return None
    return float(start), float(end)


def _span(span: tuple[float, float], epoch: bool) -> str:
    """The time span for people: dates for Unix times, seconds otherwise."""
    start, end = span
    if epoch:
        first = datetime.fromtimestamp(start, tz=timezone.utc).isoformat(timespec="milliseconds")
        last = datetime.fromtimestamp(end, tz=timezone.utc).isoformat(timespec="milliseconds")
        return f"{first} to {last} ({end - start:.3f} s)"
    return f"{start:.3f} s to {end:.3f} s ({end - start:.3f} s)"


def _last_values(batch: pa.RecordBatch) -> dict[str, object]:
    """The last non-null single value of every data column of a chunk."""
    values: dict[str, object] = {}
    for field, column in zip(batch.schema, batch.columns, strict=True):
        if (field.metadata or {}).get(b"rerun:kind") != b"data":
            continue
        for cell in reversed(column.to_pylist()):
            if cell:
                values[field.name] = cell[0]
                break
    return values


def _optional(value: object) -> str | None:
    return None if value is None else str(value)
