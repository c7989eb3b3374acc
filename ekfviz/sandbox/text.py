"""Text that came from a user's code, made safe to show: on a terminal, in a table, a CSV
cell, a JSON document.

What a filter prints, raises or names (a file may be named anything) is shown with every
control character and every bidirectional override escaped (``\\x1b``, ``\\u202e``): no
escape sequence of it reaches a terminal (to erase the ``filter NAME |`` prefix, move the
cursor, retitle the window), and no override reorders what a reader sees. A CSV cell that
a spreadsheet would run as a formula (starting with ``=``, ``+``, ``-``, ``@``, a tab or a
carriage return) is prefixed with ``'``, as OWASP's advice on CSV injection has it.
Numpy only.
"""

from __future__ import annotations

import re
import unicodedata

# C0 controls but the tab, DEL, C1 controls; the bidirectional marks, embeddings,
# overrides and isolates; the line and paragraph separators
_UNSAFE = re.compile(
    "[\x00-\x08\x0a-\x1f\x7f-\x9f\u061c\u200e\u200f\u202a-\u202e\u2028\u2029\u2066-\u2069]"
)
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def _escape(match: re.Match[str]) -> str:
    code = ord(match.group())
    return f"\\x{code:02x}" if code <= 0xFF else f"\\u{code:04x}"


def printable(text: str) -> str:
    """``text`` with its control characters (the tab kept) and bidirectional controls
    escaped as ``\\xNN`` or ``\\uNNNN``; a surrogate (a file name's undecodable byte)
    as its code too. Linear in the text's length."""
    shown = _UNSAFE.sub(_escape, text)
    if any(0xD800 <= ord(c) <= 0xDFFF for c in shown):
        shown = "".join(f"\\u{ord(c):04x}" if 0xD800 <= ord(c) <= 0xDFFF else c for c in shown)
    return shown


def one_line(text: str) -> str:
    """:func:`printable` of ``text`` on one line: its whitespace runs (line breaks, tabs)
    as single spaces."""
    return printable(" ".join(text.split()))


def spreadsheet_cell(text: str) -> str:
    """A CSV cell no spreadsheet runs: ``'`` before a cell that starts as a formula."""
    return "'" + text if text.startswith(FORMULA_STARTS) else text


def is_printable(text: str) -> bool:
    """Whether ``text`` needs no escaping (for tests and assertions of callers)."""
    return _UNSAFE.search(text) is None and all(unicodedata.category(c) != "Cs" for c in text)
