"""info and export on recordings: every kind ekfviz writes, how a run ended, what is not a
whole ekfviz recording, a special file; and info's output on a pipe.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import rerun as rr
from commands import run_ekfviz
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.io.classic import read_classic
from ekfviz.runner.replay import replay

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
runner = CliRunner()


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One recording of every kind ekfviz writes, and a few that are not ekfviz's."""
    root = tmp_path_factory.mktemp("kinds")
    made = {name: root / f"{name}.rrd" for name in ("replay", "sweep", "consistency")}
    for args in (
        ["replay", str(SAMPLE), "--truth", str(TRUTH), "--save", str(made["replay"])],
        ["sweep", str(SAMPLE), "--vary", "sigma_x=x10", "--save", str(made["sweep"]),
         "--workers", "1"],
        ["consistency", "--runs", "2", "--workers", "1", "--save", str(made["consistency"])],
    ):  # fmt: skip
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
    from ekfviz.viz import Recorder

    made["recorder"] = root / "recorder.rrd"
    rec = rr.RecordingStream("my_slam")
    rec.save(made["recorder"])
    recorder = Recorder(rec)
    for batch in replay(read_classic(SAMPLE)):
        recorder.log(batch)
    recorder.finish()
    rec.disconnect()
    made["other"] = root / "other.rrd"
    rec = rr.RecordingStream("someone_else")
    rec.save(made["other"])
    rec.log("points", rr.Points2D([[0.0, 0.0]]))
    rec.disconnect()
    whole = made["replay"].read_bytes()
    made["truncated"] = root / "truncated.rrd"
    # cut inside a message's body: a cut between two messages, or within the first bytes
    # of one's header, reads as a shorter recording; the first cut from the middle on that
    # Rerun's reader refuses
    for cut in range(len(whole) // 2, len(whole) // 2 + 256):
        made["truncated"].write_bytes(whole[:cut])
        try:
            list(RrdReader(made["truncated"]).stream())
        except Exception:  # (what Rerun's reader raises for a file cut short)
            break
    else:
        raise AssertionError("no cut of the recording's middle reads as cut short")
    return made


@pytest.mark.parametrize(
    ("kind", "words"),
    [
        ("replay", "a replay of a log"),
        ("sweep", "a parameter sweep"),
        ("consistency", "a Monte-Carlo consistency study"),
        ("recorder", "recorded through the Recorder API"),
    ],
)
def test_info_reads_every_kind_of_recording_ekfviz_writes(
    recordings: dict[str, Path], kind: str, words: str
) -> None:
    result = runner.invoke(app, ["info", str(recordings[kind])])
    assert result.exit_code == 0, result.output
    assert re.search(rf"^kind +.*{re.escape(words)}", result.stdout, re.MULTILINE), result.stdout
    document = json.loads(runner.invoke(app, ["info", str(recordings[kind]), "--json"]).stdout)
    assert document["kind"] == kind


def test_info_json_holds_the_inputs_sha256_and_a_finished_status(
    recordings: dict[str, Path],
) -> None:
    import hashlib

    result = run_ekfviz("info", recordings["replay"], "--json")
    assert result.returncode == 0 and result.stderr == ""
    document = json.loads(result.stdout)
    assert document["input"]["sha256"] == hashlib.sha256(SAMPLE.read_bytes()).hexdigest()
    assert document["status"]["state"] == "finished"
    assert document["status"]["stopped_early"] is False


def test_piped_output_is_full_width_and_unpadded(recordings: dict[str, Path]) -> None:
    result = run_ekfviz("info", recordings["replay"])
    lines = result.stdout.splitlines()
    assert any(re.fullmatch(r"input sha256 +[0-9a-f]{64}", line) for line in lines)
    assert all(line == line.rstrip() for line in lines)
    sweep = recordings["replay"].parent / "s.rrd"
    table = run_ekfviz("sweep", SAMPLE, "--truth", TRUTH, "--vary", "sigma_range=/10",
                       "--save", sweep, "--workers", "1")  # fmt: skip
    assert table.returncode == 0, table.stderr
    assert "…" not in table.stdout and "over-confident" in table.stdout
    assert all(line == line.rstrip() for line in table.stdout.splitlines())


def test_info_says_a_run_stopped_by_bad_input_stopped_there(tmp_path: Path) -> None:
    lines = SAMPLE.read_text().splitlines()
    log = tmp_path / "bad.txt"
    log.write_text("\n".join([*lines[:9], "1.0 oops", *lines[9:]]) + "\n")
    rrd = tmp_path / "bad.rrd"
    result = runner.invoke(app, ["replay", str(log), "--save", str(rrd)])
    assert result.exit_code == 2 and f"{log}:10:" in result.stderr
    status = json.loads(runner.invoke(app, ["info", str(rrd), "--json"]).stdout)["status"]
    assert status["state"] == "stopped" and status["line"] == 9 and status["event"] == 8
    assert status["reason"].startswith(f"{log}:10: ")


# -- what is not a whole ekfviz recording --------------------------------------------------


@pytest.mark.parametrize(
    ("which", "message"),
    [
        ("truncated", "truncated after"),
        ("other", "application id 'someone_else'), but not one written by ekfviz"),
        ("folder", "is a folder, expected a recording"),
        ("text", "not a Rerun recording"),
    ],
)
def test_info_on_what_is_not_a_whole_ekfviz_recording_is_one_line(
    recordings: dict[str, Path], which: str, message: str
) -> None:
    path = {
        "folder": recordings["replay"].parent,
        "text": SAMPLE,
    }.get(which) or recordings[which]
    result = runner.invoke(app, ["info", str(path)])
    assert result.exit_code == 2
    assert result.stderr.count("\n") == 1 and message in result.stderr, result.stderr
    if which == "truncated":
        assert f"truncated after {path.stat().st_size} bytes" in result.stderr


def test_info_on_a_file_that_is_not_a_recording(tmp_path: Path) -> None:
    bogus = tmp_path / "bogus.rrd"
    bogus.write_text("not a recording")
    result = run_ekfviz("info", bogus)
    assert result.returncode == 2
    assert str(bogus) in result.stderr and "Traceback" not in result.stderr


@pytest.mark.parametrize("kind", ["device", "fifo"])
def test_info_and_export_of_a_special_file_say_what_it_is(tmp_path: Path, kind: str) -> None:
    """Not "no such file" for a file that is there: what it is, and what was expected."""
    import os

    if kind == "device":
        path, words = Path("/dev/zero"), "is a device, not a regular file"
        if not path.exists():
            pytest.skip("no /dev/zero here")
    else:
        path, words = tmp_path / "pipe.rrd", "is a FIFO (named pipe), not a regular file"
        os.mkfifo(path)
    for args in (["info", str(path)], ["export", str(path), "--tum", str(tmp_path / "t.tum")]):
        result = run_ekfviz(*args)
        assert result.returncode == 2 and result.stderr == (
            f"error: {path}: {words}; expected a recording (.rrd)\n"
        ), result.stderr
    assert not (tmp_path / "t.tum").exists()
