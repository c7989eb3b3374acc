"""What a use case hands its front end to show: tables and lines as plain data (see
:mod:`ekfviz.core.tables`), in the order they are shown, and documents as ekfviz writes
JSON (reports and ``--json``)."""

from __future__ import annotations

from collections.abc import Sequence

from ekfviz.core.tables import Cell, Styled, TextTable, one_line, utf8
from ekfviz.io.files import json_text

__all__ = ["Block", "Cell", "Styled", "TextTable", "json_text", "one_line", "utf8"]

Block = TextTable | Sequence[Cell]  # a table, or lines
