"""What the commands print for people and for scripts: help pages that read cleanly, the
JSON report on stdout, a table row of an odd name, and the docs files the project cites.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from commands import run_ekfviz
from typer.testing import CliRunner

from ekfviz.cli import app

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
runner = CliRunner()


@pytest.mark.parametrize(
    "command", ["replay", "sweep", "compare", "consistency", "simulate", "convert", "info"]
)
def test_help_pages_read_cleanly(command: str) -> None:
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "80"})
    assert result.exit_code == 0
    text = result.output
    assert "<bool>" not in text and "…" not in text and "{" not in text, text
    assert not re.search(r"\w \.(\s|$)", text), re.search(r".{30}\w \.(\s|$)", text)


def test_help_keeps_sentences_whole() -> None:
    text = runner.invoke(app, ["consistency", "--help"], env={"COLUMNS": "200"}).output
    assert "95% chi-square bounds; above them it is over-confident" in text
    assert "[default: one per core]" in text


def test_replay_json_is_the_report_on_stdout(tmp_path: Path) -> None:
    report = tmp_path / "r.json"
    result = run_ekfviz("replay", SAMPLE, "--truth", TRUTH, "--json",
                        "--save", tmp_path / "r.rrd", "--report", report)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == json.loads(report.read_text())
    assert "Landmarks at the end of the run" in result.stderr


def test_a_submission_named_with_a_line_break_keeps_its_row_one_line() -> None:
    """grade's table: a file named with a line break split its row over two lines."""
    from ekfviz.app.grade_rows import GradeRow

    row = GradeRow("alice\nbob.py", "error", (), "", 0.1, detail="it raised")
    name = row.cells()[0].text
    assert name == "alice\\nbob.py" and "\n" not in "".join(c.text for c in row.cells())


def test_every_docs_file_the_project_cites_exists() -> None:
    cited: set[str] = set()
    for path in [*ROOT.glob("*.md"), *ROOT.glob("*.py"), *ROOT.glob("ekfviz/**/*.py"),
                 *ROOT.glob("examples/*.py"), *ROOT.glob("docs/*.md")]:  # fmt: skip
        cited |= set(re.findall(r"docs/[\w.-]+\.(?:md|png)", path.read_text()))
    assert cited, "the check found nothing to check"
    missing = sorted(name for name in cited if not (ROOT / name).is_file())
    assert missing == []
