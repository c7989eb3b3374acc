"""A study's summary tables fit their view at 1600 px, read back from the recording, for
sweeps of each noise sigma over 2 to 6 values; and splitting keeps every cell."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.viz.blueprint import STUDY_COLUMN_SHARES
from ekfviz.viz.study import SUMMARY
from ekfviz.viz.tables import cells, fit_tables, table_width, view_characters

DATA = Path(__file__).resolve().parents[2] / "data"
CLASSIC, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
WIDTH = view_characters(STUDY_COLUMN_SHARES[1] / sum(STUDY_COLUMN_SHARES))
SWEEPS = [
    ("sigma_x", "x0.1,x10"),
    pytest.param("sigma_y", "x0.1,x0.5,x10", marks=pytest.mark.slow),
    pytest.param("sigma_alpha", "x0.1,x0.3,x3,x10", marks=pytest.mark.slow),
    pytest.param("sigma_bearing", "x0.2,x0.5,x2,x5,x10", marks=pytest.mark.slow),
    ("sigma_range", "x0.1,x0.3,x0.5,x2,x3,x10"),
]


def tables(markdown: str) -> list[list[list[str]]]:
    """The markdown's tables, each its rows of cells without the rule."""
    found: list[list[list[str]]] = []
    block: list[list[str]] = []
    for line in [*markdown.split("\n"), ""]:
        if line.startswith("|"):
            block.append(cells(line))
        elif block:
            found.append([block[0], *block[2:]])
            block = []
    return found


@pytest.mark.parametrize(("name", "values"), SWEEPS)
def test_a_sweeps_summary_fits_its_view(name: str, values: str, tmp_path: Path) -> None:
    save = tmp_path / "sweep.rrd"
    result = CliRunner().invoke(
        app, ["sweep", str(CLASSIC), "--truth", str(TRUTH), "--vary", f"{name}={values}",
              "--workers", "1", "--save", str(save)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    (row,) = entity_rows(save, f"/{SUMMARY}", static=True)
    text = str(row["TextDocument:text"][0])  # type: ignore[index]
    found = tables(text)
    assert len(found) >= 2  # the summary's thirteen columns do not fit one
    variants = ["baseline", *(f"{name} {value}" for value in values.split(","))]
    for table in found:
        assert table_width(table) <= WIDTH
        assert [r[0] for r in table[1:]] == variants  # every table names its rows
    headers = [header for table in found for header in table[0][1:]]
    assert "mean error" in headers and "Δ baseline" in headers
    assert len(headers) == len(set(headers))


def test_split_tables_keep_every_cell_and_fit() -> None:
    rng = np.random.default_rng(5)
    for _ in range(200):
        n_cols, n_rows = int(rng.integers(2, 16)), int(rng.integers(1, 8))
        width = int(rng.integers(30, 120))
        rows = [
            ["".join("ab "[int(k)] for k in rng.integers(0, 3, int(rng.integers(1, 40))))
             .strip() or "x" for _ in range(n_cols)]
            for _ in range(n_rows + 1)
        ]  # fmt: skip
        markdown = "# T\n\n" + "\n".join(
            ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * n_cols]
            + ["| " + " | ".join(r) + " |" for r in rows[1:]]
        )
        fitted = fit_tables(markdown, width)
        assert fitted.startswith("# T\n")
        split = tables(fitted)
        for table in split:
            assert table_width(table) <= width
        shown = {(t[i][0], t[0][j], t[i][j]) for t in split for i in range(1, len(t))
                 for j in range(1, len(t[0]))}  # fmt: skip
        for i in range(1, len(rows)):
            for j in range(1, n_cols):
                cell = (rows[i][0], rows[0][j], rows[i][j])
                listed = f"- {rows[i][0]}: {rows[i][j]}" in fitted and f"**{rows[0][j]}**" in fitted
                assert cell in shown or listed, cell
