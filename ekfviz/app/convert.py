"""``convert``: a classic log rewritten in the extended format, every number as written."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.errors import UsageError
from ekfviz.io.files import (
    check_outputs,
    real_path,
    refuse_overwrite,
    same_file,
    write_bytes_atomic,
)


@dataclass(frozen=True, slots=True)
class ConvertRequest:
    """A classic log, where to write it (``force``: over an existing file)."""

    source: Path
    target: Path
    force: bool = False


def convert(request: ConvertRequest) -> int:
    """Write the extended log.

    :return: the number of events written
    :raises InputError: the source is no classic log
    :raises UsageError, OutputError: the target is the source, exists, cannot be written
    """
    from ekfviz.io.convert import classic_to_extended

    source, target = request.source, request.target
    check_outputs(("TARGET", target))
    if same_file(target, source) or real_path(target) == real_path(source):
        raise UsageError(f"TARGET {target}: is the source itself: give another file")
    refuse_overwrite(request.force, ("TARGET", target))
    text, events = classic_to_extended(source)
    write_bytes_atomic(target, text.encode("utf-8"))
    return events
