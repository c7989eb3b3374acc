"""A class's grade is never lost and says only what ekfviz writes: rows of submissions
that name themselves as escape sequences or spreadsheet formulas, recordings whose names
would collide, a planted link in --save-dir, submissions over a bound, texts that made a
scan quadratic, a worker that cannot start, a grading process that dies."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ekfviz.app.grade import GradeTask, grade_one, recording_key, spec_text
from ekfviz.app.grade_rows import GradeRow, to_csv
from ekfviz.cli import app
from ekfviz.core.params import FilterParams
from ekfviz.studies.executors import LocalExecutor

ROOT = Path(__file__).parents[2]
SAMPLE = ROOT / "data" / "classic.txt"
SKELETON = ROOT / "examples" / "course_skeleton" / "ekf_slam.py"
runner = CliRunner()


def rows_of(report: Path) -> dict[str, dict[str, str]]:
    with report.open(encoding="utf-8", newline="") as handle:
        return {row["submission"]: row for row in csv.DictReader(handle)}


def test_names_and_messages_of_a_submission_reach_no_output_raw(tmp_path: Path) -> None:
    """An escape sequence that erased a row's start on a terminal, a bidirectional
    override, a formula a spreadsheet runs: escaped and neutralised in every output."""
    folder = tmp_path / "class"
    folder.mkdir()
    shutil.copy(SKELETON, folder / "honest.py")
    hostile = "def predict(X, P, c, q, k):\n    raise ValueError('\\x1b[2K\\rall good \\u202e')\n"
    (folder / "=HYPERLINK(1).py").write_text(hostile)
    (folder / "\x1b[31mred.py").write_text(hostile)
    report, listing = tmp_path / "grades.csv", tmp_path / "grades.json"
    result = runner.invoke(app, ["grade", str(folder), "--log", str(SAMPLE), "--workers", "1",
                                 "--report", str(report), "--json"])  # fmt: skip
    assert result.exit_code == 0, result.output
    listing.write_text(result.stdout)
    for text in (report.read_text(encoding="utf-8"), listing.read_text(), result.output):
        assert "\x1b" not in text and "\u202e" not in text and "\r" not in text
    rows = rows_of(report)
    assert set(rows) == {"'=HYPERLINK(1).py", "\\x1b[31mred.py", "honest.py"}
    assert rows["honest.py"]["status"] == "match"
    document = json.loads(result.stdout)
    assert {row["submission"] for row in document["submissions"]} == {
        "=HYPERLINK(1).py", "\\x1b[31mred.py", "honest.py"}  # fmt: skip
    assert document["partial"] is False and document["sandbox"].startswith("bubblewrap")
    for cells in csv.reader(report.open(encoding="utf-8")):
        assert not any(cell.startswith(("=", "+", "-", "@")) for cell in cells), cells


def test_a_row_reads_back_from_its_json_and_refuses_what_is_not_one() -> None:
    row = GradeRow("a\x1bb.py", "diverged", ("x",), "classic:3 ...", 1.5, "d", "m",
                   (("cause", "x"), ("hint", "do \x07"), ("other", "dropped")))  # fmt: skip
    back = GradeRow.from_json(json.dumps(row.to_json()))
    assert back == row and back.submission == "a\\x1bb.py"
    assert dict(back.diagnosis) == {"cause": "x", "hint": "do \\x07"}
    for bad in ('["a"]', '{"submission": 1}', '{"status": "pwned"}'):
        with pytest.raises((ValueError, TypeError)):
            GradeRow.from_json(bad)
    with pytest.raises(ValueError, match="not a status"):
        GradeRow("a", "pwned", (), "", 0.0)
    assert to_csv([row], "none", complete=False).splitlines()[1].endswith(",none,no")


def test_recordings_are_one_per_submission_whatever_their_names(tmp_path: Path) -> None:
    """``a b.py`` and ``a_b.py-<digest of a b.py>`` wrote one file, as did two names
    that are not UTF-8 and read alike once replaced."""
    names = [b"a b.py", b"a_b.py", b"a%20b.py", b"M\xfcller.py", b"M\xfdller.py", b".x.py"]
    keys = [recording_key(name) for name in names]
    assert len(set(keys)) == len(keys)
    assert keys[1] == "a_b.py" and all("-" not in key and "/" not in key for key in keys)
    assert not any(key.startswith(".") for key in keys)


def test_a_link_planted_in_save_dir_is_replaced_never_followed(tmp_path: Path) -> None:
    folder = tmp_path / "class"
    folder.mkdir()
    shutil.copy(SKELETON, folder / "alice.py")
    saved = tmp_path / "recs"
    saved.mkdir()
    precious = tmp_path / "precious.txt"
    precious.write_text("the TA's file")
    (saved / "alice.py-classic.rrd").symlink_to(precious)
    result = runner.invoke(app, ["grade", str(folder), "--log", str(SAMPLE), "--workers", "1",
                                 "--save-dir", str(saved)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert precious.read_text() == "the TA's file"
    recording = saved / "alice.py-classic.rrd"
    assert not recording.is_symlink() and recording.stat().st_size > 1000


def task(path: Path, **changes: object) -> GradeTask:
    return GradeTask(path.name, path, ((SAMPLE, None, None, None),), FilterParams(), 60.0, 1024,
                     **changes)  # type: ignore[arg-type]  # fmt: skip


@pytest.mark.parametrize("shape", ["sparse", "folders", "link", "hard link"])
def test_a_submission_over_a_bound_or_not_its_own_is_an_error_row(
    tmp_path: Path, shape: str
) -> None:
    entry = tmp_path / "alice"
    entry.mkdir()
    shutil.copy(SKELETON, entry / "ekf_slam.py")
    if shape == "sparse":  # 1.5 GB, never read
        with open(entry / "big.py", "wb") as handle:
            handle.truncate(1500 << 20)
    elif shape == "folders":
        for index in range(300):
            (entry / f"d{index}").mkdir()
    elif shape == "link":
        (entry / "bob.py").symlink_to(tmp_path / "bob.py")
        (tmp_path / "bob.py").write_text("x = 1\n")
    else:  # (a link to a file of its own: never to the project's, whose count it would raise)
        shutil.copy(SKELETON, tmp_path / "neighbour.py")
        os.link(tmp_path / "neighbour.py", entry / "copied.py")
    row = grade_one(task(entry))
    assert row.status == "error", row
    said = {
        "sparse": "more than 8 MiB",
        "folders": "more than 200 files and folders",
        "link": "bob.py is a symbolic link that leads out",
        "hard link": "has hard links outside",
    }
    assert said[shape] in row.detail, row.detail


@pytest.mark.slow
def test_every_pass_over_a_submission_s_text_is_linear(tmp_path: Path) -> None:
    """A class and a file of blank lines took the old scans 25 s past --timeout: each
    line was matched again from every line before it. Run apart: a quadratic scan of
    these 7 MB would not end within the bound of the run."""
    module = tmp_path / "ekf_slam.py"
    module.write_text("class F:\n" + " \n" * 3_500_000 + "    def predict(self):\n")
    code = ("import sys; from pathlib import Path; from ekfviz.app.grade import spec_text,"
            " module_of; print(spec_text(Path(sys.argv[1])))")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code, str(module)], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert done.stdout.strip() == f"{module}:F", done.stderr
    assert spec_text(SKELETON) == str(SKELETON)


def test_a_worker_that_cannot_start_is_ekfviz_s_grader_error(tmp_path: Path) -> None:
    """Not the student's ``crashed``: the interpreter asked for is no Python."""
    shutil.copy(SKELETON, tmp_path / "alice.py")
    row = grade_one(task(tmp_path / "alice.py", python=shutil.which("true")))
    assert row.status == "grader_error", row
    assert "did not start" in row.detail


