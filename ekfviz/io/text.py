"""Line-by-line reading of numeric text files, shared by the log and truth readers."""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.io.errors import InputError
from ekfviz.models.angles import wrap_angles

_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_NUMBERS = re.compile(rf"{_NUMBER.pattern}(?: {_NUMBER.pattern})*")  # tokens joined by spaces
_NON_FINITE = re.compile(r"[-+]?(?:nan|inf|infinity)", re.IGNORECASE)

ProgressCallback = Callable[[int], None]
WarningCallback = Callable[[str], None]
MAX_LINE_BYTES = 1 << 20  # an observation of some 50,000 landmarks: far past any EKF


def token_lines(
    path: Path, progress: ProgressCallback | None = None
) -> Iterator[tuple[int, list[str]]]:
    """Stream the non-blank lines of a file as tokens, never holding the whole file.

    Accepts tabs or spaces, trailing separators, LF, CRLF or CR line ends, a UTF-8
    byte-order mark and ``#`` comments.

    :param progress: called now and then with the number of bytes read so far
    :return: iterator of (1-based line number, whitespace-separated tokens of that line)
    :raises InputError: a missing or unreadable file, text that is not UTF-8
    """
    try:
        handle = path.open("rb")
    except FileNotFoundError:
        raise InputError(path, 0, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, 0, "is a directory, expected a text file") from None
    except OSError as error:
        raise InputError(path, 0, f"cannot be read ({error.strerror})") from None
    with handle:
        bytes_read = 0
        number = 0
        # readline with a limit: a runaway line cannot take the memory
        while raw := handle.readline(MAX_LINE_BYTES + 1):
            number += 1
            if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
                raise InputError(
                    path,
                    number,
                    f"found a line longer than {MAX_LINE_BYTES // (1 << 20)} MiB,"
                    " expected one event a line",
                )
            bytes_read += len(raw)
            if progress is not None and number % 4096 == 0:
                progress(bytes_read)
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError:
                raise InputError(path, number, "found bytes that are not UTF-8 text") from None
            if number == 1 and text.startswith(
                "\ufeff"
            ):  # a byte-order mark, as some editors write
                text = text[1:]
            if "\r" in text:  # CRLF, or lines ended by CR alone (classic Mac)
                pieces = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
                if pieces[-1] == "":
                    pieces.pop()
                for piece in pieces[:-1]:
                    tokens = piece.split("#", 1)[0].split()
                    if tokens:
                        yield number, tokens
                    number += 1
                text = pieces[-1] if pieces else ""
            tokens = text.split("#", 1)[0].split()
            if tokens:
                yield number, tokens
        if progress is not None:
            progress(bytes_read)


def numeric_lines(
    path: Path, progress: ProgressCallback | None = None
) -> Iterator[tuple[int, list[float]]]:
    """Stream the non-blank lines of a file as numbers (see :func:`token_lines`).

    :raises InputError: as :func:`token_lines`, and for a token that is not a finite
        decimal number
    """
    for number, tokens in token_lines(path, progress):
        # one regex match a line for the usual case; token by token to name a bad one
        if _NUMBERS.fullmatch(" ".join(tokens)):
            values = list(map(float, tokens))
            if all(map(math.isfinite, values)):
                yield number, values
                continue
        yield number, [parse_number(path, number, token) for token in tokens]


BLOCK_BYTES = 1 << 18  # bytes read per block by numeric_blocks


def numeric_blocks(
    path: Path, columns: int, what: str, progress: ProgressCallback | None = None
) -> Iterator[tuple[list[int], FloatArray]]:
    """Stream a table of ``columns`` numbers a line in blocks: (line numbers, (k, columns)).

    For long, regular files (MRCLAM's tens of thousands of lines): a block is converted
    in one go, and only a block that does not convert is read line by line, to name the
    first bad line as :func:`numeric_lines` would (``what`` says what a line holds).

    :raises InputError: as :func:`numeric_lines`, and for a line of another length
    """
    try:
        handle = path.open("rb")
    except FileNotFoundError:
        raise InputError(path, 0, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, 0, "is a directory, expected a text file") from None
    except OSError as error:
        raise InputError(path, 0, f"cannot be read ({error.strerror})") from None
    with handle:
        number = 0
        done = 0
        while raw := handle.readlines(BLOCK_BYTES):
            first = number + 1
            number += len(raw)
            done += sum(map(len, raw))
            lines: list[int] = []
            data: list[bytes] = []
            for k, text in enumerate(raw, start=first):
                body = text.split(b"#", 1)[0] if b"#" in text else text
                if body.strip():
                    lines.append(k)
                    data.append(body)
            try:
                values = list(map(float, b" ".join(data).split()))
                table = np.array(values, dtype=np.float64)
                good = len(values) == columns * len(data) and bool(np.isfinite(table).all())
            except ValueError:
                good = False
            if not good:
                # the slow way, to name the line at fault
                table = np.array(_checked_rows(path, first, raw, columns, what), dtype=np.float64)
            if progress is not None:
                progress(done)
            if lines:
                yield lines, table.reshape(len(lines), columns)


def _checked_rows(
    path: Path, first: int, raw: list[bytes], columns: int, what: str
) -> list[list[float]]:
    rows = []
    for number, text in enumerate(raw, start=first):
        try:
            body = text.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(path, number, "found bytes that are not UTF-8 text") from None
        tokens = body.split("#", 1)[0].split()
        if not tokens:
            continue
        if len(tokens) != columns:
            raise InputError(
                path, number, f"found {len(tokens)} numbers, expected {columns}: {what}"
            )
        rows.append([parse_number(path, number, token) for token in tokens])
    return rows


def parse_number(path: Path, line: int, token: str) -> float:
    """A finite decimal number, or an :class:`InputError` naming the token."""
    if _NUMBER.fullmatch(token):
        value = float(token)
        if math.isfinite(value):
            return value
        raise InputError(path, line, f"found {token!r}, which overflows, expected a finite number")
    if _NON_FINITE.fullmatch(token):
        raise InputError(path, line, f"found {token!r}, expected a finite number")
    shown = token if len(token) <= 20 else token[:20] + "..."
    raise InputError(path, line, f"found {shown!r}, expected a decimal number")


def format_number(value: float, precision: int | None) -> str:
    """``precision`` decimals, or the shortest text that reads back exactly when None."""
    return repr(float(value)) if precision is None else f"{value:.{precision}f}"


class BearingWrapper:
    """Wraps bearings outside (-pi, pi] into range, warning once per file."""

    def __init__(self, path: Path, warn: WarningCallback | None) -> None:
        self._path = path
        self._warn = warn
        self._warned = False

    def __call__(self, line: int, bearings: FloatArray) -> FloatArray:
        outside = (bearings > math.pi) | (bearings <= -math.pi)
        if not outside.any():
            return bearings
        if self._warn is not None and not self._warned:
            first = float(bearings[outside][0])
            self._warn(
                f"{self._path}:{line}: found bearing {first:g} outside (-pi, pi],"
                " wrapped it and any later ones into range"
            )
        self._warned = True
        return wrap_angles(bearings)
