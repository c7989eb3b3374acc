"""Tables and lines for people, as plain data: what a result prints is written beside the
result (``Evaluation.table()``, ``MonteCarlo.table()``), and the command line renders it
(:func:`ekfviz.cli.common.show`), so that the layers below it need no terminal library."""

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