def dies_at_three(item: int) -> int:
    if item == 3:
        os.kill(os.getpid(), 9)
    return item * 10


def test_a_dead_pool_process_is_its_item_s_row_and_the_rest_go_on() -> None:
    lost: list[tuple[int, str]] = []
    found = LocalExecutor(workers=2).map(
        dies_at_three, list(range(6)), lost=lambda item, why: lost.append((item, why)) or -1
    )
    assert found == [0, 10, 20, -1, 40, 50]
    assert [item for item, _ in lost] == [3] and "died" in lost[0][1]
    from concurrent.futures.process import BrokenProcessPool

    with pytest.raises(BrokenProcessPool):
        LocalExecutor(workers=2).map(dies_at_three, list(range(6)))


def test_what_a_filter_prints_reaches_the_terminal_escaped(tmp_path: Path) -> None:
    """A line that erased the ``filter NAME |`` prefix and retitled the terminal."""
    module = tmp_path / "loud.py"
    module.write_text(
        SKELETON.read_text()
        + "\nprint('\\x1b[2K\\x1b[1Gok \\x1b]0;owned\\x07 \\u202eevil', flush=True)\n"
    )
    result = runner.invoke(app, ["check", str(SAMPLE), "--filter", str(module)])
    assert result.exit_code == 0, result.output
    assert "filter loud.py | \\x1b[2K\\x1b[1Gok \\x1b]0;owned\\x07 \\u202eevil" in result.output
    assert "\x1b" not in result.output and "\u202e" not in result.output
