"""What describes a run in its recording: what was replayed (the input's size, digest and,
when small, its text), how (the command and the parameters), with which truth; and the
recording id those fix, so that the same run gives the same recording.
"""

from __future__ import annotations

import hashlib
import json
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from ekfviz import __version__
from ekfviz.core.errors import InputError
from ekfviz.core.truth import GroundTruth
from ekfviz.io.text import open_input

INPUT_TEXT_CAP = 4 * 1024 * 1024  # bytes of input embedded in a recording
# Fixed namespace: recording ids are uuid5(namespace, digest of what made the run).
RECORDING_NAMESPACE = uuid.UUID("6f1d3c52-8a47-5e0b-9c1e-2b7a4d9e0f31")


@dataclass(frozen=True, slots=True)
class RunInfo:
    """Everything that describes a run: what was replayed, how, and with which result.

    Build it with :func:`run_info`, which reads the input to fill in its size, sha256
    and text.
    """

    name: str
    command: str
    parameters: dict[str, object]
    input_path: Path
    input_size: int
    input_sha256: str
    input_text: str | None  # None when over INPUT_TEXT_CAP or not UTF-8 (see input_note)
    input_note: str | None
    truth: GroundTruth | None = None
    truth_path: Path | None = None
    truth_sha256: str | None = None
    version: str = field(default=__version__)
    kind: str = "replay"  # or "sweep": what ``ekfviz info`` says the recording is
    # each file's own sha256 where the input or truth is several files (a dataset)
    file_digests: dict[str, str] = field(default_factory=dict)

    @property
    def recording_id(self) -> str:
        """A UUID fixed by the version, the input, the truth and the parameters."""
        digest = hashlib.sha256(
            json.dumps(
                [self.version, self.input_sha256, self.truth_sha256, self.parameters],
                sort_keys=True,
                default=str,
            ).encode()
        ).hexdigest()
        return str(uuid.uuid5(RECORDING_NAMESPACE, digest))

    def markdown(self) -> str:
        """The run information as a markdown document for the viewer."""
        rows = [
            f"# {self.name}",
            "",
            f"- **ekfviz** {self.version}",
            f"- **command** `{self.command}`",
            f"- **input** `{self.input_path.name}`, {self.input_size} bytes,"
            f" sha256 `{self.input_sha256}`",
        ]
        if self.input_note:
            rows.append(f"- **input text** {self.input_note}")
        if self.truth_path is not None:
            rows.append(f"- **truth** `{self.truth_path.name}`, sha256 `{self.truth_sha256}`")
        rows += [
            f"- **file** `{path}`, sha256 `{digest}`" for path, digest in self.file_digests.items()
        ]
        rows += ["", "## Parameters", "", "| parameter | value |", "|---|---|"]
        rows += [f"| {key} | `{json_value(value)}` |" for key, value in self.parameters.items()]
        return "\n".join(rows) + "\n"


def run_info(
    name: str,
    command: str,
    parameters: dict[str, object],
    input_path: Path,
    truth: GroundTruth | None = None,
    truth_path: Path | None = None,
    input_files: Sequence[Path] | None = None,
    truth_files: Sequence[Path] | None = None,
    kind: str = "replay",
) -> RunInfo:
    """Describe a run, reading the input (and truth) file for its size, sha256 and text.

    :param input_files: the files an input directory is read from (an MRCLAM dataset's
        robot): their size and sha256 together, the text of none
    :param truth_files: likewise for the truth, instead of ``truth_path`` alone
    :raises InputError: when the input or truth file cannot be read
    """
    if input_files is not None and input_path.is_dir():
        size, sha256 = _digest_files(input_files)
        return replace(
            _described(
                name, command, parameters, input_path, size, sha256, None,
                "not embedded: a dataset directory", truth, truth_path, truth_files, input_files,
            ),
            kind=kind,
        )  # fmt: skip
    size, sha256, data = _digest(input_path, keep_up_to=INPUT_TEXT_CAP)
    text: str | None = None
    note: str | None = None
    if data is None:
        note = f"not embedded: over the {INPUT_TEXT_CAP // (1024 * 1024)} MiB cap"
    else:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            note = "not embedded: not UTF-8 text"
    return replace(
        _described(
            name, command, parameters, input_path, size, sha256, text, note, truth, truth_path,
            truth_files,
        ),
        kind=kind,
    )  # fmt: skip


def _described(
    name: str,
    command: str,
    parameters: dict[str, object],
    input_path: Path,
    size: int,
    sha256: str,
    text: str | None,
    note: str | None,
    truth: GroundTruth | None,
    truth_path: Path | None,
    truth_files: Sequence[Path] | None,
    input_files: Sequence[Path] | None = None,
) -> RunInfo:
    truth_sha256 = None
    truth_list = list(truth_files or ([] if truth_path is None else [truth_path]))
    if len(truth_list) == 1:  # the file's own digest, as sha256sum prints it
        truth_sha256 = _digest(truth_list[0], keep_up_to=0)[1]
    elif truth_list:  # a dataset's files: a digest of them all, each in file_digests
        truth_sha256 = _digest_files(truth_list)[1]
    listed = [*(input_files or []), *truth_list] if len(truth_list) > 1 or input_files else []
    return RunInfo(
        name=name,
        command=command,
        parameters=dict(parameters),
        input_path=input_path,
        input_size=size,
        input_sha256=sha256,
        input_text=text,
        input_note=note,
        truth=truth,
        truth_path=truth_path,
        truth_sha256=truth_sha256,
        file_digests=_file_digests(listed),
    )


def _file_digests(paths: Sequence[Path]) -> dict[str, str]:
    """Each file's own sha256, by path as given."""
    return {str(path): _digest(path, keep_up_to=0)[1] for path in paths}


def _digest_files(paths: Sequence[Path]) -> tuple[int, str]:
    """Total size and the sha256 of several files, each named and hashed in turn."""
    sha = hashlib.sha256()
    total = 0
    for path in paths:
        size, digest, _ = _digest(path, keep_up_to=0)
        total += size
        sha.update(f"{path.name}\0{digest}\n".encode())
    return total, sha.hexdigest()


def _digest(path: Path, *, keep_up_to: int) -> tuple[int, str, bytes | None]:
    """Size, sha256 and, when at most ``keep_up_to`` bytes, the content of a file."""
    sha = hashlib.sha256()
    kept = bytearray()
    size = 0
    # opened as the readers open their files (a FIFO refused, not waited on for ever)
    with open_input(path, "a regular file") as file:
        try:
            while block := file.read(1 << 20):
                sha.update(block)
                size += len(block)
                if size <= keep_up_to:
                    kept += block
        except OSError as error:  # the same words as the readers' errors
            raise InputError(path, 0, f"cannot be read ({error.strerror})") from None
    return size, sha.hexdigest(), bytes(kept) if size <= keep_up_to else None


def json_value(value: object) -> str:
    """A value as JSON text, anything JSON has no word for as its ``str``."""
    return json.dumps(value, default=str)
