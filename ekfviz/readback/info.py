"""Read back how an ekfviz recording was made: its kind, properties, input, result, status.

Every recording ekfviz writes carries the property ``ekfviz`` (version, kind, command,
parameters, input): a ``replay``, a ``sweep``, a ``consistency`` study, or a recording
made through the :class:`~ekfviz.viz.recorder.Recorder` API by a filter of the user's
own (``recorder``). A replay also carries ``status``: finished, or stopped early (where
and why). Recordings made before these properties existed are still recognised by their
entities.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pyarrow as pa  # type: ignore[import-untyped]
from rerun.chunk import RrdReader

from ekfviz.io.text import special_kind
from ekfviz.readback.apart import NotARecordingError, read_apart
from ekfviz.viz import style

MAX_PROPERTY_CHARS = 1 << 20  # the parameters of a run are a few hundred bytes


KINDS = {
    "replay": "a replay of a log (ekfviz replay)",
    "sweep": "a parameter sweep (ekfviz sweep)",
    "compare": "a comparison of filters (ekfviz compare)",
    "check": "a filter checked against the reference, event by event (ekfviz check)",
    "consistency": "a Monte-Carlo consistency study (ekfviz consistency)",
    "recorder": "a filter of your own, recorded through the Recorder API",
}


@dataclass(frozen=True, slots=True)
class RunStatus:
    """How a run ended: ``finished``, or ``stopped`` early with where and why."""

    state: str
    reason: str | None = None
    event: int | None = None
    step: int | None = None
    line: int | None = None

    @property
    def stopped(self) -> bool:
        return self.state == "stopped"

    def describe(self) -> str:
        if not self.stopped:
            return self.state
        where = [f"event {self.event}"] if self.event is not None else []
        if self.step is not None:
            where.append(f"step {self.step}")
        if self.line:
            where.append(f"input line {self.line}")
        at = f" after {', '.join(where)}" if where else ""
        return f"stopped early{at}: {self.reason or 'no reason recorded'}"

    def to_json(self) -> dict[str, object]:
        return {
            "state": self.state,
            "stopped_early": self.stopped,
            "reason": self.reason,
            "event": self.event,
            "step": self.step,
            "line": self.line,
        }


@dataclass(frozen=True, slots=True)
class RecordingInfo:
    """What ``ekfviz info`` shows; ``input_text`` is the input exactly as replayed.

    Fields a kind of recording does not have (a consistency study has no input) are
    empty.
    """

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
    kind: str = "replay"
    application_id: str = "ekfviz"
    status: RunStatus | None = None  # None: not recorded (not a replay, or an older one)
    notes: list[str] = field(default_factory=list)
    # a replay's results beside its evaluation: the association's counts, the GPS error
    results: dict[str, object] = field(default_factory=dict)

    @property
    def has_input(self) -> bool:
        return bool(self.input_sha256)

    def summary(self) -> list[tuple[str, str]]:
        """(key, value) rows for a two-column table."""
        rows = [
            ("recording", str(self.path)),
            ("kind", KINDS.get(self.kind, self.kind)),
            ("status", self.status.describe() if self.status is not None else "-"),
            ("name", self.name or "-"),
            ("application id", self.application_id),
            ("recording id", self.recording_id),
            ("ekfviz", self.version or "-"),
        ]
        if self.compiled_kernel is not None:
            rows.append(("filter kernel", "compiled" if self.compiled_kernel else "numpy"))
        if self.command:
            rows.append(("command", self.command))
        if self.has_input:
            rows += [
                ("input", f"{self.input_name} ({self.input_size} bytes)"),
                ("input sha256", self.input_sha256),
                ("input embedded", "yes" if self.input_text is not None else "no"),
            ]
        if self.time_span is not None:
            rows.append(("time span", _span(self.time_span, self.time_kind == "timestamp")))
        if self.truth_name is not None:
            rows += [("truth", self.truth_name), ("truth sha256", self.truth_sha256 or "-")]
        rows += [(f"  {key}", json.dumps(value)) for key, value in self.parameters.items()]
        rows += [
            (RESULT_NAMES.get(key, key), _result(value)) for key, value in self.results.items()
        ]
        rows += [("note", note) for note in self.notes]
        return rows

    def to_json(self) -> dict[str, object]:
        """Everything shown, as plain JSON values (the input text itself left out)."""
        return {
            "recording": str(self.path),
            "kind": self.kind,
            "status": None if self.status is None else self.status.to_json(),
            "name": self.name,
            "application_id": self.application_id,
            "recording_id": self.recording_id,
            "ekfviz_version": self.version or None,
            "compiled_kernel": self.compiled_kernel,
            "command": self.command or None,
            "input": (
                {
                    "name": self.input_name,
                    "size": self.input_size,
                    "sha256": self.input_sha256,
                    "embedded": self.input_text is not None,
                }
                if self.has_input
                else None
            ),
            "truth": (
                None
                if self.truth_name is None
                else {"name": self.truth_name, "sha256": self.truth_sha256}
            ),
            "parameters": self.parameters,
            "time_span": None if self.time_span is None else list(self.time_span),
            "time_kind": self.time_kind,
            "evaluation_markdown": self.evaluation_markdown,
            "notes": self.notes,
            "results": self.results,
        }


PROPERTIES = "/__properties"
EKFVIZ_PROPERTIES = "/__properties/ekfviz"
STATUS_PROPERTIES = "/__properties/status"
TIME_PROPERTIES = "/__properties/time"
RESULTS_PROPERTIES = "/__properties/results"
CONSISTENCY_DOCUMENT = "/run/consistency"
SWEEP_DOCUMENT = "/run/sweep"
# entities every Recorder writes: how a recording of an older ekfviz is recognised
RECORDER_ENTITIES = [f"/{style.ROBOT}", f"/{style.LOG}"]


def read_recording_info(path: Path | str) -> RecordingInfo:
    """Read the kind, properties, embedded input, evaluation and status of a recording,
    in a child process (:func:`~ekfviz.readback.apart.read_apart`: a damaged file cannot
    abort this one).

    Only the chunks of the properties and the run documents are decoded.

    :raises NotARecordingError: with a one-line reason, when ``path`` is missing, a
        folder, not a Rerun file, cut short, damaged, or a recording ekfviz did not write
    """
    return read_apart(_read_recording_info, path)


def _read_recording_info(path: Path) -> RecordingInfo:
    """:func:`read_recording_info` in this process."""
    check_recording_path(path)
    wanted = [
        PROPERTIES,
        EKFVIZ_PROPERTIES,
        STATUS_PROPERTIES,
        TIME_PROPERTIES,
        RESULTS_PROPERTIES,
        f"/{style.RUN_INPUT}",
        f"/{style.RUN_EVALUATION}",
        CONSISTENCY_DOCUMENT,
        SWEEP_DOCUMENT,
    ]
    latest: dict[str, dict[str, object]] = {}
    notes: list[str] = []
    try:
        reader, recordings, footerless = recordings_of(path)
        entry = the_recording(path, recordings)
        for chunk in reader.stream(store=entry).filter(content=wanted):
            values = latest.setdefault(chunk.entity_path, {})
            values.update(_last_values(chunk.to_record_batch()))
        if EKFVIZ_PROPERTIES not in latest:  # an older ekfviz's? look for the Recorder's
            for chunk in reader.stream(store=entry).filter(content=RECORDER_ENTITIES):
                latest.setdefault(chunk.entity_path, {})
                if all(entity in latest for entity in RECORDER_ENTITIES):
                    break
    except (RuntimeError, ValueError, OSError) as error:
        raise NotARecordingError(unreadable(path, error)) from None
    if footerless:  # ekfviz saves atomically, footer included: cut short, or not closed
        notes.append(
            "the file has no footer: cut short, or its writer did not close it; what it"
            " holds may be its first part only (its status is not known)"
        )
        latest.pop(STATUS_PROPERTIES, None)  # ("finished": said before its last chunks)
    properties = latest.get(EKFVIZ_PROPERTIES)
    documents = {key: values.get("TextDocument:text") for key, values in latest.items()}
    name = _optional(latest.get(PROPERTIES, {}).get("RecordingInfo:name"))
    if properties is None or "version" not in properties:
        kind = _kind_by_entities(latest)
        # (an older ekfviz's is ekfviz's application: another program's that logs the
        # same entities is not ekfviz's)
        if kind is None or entry.application_id != style.APPLICATION_ID:
            raise NotARecordingError(
                f"{path}: a Rerun recording (application id {entry.application_id!r}),"
                " but not one written by ekfviz"
            )
        notes.append("made by an older ekfviz: it does not say its version or command")
        properties = {"kind": kind}
    try:
        info = _info(path, entry, latest, properties, documents, name, notes)
        # shown here, in the child: what the properties hold reads as ekfviz writes it (a
        # list of results, a NaN time span were tracebacks in the parent, showing them)
        info.summary()
        info.to_json()
        return info
    except (ValueError, TypeError, AttributeError, OverflowError, KeyError, IndexError) as error:
        reason = str(error).splitlines()[0][:80] if str(error) else type(error).__name__
        raise NotARecordingError(
            f"{path}: its ekfviz properties do not read ({reason}), expected those ekfviz"
            " writes: a damaged recording or one another program wrote"
        ) from None


def _info(
    path: Path,
    entry: Any,
    latest: dict[str, dict[str, object]],
    properties: dict[str, object],
    documents: dict[str, object],
    name: str | None,
    notes: list[str],
) -> RecordingInfo:
    """The recording's information from the values read (see :func:`read_recording_info`).

    :raises ValueError, TypeError: properties of the wrong type
    """
    kind = str(properties.get("kind") or _kind_by_entities(latest) or "replay")
    embedded = bool(properties.get("input_embedded", False))
    evaluation = documents.get(f"/{style.RUN_EVALUATION}") or documents.get(
        CONSISTENCY_DOCUMENT if kind == "consistency" else SWEEP_DOCUMENT
    )
    return RecordingInfo(
        path=path,
        recording_id=entry.recording_id,
        name=name,
        version=str(properties.get("version", "")),
        command=str(properties.get("command", "") or ""),
        parameters=_parameters(properties.get("parameters")),
        input_name=str(properties.get("input_name", "") or ""),
        input_size=int(str(properties.get("input_size", 0) or 0)),
        input_sha256=str(properties.get("input_sha256", "") or ""),
        truth_name=_optional(properties.get("truth_name")),
        truth_sha256=_optional(properties.get("truth_sha256")),
        input_text=_optional(documents.get(f"/{style.RUN_INPUT}")) if embedded else None,
        evaluation_markdown=_optional(evaluation),
        compiled_kernel=(
            None if "compiled_kernel" not in properties else bool(properties["compiled_kernel"])
        ),
        time_span=_time_span(latest.get(TIME_PROPERTIES, {})),
        time_kind=_optional(latest.get(TIME_PROPERTIES, {}).get("kind")),
        kind=kind,
        application_id=entry.application_id,
        status=_status(latest.get(STATUS_PROPERTIES)),
        notes=notes,
        results=json.loads(str(latest.get(RESULTS_PROPERTIES, {}).get("json", "{}") or "{}")),
    )


def reader_of(path: Path) -> RrdReader:
    """Rerun's reader of the recording at ``path``, whatever its name: Rerun's reader takes
    UTF-8 names only, so a name that is not (bytes a file system allows) is read through
    the descriptor of the file opened here (``/proc/self/fd/N``, kept open: a recording is
    read in a child process of its own, see :mod:`ekfviz.readback.apart`)."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        if os.path.isdir("/proc/self/fd"):
            return RrdReader(f"/proc/self/fd/{os.open(path, os.O_RDONLY)}")
    return RrdReader(path)


