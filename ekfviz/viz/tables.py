"""Markdown tables cut to the width of the view that shows them.

The viewer's text view neither wraps a table nor scrolls it sideways: a row wider than
the view is cut at its edge. A table is split into tables of a few columns each, every
one led by the first column (the row's name); a column whose cells are too wide for any
table (a sentence) becomes a list beneath them, which the view wraps.
"""

from __future__ import annotations

from collections.abc import Sequence

CELL_PAD = 3  # the characters a cell's padding and rule take, beside its text
WINDOW_PX = 1600  # the window width a layout is made for
# the text view's proportional font, a character's mean width in pixels on the tables of
# a study (6.3 measured on a screenshot at 1600 px, rounded up: digits and capitals)
CHAR_PX = 7.0
VIEW_MARGIN_PX = 24  # the view's own margins and scroll bar


def view_characters(share: float) -> int:
    """The characters of a line that a text view ``share`` of the window wide shows."""
    return int((share * WINDOW_PX - VIEW_MARGIN_PX) / CHAR_PX)


def cells(line: str) -> list[str]:
    """The cells of a markdown table row ``| a | b |``."""
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def table_width(rows: Sequence[Sequence[str]]) -> int:
    """The width of a table of ``rows`` (the header first) as the view draws it, in
    characters: each column its widest cell and a cell's padding."""
    return sum(max(len(row[j]) for row in rows) + CELL_PAD for j in range(len(rows[0])))


def fit_table(rows: list[list[str]], width: int) -> list[str]:
    """One table (``rows``, the header first, without the rule) as markdown lines of
    tables no wider than ``width`` characters, then a list of its too-wide columns."""
    key = [row[0] for row in rows]
    wide: list[int] = []
    groups: list[list[int]] = [[]]
    for j in range(1, len(rows[0])):
        column = [[row[0], row[j]] for row in rows]
        if table_width(column) > width:
            wide.append(j)
            continue
        trial = groups[-1] + [j]
        if groups[-1] and table_width([[row[i] for i in [0, *trial]] for row in rows]) > width:
            groups.append([j])
        else:
            groups[-1] = trial
    lines: list[str] = []
    for group in groups:
        if not group:
            continue
        picked = [[row[i] for i in [0, *group]] for row in rows]
        lines += [row_line(picked[0]), row_line(["---"] * len(picked[0]))]
        lines += [row_line(row) for row in picked[1:]]
        lines.append("")
    for j in wide:
        lines.append(f"**{rows[0][j]}**")
        lines.append("")
        lines += [f"- {name}: {row[j]}" for name, row in zip(key[1:], rows[1:], strict=True)]
        lines.append("")
    return lines[:-1] if lines and not lines[-1] else lines


def row_line(row: Sequence[str]) -> str:
    return "| " + " | ".join(row) + " |"


def fit_tables(markdown: str, width: int) -> str:
    """``markdown`` with every table wider than ``width`` characters split to fit (see
    :func:`fit_table`); the rest as it was."""
    lines = markdown.split("\n")
    out: list[str] = []
    k = 0
    while k < len(lines):
        if not lines[k].lstrip().startswith("|"):
            out.append(lines[k])
            k += 1
            continue
        end = k
        while end < len(lines) and lines[end].lstrip().startswith("|"):
            end += 1
        block = [cells(line) for line in lines[k:end]]
        rows = [block[0], *block[2:]]  # without the rule under the header
        if len(block) < 2 or table_width(rows) <= width or len({len(r) for r in rows}) > 1:
            out += lines[k:end]
        else:
            out += fit_table(rows, width)
        k = end
    return "\n".join(out)
