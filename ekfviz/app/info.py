"""``info``: what a recording is, how it was made, how it ended and its result; and the
input log it embeds, extracted byte for byte."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.core.errors import InputError
from ekfviz.io.files import check_outputs, write_bytes_atomic

if TYPE_CHECKING:
    from ekfviz.readback.info import RecordingInfo


@dataclass(frozen=True, slots=True)
class InfoRequest:
    """A recording to describe, and where to extract its embedded input (None: not)."""

    recording: Path
    extract_input: Path | None = None


def info(request: InfoRequest) -> RecordingInfo:
    """What the recording holds; its input written where asked.

    :raises UsageError: a file that is no recording of ekfviz's
    :raises InputError: an input asked of a recording that embeds none
    :raises OutputError: the input cannot be written there
    """
    from ekfviz import readback

    recording, extract = request.recording, request.extract_input
    check_outputs(("--extract-input", extract), inputs=[recording])
    found = readback.read_recording_info(recording)
    if extract is not None:
        if found.input_text is None:
            reason = "it was over the size cap" if found.has_input else "this kind has no input"
            raise InputError(recording, 0, f"the input is not embedded ({reason})")
        write_bytes_atomic(extract, found.input_text.encode("utf-8"))
    return found
