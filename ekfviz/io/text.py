"""Line-by-line reading of numeric text files, shared by the log and truth readers."""

from __future__ import annotations

import math
import os
import re
import stat
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, NoReturn

import numpy as np

from ekfviz.core.errors import InputError
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.io.decimals import plain_decimals, token_bounds
from ekfviz.models.angles import wrap_angles

# ASCII digits only: float() also takes the digits of other scripts (Arabic-Indic,
# full-width) and underscores ("1_000"), which no log means as numbers
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", re.ASCII)
_NUMBERS = re.compile(rf"{_NUMBER.pattern}(?: {_NUMBER.pattern})*", re.ASCII)  # joined by spaces
_NON_FINITE = re.compile(r"[-+]?(?:nan|inf|infinity)", re.IGNORECASE)

ProgressCallback = Callable[[int], None]
WarningCallback = Callable[[str], None]
MAX_LINE_BYTES = 1 << 20  # an observation of some 50,000 landmarks: far past any EKF
# Every number read from any input lies in [-MAX_MAGNITUDE, MAX_MAGNITUDE]: its square,
# and the square of that, stay far from float64's overflow (1.8e308), so no sum of
# squares in a filter overflows on an input's account, and time stamps in microseconds
# since 1970 (1.8e15) are still inside. Physical values of a 2-D run are far smaller.
MAX_MAGNITUDE = 1e18
RANGE_TEXT = "+-1e18"  # MAX_MAGNITUDE in messages
# A recording's ``time`` timeline counts nanoseconds in 64 bits (a timestamp since 1970
# or a duration): +-9.22e9 s. A log's time stamps beyond (Unix time past the year 2261,
# milliseconds taken for seconds) are refused where they are read, naming their line,
# rather than overflowing when the run is recorded.
MAX_TIME_S = 9.2e9
TIME_RANGE_TEXT = "+-9.2e9 s"  # MAX_TIME_S in messages
BLOCK_BYTES = 1 << 18  # bytes read at once
BOM = b"\xef\xbb\xbf"


