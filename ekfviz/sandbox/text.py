"""Text that came from a user's code, made safe to show: on a terminal, in a table, a CSV
cell, a JSON document.

What a filter prints, raises or names (a file may be named anything) is shown on one line
with every character that is not printable escaped as Python writes it (``\\x1b``,
``\\u202e``, ``\\n``): no escape sequence of it reaches a terminal (to erase the ``filter
NAME |`` prefix, move the cursor, retitle the window), no bidirectional override reorders
what a reader sees, no line break forges a row. A CSV cell that a spreadsheet would run as
a formula (starting with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return) is
prefixed with ``'``, as OWASP's advice on CSV injection has it. Numpy only.
"""

from __future__ import annotations

from ekfviz.core.tables import one_line, utf8

FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def printable(text: str) -> str:
    """``text`` on one line, its characters that are not printable (controls, escape
    sequences, bidirectional controls, line breaks, a file name's bytes that are not
    UTF-8) escaped. Linear in its length."""
    return one_line(utf8(text))


def spreadsheet_cell(text: str) -> str:
    """A CSV cell no spreadsheet runs: ``'`` before a cell that starts as a formula."""
    return "'" + text if text.startswith(FORMULA_STARTS) else text
