"""Tables and lines for people, as plain data: what a result prints is written beside the
result (``Evaluation.table()``, ``MonteCarlo.table()``), and the command line renders it
(:func:`ekfviz.cli.console.show`), so that the layers below it need no terminal library."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Styled:
    """Text with a style for the terminal (``green``, ``bold red``), taken as it is: no
    markup is read in it."""

    text: str
    style: str | None = None
    wrap: bool = True  # False: a line never broken at the terminal's width


Spans = tuple[Styled, ...]  # one line of several styles
Cell = str | Styled | Spans


@dataclass(frozen=True, slots=True)
class TextTable:
    """A table: a title, its columns (right-justified unless named in ``left``) and rows
    of as many cells; ``lines``: False for a table with a rule under its head only."""

    title: str
    columns: tuple[str, ...]
    rows: tuple[tuple[Cell, ...], ...]
    left: frozenset[str] = frozenset()
    lines: bool = True


def utf8(text: str) -> str:
    """``text`` as UTF-8 can hold it: the bytes of a file name that are not UTF-8 (which
    Python keeps as lone surrogates, and which a UTF-8 file, JSON or Rerun would refuse)
    as U+FFFD, one a byte."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        pass
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
    except UnicodeEncodeError:  # a surrogate that stands for no byte (from JSON's \ud800)
        return text.encode("utf-8", "surrogatepass").decode("utf-8", "replace")


def one_line(text: str) -> str:
    """``text`` as one line: a line break or another character that is not printable in
    it (from a file name, a user's exception, bytes that are not UTF-8) written as
    ``repr`` writes it (``\\n``, ``\\x00``), so that an error, a warning or a table's
    cell is always one line on the terminal and for the scripts reading it."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