def open_input(path: Path, what: str = "a text file") -> BinaryIO:
    """Open an input file for reading bytes, or say in one line why it cannot be.

    :param what: what was expected at ``path``, for the message
    :raises InputError: a missing file, a directory, an unreadable file
    """
    try:
        if path.is_dir():
            raise InputError(path, 0, f"is a directory, expected {what}")
        # opened without waiting: a FIFO with no writer would block open() for ever
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        kind = special_kind(os.fstat(fd).st_mode)
        if kind is not None:
            os.close(fd)
            raise InputError(path, 0, f"is {kind}, not a regular file; expected {what}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except FileNotFoundError:
        raise InputError(path, 0, f"no such file, expected {what}") from None
    except IsADirectoryError:
        raise InputError(path, 0, f"is a directory, expected {what}") from None
    except OSError as error:
        raise InputError(path, 0, f"cannot be read ({error.strerror})") from None


def special_kind(mode: int) -> str | None:
    """What a file that is not a regular one is (None for a regular file). A log is read
    twice (its format told from its first line, then its events) and must end: a pipe
    cannot be read again, a terminal or a FIFO may wait for ever."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "a special file"


def line_blocks(path: Path, handle: BinaryIO) -> Iterator[tuple[int, list[bytes]]]:
    """The lines of an open file in blocks of about :data:`BLOCK_BYTES`: the one policy of
    every reader for line ends and byte-order marks.

    A line ends at LF, CRLF or CR alone (the three may mix); a UTF-8 byte-order mark at the
    very start of the file is dropped. The lines are returned without their ends.

    :return: iterator of (1-based number of the block's first line, its lines)
    :raises InputError: a line longer than :data:`MAX_LINE_BYTES`
    """
    number = 1
    carry = b""  # the start of a line whose end is not read yet
    chunk = handle.read(BLOCK_BYTES).removeprefix(BOM)
    while True:
        at_end = not chunk
        text = carry + chunk
        held = b""
        if not at_end and text.endswith(b"\r"):  # maybe a CRLF split between two reads
            text, held = text[:-1], b"\r"
        if b"\r" in text:
            text = text.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        lines = text.split(b"\n")
        carry = lines.pop() + held
        if len(carry) > MAX_LINE_BYTES:
            _too_long(path, number + len(lines))
        if lines:
            for k, line in enumerate(lines):
                if len(line) > MAX_LINE_BYTES:
                    _too_long(path, number + k)
            yield number, lines
            number += len(lines)
        if at_end:
            break
        chunk = handle.read(BLOCK_BYTES)
    if carry:
        yield number, [carry]


def _too_long(path: Path, line: int) -> NoReturn:
    raise InputError(
        path,
        line,
        f"found a line longer than {MAX_LINE_BYTES // (1 << 20)} MiB, expected one event a line",
    )


def token_lines(
    path: Path, progress: ProgressCallback | None = None
) -> Iterator[tuple[int, list[str]]]:
    """Stream the non-blank lines of a file as tokens, never holding the whole file.

    Accepts tabs or spaces, trailing separators, LF, CRLF or CR line ends, a UTF-8
    byte-order mark and ``#`` comments (see :func:`line_blocks`).

    :param progress: called now and then with the number of bytes read so far
    :return: iterator of (1-based line number, whitespace-separated tokens of that line)
    :raises InputError: a missing or unreadable file, text that is not UTF-8
    """
    with open_input(path) as handle:
        for first, lines in line_blocks(path, handle):
            yield from block_tokens(path, first, lines)
            if progress is not None:
                progress(handle.tell())


def block_tokens(path: Path, first: int, lines: list[bytes]) -> Iterator[tuple[int, list[str]]]:
    """The non-blank lines of a block (``first``: the first one's number) as tokens.

    :raises InputError: a line that is not UTF-8
    """
    for number, raw in enumerate(lines, start=first):
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(path, number, "found bytes that are not UTF-8 text") from None
        tokens = text.split("#", 1)[0].split()
        if tokens:
            yield number, tokens


def numeric_lines(
    path: Path, progress: ProgressCallback | None = None
) -> Iterator[tuple[int, list[float]]]:
    """Stream the non-blank lines of a file as numbers (see :func:`token_lines`).

    :raises InputError: as :func:`token_lines`, and for a token that is not a decimal
        number within +-:data:`MAX_MAGNITUDE`
    """
    for number, tokens in token_lines(path, progress):
        values = plain_numbers(tokens)
        if values is None:  # token by token, to name the bad one
            values = [parse_number(path, number, token) for token in tokens]
        yield number, values


def plain_numbers(tokens: list[str]) -> list[float] | None:
    """The tokens as numbers where every one is a decimal number within
    +-:data:`MAX_MAGNITUDE` (one regular expression for the lot: the usual case), else
    None (:func:`parse_number` then names the bad one)."""
    if _NUMBERS.fullmatch(" ".join(tokens)):
        values = list(map(float, tokens))
        if all(-MAX_MAGNITUDE <= v <= MAX_MAGNITUDE for v in values) and (
            0.0 not in values
            or not any(underflows(t) for t, v in zip(tokens, values, strict=True) if v == 0)
        ):
            return values
    return None


# The bytes a block of plain decimal numbers is made of. float() accepts more ("nan",
# "inf", "1_000"): a block with any other byte is read line by line, as numeric_lines does.
_PLAIN_BYTES = b"0123456789+-.eE \t"


@dataclass(frozen=True, slots=True)
class NumberBlock:
    """The non-blank lines of a block of a file as numbers, every line's in one array.

    :param lines: (k,) 1-based line numbers
    :param counts: (k,) how many numbers each line holds
    :param starts: (k,) where each line's numbers start in ``values``
    :param values: (sum(counts),) the numbers, line after line
    :param fault: the error of the first bad line after these, if the block has one
    """

    lines: list[int]
    counts: IntArray
    starts: IntArray
    values: FloatArray
    fault: InputError | None = None


def number_blocks(path: Path, progress: ProgressCallback | None = None) -> Iterator[NumberBlock]:
    """:func:`numeric_lines` in blocks: the same lines, numbers and errors, a block of
    some :data:`BLOCK_BYTES` converted in one go (a long log's 200,000 lines would cost
    a regular expression and a list each).

    A block that does not convert at once (a byte outside plain decimal numbers, a number
    out of range, text that is not UTF-8) is read line by line, as :func:`numeric_lines`
    reads it: its lines up to the first bad one come with that line's error as the
    block's ``fault``, and nothing after it is read. The caller raises the fault once it
    has used the lines before it (a run cut short keeps everything before the bad line).

    :raises InputError: a missing or unreadable file, a line too long
    """
    with open_input(path) as handle:
        for first, raw in line_blocks(path, handle):
            block = _plain_block(first, raw)
            if block is None:
                block = _checked_block(path, first, raw)
            if progress is not None:
                progress(handle.tell())
            if block.lines or block.fault is not None:
                yield block
            if block.fault is not None:
                return


def _plain_block(first: int, raw: list[bytes]) -> NumberBlock | None:
    """The block converted in one go, or None where it needs a look line by line."""
    joined = b"\n".join(raw)
    if not joined.isascii():  # comments too: one policy for text (UTF-8, line by line)
        return None
    if b"#" in joined:
        raw = [text.split(b"#", 1)[0] for text in raw]
        joined = b"\n".join(raw)
    converted = plain_table(joined, len(raw))  # comments are cut: no byte of theirs
    if converted is None:
        return None
    values, counts_all, _ = converted
    kept = np.flatnonzero(counts_all)
    counts = counts_all[kept]
    starts = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    return NumberBlock((kept + first).tolist(), counts, starts, values)


def plain_table(
    joined: bytes, lines: int, digits: bool = False
) -> tuple[FloatArray, IntArray, BoolArray | None] | None:
    """The numbers of ``lines`` lines joined by LF, how many each line holds and (where
    ``digits``) whether each is written as ASCII digits alone (an integer as written, not
    ``+5``, ``5.0`` or ``5e0``), where every byte is of plain decimal numbers or a
    separator and every number is within +-:data:`MAX_MAGNITUDE`; else None (the caller
    reads line by line, to name the fault)."""
    if joined.translate(None, _PLAIN_BYTES + b"\n"):
        return None  # a byte of something else ("nan", "1_000", another script's digits)
    converted = _converted(joined, lines, digits)
    if converted is None or not (np.abs(converted[0]) <= MAX_MAGNITUDE).all():
        return None
    return converted


def _converted(
    joined: bytes, lines: int, digits: bool = False
) -> tuple[FloatArray, IntArray, BoolArray | None] | None:
    """The numbers of ``joined`` (``lines`` lines of plain bytes joined by LF), how many
    each line holds and (``digits``) whether each is written as digits alone; None where
    a token is not a number: plain decimals at once (:mod:`ekfviz.io.decimals`), any
    other block by ``float()`` of each token, the counts in numpy."""
    text = np.frombuffer(joined, dtype=np.uint8)
    starts, ends, line_of = token_bounds(text)
    counts = np.bincount(line_of, minlength=lines).astype(np.int64)
    decimals = plain_decimals(joined, text, starts, ends)
    if decimals is not None:
        return decimals[0], counts, decimals[1] if digits else None
    tokens = joined.split()
    try:
        values = np.array(list(map(float, tokens)), dtype=np.float64)
    except ValueError:
        return None
    zeros = np.flatnonzero(values == 0).tolist()
    if zeros and any(map(underflows, set(map(tokens.__getitem__, zeros)))):
        return None  # line by line, to name it (each way a 0 is written asked once)
    plain = np.array(list(map(bytes.isdigit, tokens)), dtype=bool) if digits else None
    return values, counts, plain


def _checked_block(path: Path, first: int, raw: list[bytes]) -> NumberBlock:
    """The block line by line, as :func:`numeric_lines` reads it, up to its first bad line."""
    lines: list[int] = []
    rows: list[list[float]] = []
    fault = None
    try:
        for number, tokens in block_tokens(path, first, raw):
            rows.append([parse_number(path, number, token) for token in tokens])
            lines.append(number)
    except InputError as error:
        fault = error
    counts = np.array([len(row) for row in rows], dtype=np.int64)
    starts = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    values = np.array([v for row in rows for v in row], dtype=np.float64)
    return NumberBlock(lines, counts, starts, values, fault)


def numeric_blocks(
    path: Path, columns: int, what: str, progress: ProgressCallback | None = None
) -> Iterator[tuple[list[int], FloatArray]]:
    """Stream a table of ``columns`` numbers a line in blocks: (line numbers, (k, columns)).

    For long, regular files (MRCLAM's tens of thousands of lines): a block is converted
    in one go, and only a block that does not convert is read line by line, to name the
    first bad line as :func:`numeric_lines` would (``what`` says what a line holds). The
    lines before a bad one are yielded before the error is raised, so that a run cut
    short by it keeps everything up to it.

    :raises InputError: as :func:`numeric_lines`, and for a line of another length
    """
    with open_input(path) as handle:
        for first, raw in line_blocks(path, handle):
            block = _plain_block(first, raw)
            if block is not None and (block.counts == columns).all():
                lines, table = block.lines, block.values.reshape(len(block.lines), columns)
            else:  # the slow way, to name the line at fault (every line's count checked)
                lines, rows, fault = _checked_rows(path, first, raw, columns, what)
                if fault is not None:
                    if rows:
                        yield lines, np.array(rows, dtype=np.float64)
                    raise fault
                table = np.array(rows, dtype=np.float64).reshape(len(rows), columns)
            if progress is not None:
                progress(handle.tell())
            if lines:
                yield lines, table


def _checked_rows(
    path: Path, first: int, raw: list[bytes], columns: int, what: str
) -> tuple[list[int], list[list[float]], InputError | None]:
    """The line numbers and rows of a block's non-blank lines up to its first bad line
    (blank as :func:`block_tokens` has it: Unicode's white space too), and the error of
    that line."""
    lines: list[int] = []
    rows: list[list[float]] = []
    for number, text in enumerate(raw, start=first):
        try:
            body = text.decode("utf-8")
            tokens = body.split("#", 1)[0].split()
            if not tokens:
                continue
            if len(tokens) != columns:
                raise InputError(
                    path, number, f"found {len(tokens)} numbers, expected {columns}: {what}"
                )
            rows.append([parse_number(path, number, token) for token in tokens])
            lines.append(number)
        except UnicodeDecodeError:
            return lines, rows, InputError(path, number, "found bytes that are not UTF-8 text")
        except InputError as error:
            return lines, rows, error
    return lines, rows, None


def underflows(token: str | bytes) -> bool:
    """Whether a number written with a digit other than 0 before its exponent reads as
    0.0 (``1e-400``: below float64's smallest, 4.9e-324): a value the file does not hold.
    Asked of a token only where its value is 0."""
    text = token.decode("ascii", errors="replace") if isinstance(token, bytes) else token
    mantissa = text.lower().split("e", 1)[0]
    return any(digit in mantissa for digit in "123456789")


UNDERFLOW_TEXT = (
    "which reads as 0 (a float64 holds no magnitude below 4.9e-324), expected 0 or a larger number"
)


def parse_number(path: Path, line: int, token: str) -> float:
    """A decimal number within +-:data:`MAX_MAGNITUDE`, or an error naming the token (a
    nonzero one that reads as 0 too: see :func:`underflows`)."""
    if _NUMBER.fullmatch(token):
        value = float(token)
        shown = repr(token if len(token) <= 20 else token[:20] + "...")
        if value == 0.0 and underflows(token):
            raise InputError(path, line, f"found {shown}, {UNDERFLOW_TEXT}")
        if -MAX_MAGNITUDE <= value <= MAX_MAGNITUDE:
            return value
        overflows = "" if math.isfinite(value) else " which overflows,"
        raise InputError(
            path, line, f"found {shown},{overflows} expected a number within {RANGE_TEXT}"
        )
    if _NON_FINITE.fullmatch(token):
        raise InputError(path, line, f"found {token!r}, expected a finite number")
    shown = token if len(token) <= 20 else token[:20] + "..."
    raise InputError(path, line, f"found {shown!r}, expected a decimal number")


def check_time(path: Path, line: int, time: float) -> float:
    """``time`` (seconds) if a recording's timeline holds it (see :data:`MAX_TIME_S`).

    :raises InputError: naming the line and the time
    """
    if not -MAX_TIME_S <= time <= MAX_TIME_S:
        raise time_error(path, line, time)
    return time


def first_time_out_of_range(times: FloatArray) -> int | None:
    """The index of the first time (seconds) a recording's timeline cannot hold (see
    :data:`MAX_TIME_S`), or None when it holds them all."""
    outside = np.flatnonzero(np.abs(times) > MAX_TIME_S)
    return int(outside[0]) if outside.size else None


def first_bad_time(times: FloatArray, last: float) -> tuple[int, float | None] | None:
    """The first time of a block (seconds) that a reader refuses, and the time before it
    where it goes back (None: a time a recording cannot hold, see :data:`MAX_TIME_S`);
    None when every time is good.

    :param last: the time of the line before the block (-inf at the first)
    """
    before = np.concatenate(([last], times[:-1]))
    back = np.flatnonzero(times < before)
    outside = first_time_out_of_range(times)
    if back.size and (outside is None or int(back[0]) < outside):
        k = int(back[0])
        return k, float(before[k])
    return None if outside is None else (outside, None)


def time_error(path: Path, line: int, time: float) -> InputError:
    """The error of a time (seconds) a recording's timeline cannot hold, on its line."""
    return InputError(
        path,
        line,
        f"found time {time:g}, expected seconds within {TIME_RANGE_TEXT} (a recording's"
        " timeline counts nanoseconds in 64 bits; milliseconds or microseconds taken for"
        " seconds?)",
    )


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