def recordings_of(path: Path) -> tuple[RrdReader, list[Any], bool]:
    """Rerun's reader of the file at ``path``, its recordings (not its blueprints), and
    whether it lacks its footer (cut short, or its writer did not close it: Rerun says so
    in a Python warning)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = reader_of(path)
        recordings = [entry for entry in reader.recordings() if entry.kind == "recording"]
    return reader, recordings, any("no footer" in str(w.message) for w in caught)


def the_recording(path: Path, recordings: list[Any]) -> Any:
    """The one recording of a file (:func:`recordings_of`).

    :raises NotARecordingError: none, or several (``rerun rrd merge``: which one is meant
        is not known)
    """
    if not recordings:
        raise NotARecordingError(f"{path}: a Rerun file without a recording")
    if len(recordings) > 1:
        raise NotARecordingError(
            f"{path}: holds {len(recordings)} recordings, expected one (files merged?)"
        )
    return recordings[0]


def check_recording_path(path: Path) -> None:
    """Refuse what cannot be a recording before Rerun's reader is given it: a folder, a
    missing file, a device, a FIFO, a socket (a device may never end).

    :raises NotARecordingError: saying which
    """
    if path.is_dir():
        raise NotARecordingError(f"{path}: is a folder, expected a recording (.rrd)")
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise NotARecordingError(f"{path}: no such file") from None
    except OSError as error:
        raise NotARecordingError(f"{path}: cannot be read ({error.strerror})") from None
    kind = special_kind(mode)
    if kind is not None:
        raise NotARecordingError(
            f"{path}: is {kind}, not a regular file; expected a recording (.rrd)"
        )


def unreadable(path: Path, error: BaseException) -> str:
    """One line saying why Rerun could not read ``path``: cut short, or no recording."""
    text = str(error)
    if "exceeds file size" in text or ("too small" in text and _rrd_header(path)):
        size = path.stat().st_size
        return (
            f"{path}: truncated after {size} bytes (a recording cut short, e.g. by an"
            " interrupted copy)"
        )
    if "too small" in text or "not an rrd" in text.lower():
        return f"{path}: not a Rerun recording (.rrd)"
    reason = text.splitlines()[0] if text else type(error).__name__
    return f"{path}: not a Rerun recording (.rrd): {reason}"


RESULT_NAMES = {"association": "association", "gps": "GPS reference"}


def _result(value: object) -> str:
    """One result as a line: a mapping as ``key value, ...`` (numbers to 4 digits)."""
    if isinstance(value, dict):
        return ", ".join(
            f"{key} {f'{item:.4g}' if isinstance(item, float) else item}"
            for key, item in value.items()
        )
    return json.dumps(value)


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


def _rrd_header(path: Path) -> bool:
    """Whether a file starts like a Rerun file (its four-character code)."""
    with path.open("rb") as file:
        head = file.read(4)
    return bool(head) and b"RRF2".startswith(head)


def _kind_by_entities(latest: dict[str, dict[str, object]]) -> str | None:
    """The kind of a recording without ekfviz properties, from what it holds."""
    if CONSISTENCY_DOCUMENT in latest:
        return "consistency"
    if SWEEP_DOCUMENT in latest:
        return "sweep"
    if f"/{style.RUN_INPUT}" in latest:
        return "replay"
    if all(entity in latest for entity in RECORDER_ENTITIES):
        return "recorder"
    return None


def _status(values: dict[str, object] | None) -> RunStatus | None:
    if not values or "state" not in values:
        return None

    def number(key: str) -> int | None:
        value = values.get(key)
        return None if value is None or int(str(value)) < 0 else int(str(value))

    return RunStatus(
        state=str(values["state"]),
        reason=_optional(values.get("reason")) or None,
        event=number("event"),
        step=number("step"),
        line=number("line"),
    )


def _last_values(batch: pa.RecordBatch) -> dict[str, object]:
    """The last non-null single value of every data column of a chunk."""
    values: dict[str, object] = {}
    for field_, column in zip(batch.schema, batch.columns, strict=True):
        if (field_.metadata or {}).get(b"rerun:kind") != b"data":
            continue
        for cell in reversed(column.to_pylist()):
            if cell:
                values[field_.name] = cell[0]
                break
    return values


def _parameters(value: object) -> dict[str, object]:
    """The parameters property: a JSON object, within the limits of inputs' JSON."""
    text = str(value or "{}")
    if len(text) > MAX_PROPERTY_CHARS:
        raise ValueError("parameters over 1 MiB")
    try:
        document = json.loads(text)
    except RecursionError:
        raise ValueError("parameters nested too deep") from None
    if not isinstance(document, dict):
        raise ValueError("parameters that are not a JSON object")
    return document


def _optional(value: object) -> str | None:
    return None if value is None else str(value)
