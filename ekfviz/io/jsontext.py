"""JSON read from inputs with limits that hold by construction: size, depth and numbers.

Python's ``json`` takes any size, recurses once per nesting level (a deep document is a
``RecursionError``), turns a 5,000-digit integer into a ``ValueError`` and a 400-digit
one into an int no float can hold, and accepts ``NaN`` and ``Infinity``. Here a
document is refused, with its file and line, when it is over :data:`MAX_JSON_BYTES`,
nested over :data:`MAX_JSON_DEPTH` deep, gives a key twice in one object (Python keeps
the last, losing the first), or holds a number outside
+-:data:`~ekfviz.io.text.MAX_MAGNITUDE` or a non-finite constant; every number read is a
Python ``int`` (up to 19 digits) or a finite ``float``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from ekfviz.core.errors import InputError
from ekfviz.io.text import BOM, MAX_MAGNITUDE, RANGE_TEXT, UNDERFLOW_TEXT, open_input, underflows

MAX_JSON_BYTES = 256 << 20  # a truth of a million poses is some 60 MB
MAX_JSON_DEPTH = 64  # a truth file nests 3 deep; room for what others add
_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_OPEN = np.frombuffer(b"[{", dtype=np.uint8)
_CLOSE = np.frombuffer(b"]}", dtype=np.uint8)
_MAX_INT_DIGITS = 19  # int64's 9.2e18


class _BadNumber(ValueError):
    def __init__(self, token: str) -> None:
        super().__init__(token)
        self.token = token


def load_json(path: Path, what: str = "a JSON file") -> object:
    """The JSON document of a file, within the limits of the module.

    :param what: what was expected at ``path``, for the messages
    :raises InputError: naming the file, the line where there is one, and the limit
    """
    with open_input(path, what) as handle:
        raw = handle.read(MAX_JSON_BYTES + 1)
    if len(raw) > MAX_JSON_BYTES:
        raise InputError(
            path, 0, f"found over {MAX_JSON_BYTES >> 20} MiB, expected {what} of at most that"
        )
    # the readers' line ends (CR alone too) as LF, so that every message counts lines as
    # they do (a raw CR inside a string is invalid JSON either way)
    raw = raw.removeprefix(BOM).replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    depth, line = _depth(raw)
    if depth > MAX_JSON_DEPTH:
        raise InputError(
            path, line, f"found JSON nested over {MAX_JSON_DEPTH} deep, expected {what}"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        line = raw.count(b"\n", 0, error.start) + 1
        raise InputError(path, line, "found bytes that are not UTF-8 text") from None
    try:
        return json.loads(
            text,
            parse_int=_int,
            parse_float=_float,
            parse_constant=_constant,
            object_pairs_hook=_unique,
        )
    except json.JSONDecodeError as error:
        raise InputError(path, error.lineno, f"invalid JSON: {error.msg}") from None
    except _Repeated as error:
        line = _line_of(text, json.dumps(error.key), nth=2)
        raise InputError(
            path, line, f"found the key {error.key!r} twice in one object, expected it once"
        ) from None
    except _BadNumber as error:
        line = _line_of(text, error.token)
        shown = error.token if len(error.token) <= 20 else error.token[:20] + "..."
        if float(error.token) == 0.0:  # a nonzero number that reads as 0 (see underflows)
            raise InputError(path, line, f"found {shown}, {UNDERFLOW_TEXT}") from None
        raise InputError(
            path, line, f"found {shown}, expected a finite number within {RANGE_TEXT}"
        ) from None


class _Repeated(ValueError):
    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def _unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """An object, refusing a key given twice (Python keeps the last: the first is lost)."""
    document = dict(pairs)
    if len(document) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise _Repeated(key)
            seen.add(key)
    return document


def _depth(raw: bytes) -> tuple[int, int]:
    """The deepest nesting of brackets outside strings, and the line where it is first met."""
    bare = np.frombuffer(_STRING.sub(b'""', raw), dtype=np.uint8)
    if bare.size == 0:
        return 0, 0
    steps = np.isin(bare, _OPEN).astype(np.int64) - np.isin(bare, _CLOSE).astype(np.int64)
    levels = np.cumsum(steps)
    deepest = int(levels.max(initial=0))
    if deepest <= MAX_JSON_DEPTH:
        return deepest, 0
    at = int(np.argmax(levels > MAX_JSON_DEPTH))
    return deepest, int(np.count_nonzero(bare[:at] == ord("\n"))) + 1


def _int(token: str) -> int | float:
    digits = token.lstrip("-")
    if len(digits) <= _MAX_INT_DIGITS:
        return int(token)
    return _float(token)  # a float in range (1e18 written out), else refused


def _float(token: str) -> float:
    value = float(token)  # no digit limit for floats: a long one is inf, refused
    if not -MAX_MAGNITUDE <= value <= MAX_MAGNITUDE or (value == 0.0 and underflows(token)):
        raise _BadNumber(token)
    return value


def _constant(token: str) -> float:
    raise _BadNumber(token)


def _line_of(text: str, token: str, nth: int = 1) -> int:
    """The line of the ``nth`` occurrence of ``token`` (a good guess: JSON says no more)."""
    at = -1
    for _ in range(nth):
        at = text.find(token, at + 1)
        if at < 0:
            return 0
    return text.count("\n", 0, at) + 1
