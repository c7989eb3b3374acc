"""A TA's ``kill PID`` (SIGTERM), Ctrl-C (SIGINT) or ``kill -9`` of a grade: the rows done
are written (the others ``not graded``, the files marked partial), and no process of the
grade or of a submission is left. Each waits for a first submission's row in the report
(rewritten as each row arrives: its handshake), never on a fixed sleep."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[2]
SAMPLE = ROOT / "data" / "classic.txt"
SKELETON = ROOT / "examples" / "course_skeleton" / "ekf_slam.py"


def processes_naming(text: str) -> list[int]:
    """The processes whose command line holds ``text``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and entry.name != str(os.getpid()):
            try:
                if text.encode() in (entry / "cmdline").read_bytes():
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def wait_for(condition: object, what: str, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"{what} within {timeout} s"
        time.sleep(0.05)


def report_rows(report: Path) -> dict[str, dict[str, str]]:
    """The rows of a grade's CSV report by submission (none before it is written)."""
    if not report.is_file():
        return {}
    with report.open(newline="") as handle:
        return {row["submission"]: row for row in csv.DictReader(handle)}


def started_grade(tmp_path: Path) -> tuple[subprocess.Popen[str], Path]:
    """A grade of a quick submission and one that never ends, running once the quick
    one's row is in the report; its class folder."""
    folder = tmp_path / "class"
    folder.mkdir()
    shutil.copy(SKELETON, folder / "fast.py")
    endless = "def predict(*a):\n    while True:\n        pass\n\n\ndef unused_predict("
    (folder / "slow.py").write_text(SKELETON.read_text().replace("def predict(", endless, 1))
    home = str(tmp_path)
    env = {**os.environ, "CI": "1", "XDG_CONFIG_HOME": home, "XDG_DATA_HOME": home}
    grade = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", "grade", str(folder), "--log", str(SAMPLE), "--workers",
         "2", "--timeout", "600", "--report", str(tmp_path / "g.csv"), "--save-dir",
         str(tmp_path / "recs"), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path,
    )  # fmt: skip
    report = tmp_path / "g.csv"

    def fast_graded() -> bool:
        return report_rows(report).get("fast.py", {}).get("status", "not graded") != "not graded"

    wait_for(lambda: fast_graded() or grade.poll() is not None, "the quick submission's row")
    assert grade.poll() is None, grade.communicate()
    rows = report_rows(report)
    assert (rows["fast.py"]["status"], rows["slow.py"]["status"]) == ("match", "not graded")
    assert (tmp_path / "recs" / "fast.py-classic.rrd").is_file()  # saved before its row came
    return grade, folder


@pytest.mark.parametrize(
    "signum", [pytest.param(signal.SIGTERM, marks=pytest.mark.slow), signal.SIGINT]
)
def test_a_signal_writes_the_rows_done_and_leaves_no_process(tmp_path: Path, signum: int) -> None:
    grade, folder = started_grade(tmp_path)
    assert processes_naming(str(folder))  # (the slow one's sandbox, its grading process)
    grade.send_signal(signum)
    stdout, stderr = grade.communicate(timeout=120)
    assert grade.returncode == 128 + signum, stderr
    name = signal.Signals(signum).name
    assert f"error: interrupted ({name}): 1 of 2 submissions graded" in stderr
    rows = report_rows(tmp_path / "g.csv")
    assert (rows["fast.py"]["status"], rows["slow.py"]["status"]) == ("match", "not graded")
    assert {row["complete"] for row in rows.values()} == {"no"}
    document = json.loads(stdout)
    assert document["partial"] is True and document["stopped_by"] == name
    wait_for(lambda: not processes_naming(str(folder)), "every process of the grade gone", 30)


@pytest.mark.slow
def test_a_grade_killed_outright_leaves_no_process(tmp_path: Path) -> None:
    """Its pool processes die with it, and their sandboxes with them; its report keeps
    the rows done, marked partial."""
    grade, folder = started_grade(tmp_path)
    grade.kill()
    grade.communicate(timeout=60)
    wait_for(lambda: not processes_naming(str(folder)), "every process of the grade gone", 30)
    rows = report_rows(tmp_path / "g.csv")
    assert (rows["fast.py"]["status"], rows["slow.py"]["status"]) == ("match", "not graded")
    assert {row["complete"] for row in rows.values()} == {"no"}
    assert not list(tmp_path.glob(".*g.csv*"))  # no temporary file of the report left
