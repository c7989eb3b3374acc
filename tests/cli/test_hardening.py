"""What a new user trips over: honest ``info`` for every recording, readings
that do not flip, quiet textbook filters, piped output, help pages, convert, stale refs."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.health import check_covariance
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import (
    INSIDE_BORDERLINE,
    INSIDE_FOR_CONSISTENT,
    BoundCount,
    Consistency,
    Verdict,
    reading,
)
from ekfviz.io.classic import read_classic
from ekfviz.runner.replay import replay

ROOT = Path(__file__).parents[2]
DATA = ROOT / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
runner = CliRunner()


def ekfviz(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m ekfviz ARGS`` with stdout and stderr piped: no terminal."""
    return subprocess.run(
        [sys.executable, "-m", "ekfviz", *args], capture_output=True, text=True, cwd=cwd
    )


# -- output paths ------------------------------------------------------------------------


def test_replay_without_an_output_option_keeps_the_earlier_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    for _ in range(2):
        result = runner.invoke(app, ["replay", str(SAMPLE)])
        assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "recordings").iterdir()) == [
        "classic-2.rrd",
        "classic.rrd",
    ]
    assert "Saved recordings/classic-2.rrd; open it with: " in result.stdout


# -- info: every kind of recording, and how a run ended ------------------------------------


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
    made["truncated"].write_bytes(whole[: len(whole) // 2])
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

    result = ekfviz("info", str(recordings["replay"]), "--json")
    assert result.returncode == 0 and result.stderr == ""
    document = json.loads(result.stdout)
    assert document["input"]["sha256"] == hashlib.sha256(SAMPLE.read_bytes()).hexdigest()
    assert document["status"]["state"] == "finished"
    assert document["status"]["stopped_early"] is False


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


def test_info_says_a_run_cut_by_sigterm_stopped_early_and_where(
    tmp_path: Path, slow_log: Path
) -> None:
    from conftest import recording_started

    rrd = tmp_path / "cut.rrd"
    process = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", "replay", str(slow_log), "--save", str(rrd)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    recording_started(tmp_path, rrd.name)
    time.sleep(0.5)  # into the replay, seconds before its end
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 143, stderr
    document = json.loads(ekfviz("info", str(rrd), "--json").stdout)
    status = document["status"]
    assert status["state"] == "stopped" and status["stopped_early"] is True
    assert "terminated (SIGTERM)" in status["reason"]
    assert status["event"] >= 0 and status["line"] >= 1
    text = ekfviz("info", str(rrd)).stdout
    assert re.search(r"^status +stopped early after event \d+, step \d+, input line", text, re.M)


# -- readings --------------------------------------------------------------------------------


def _count(inside: int, above: int, below: int) -> BoundCount:
    return BoundCount(below=below, inside=inside, above=above)


def test_a_run_near_the_threshold_is_borderline_whichever_side_it_misses() -> None:
    assert INSIDE_BORDERLINE < INSIDE_FOR_CONSISTENT
    # one step either way around 90 %: the reading must not flip from one verdict to its
    # opposite
    assert _count(89, 6, 5).verdict is Verdict.BORDERLINE
    assert _count(89, 5, 6).verdict is Verdict.BORDERLINE
    assert _count(90, 5, 5).verdict is Verdict.CONSISTENT
    assert _count(60, 40, 0).verdict is Verdict.OVER_CONFIDENT
    assert _count(60, 0, 40).verdict is Verdict.TOO_CAUTIOUS


def test_a_run_is_never_read_consistent_while_its_map_is_off() -> None:
    consistency = Consistency()
    consistency.nis = _count(97, 2, 1)  # the NIS alone looks fine
    assert reading(consistency, 195, 200) == "consistent"
    off = reading(consistency, 0, 200)
    assert off.startswith("over-confident") and "0/200 landmarks in 3σ" in off
    with_nees = Consistency(nees=_count(40, 60, 0), nis=_count(97, 2, 1))
    assert reading(with_nees, 200, 200) == "over-confident: NEES 60% high"
    # a batch optimum has no per-step statistics: its map is read alone
    assert reading(Consistency(), 6, 6) == "no NEES or NIS; map: 6/6 landmarks in 3σ"
    assert reading(Consistency(), 2, 6).startswith("over-confident")
    assert reading(Consistency(), None, 0) == "no update to judge"


def test_a_truth_with_fewer_poses_than_steps_says_how_many_were_judged() -> None:
    events = list(read_classic(SAMPLE))
    truth_file = json.loads(TRUTH.read_text())
    landmarks = truth_file["landmarks"]
    ids = np.array(sorted(int(k) for k in landmarks))
    xy = np.array([landmarks[str(i)] for i in ids])
    poses = np.array(truth_file["poses"][:11])  # the start and 10 of 29 steps
    consistency = Consistency(GroundTruth(ids, xy, poses))
    for batch in replay(events):
        consistency.add(batch)
    assert consistency.nees.total == 11
    assert any(
        "only 11 of 30 corrected states have a true pose" in s for s in consistency.summary()
    )


# -- symmetry of P ---------------------------------------------------------------------------


def test_round_off_asymmetry_is_judged_against_the_size_of_P() -> None:
    P = np.diag([4.0, 4.0, 1.0, 9.0, 9.0])
    P[0, 1], P[1, 0] = 0.5, 0.5 + 4e-16  # a textbook filter's round-off
    check = check_covariance(P)
    assert check.asymmetry > 0 and check.round_off_asymmetry
    assert check.problems() == []
    assert "round-off" in check.problems(round_off=True)[0]
    P[1, 0] = 0.6  # a real fault
    assert "not symmetric" in check_covariance(P).problems()[0]


def test_a_textbook_filter_with_round_off_is_warned_once_a_run(tmp_path: Path) -> None:
    from ekfviz.viz import Recorder, style

    out = tmp_path / "plain.rrd"
    rec = rr.RecordingStream("plain")
    rec.save(out)
    recorder = Recorder(rec, blueprint=False)
    x = np.zeros(3)
    for k in range(6):
        P = np.diag([0.01, 0.02, 0.03]) * (k + 1)
        P[0, 1], P[1, 0] = 0.001, 0.001 * (1 + 1e-15)
        recorder.predict(x, P, control=(1.0, 0.0))
    recorder.finish()
    rec.disconnect()
    warned = [r for r in entity_rows(out, f"/{style.LOG}") if r["TextLog:level"] == ["WARN"]]
    assert len(warned) == 1 and "round-off" in str(warned[0]["TextLog:text"])


# -- command line ------------------------------------------------------------------------------


def test_piped_output_is_full_width_and_unpadded(recordings: dict[str, Path]) -> None:
    result = ekfviz("info", str(recordings["replay"]))
    lines = result.stdout.splitlines()
    assert any(re.fullmatch(r"input sha256 +[0-9a-f]{64}", line) for line in lines)
    assert all(line == line.rstrip() for line in lines)
    sweep = recordings["replay"].parent / "s.rrd"
    table = ekfviz("sweep", str(SAMPLE), "--truth", str(TRUTH), "--vary", "sigma_range=/10",
                   "--save", str(sweep), "--workers", "1")  # fmt: skip
    assert table.returncode == 0, table.stderr
    assert "…" not in table.stdout and "over-confident" in table.stdout
    assert all(line == line.rstrip() for line in table.stdout.splitlines())


def test_replay_json_is_the_report_on_stdout(tmp_path: Path) -> None:
    report = tmp_path / "r.json"
    result = ekfviz("replay", str(SAMPLE), "--truth", str(TRUTH), "--json",
                    "--save", str(tmp_path / "r.rrd"), "--report", str(report))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == json.loads(report.read_text())
    assert "Landmarks at the end of the run" in result.stderr


def test_debug_is_taken_after_the_command_too(tmp_path: Path) -> None:
    result = ekfviz("replay", str(tmp_path / "missing.txt"), "--save", "x.rrd", "--debug",
                    cwd=tmp_path)  # fmt: skip
    assert result.returncode == 1 and "Traceback" in result.stderr


def test_a_multi_value_option_missing_a_number_says_how_many(tmp_path: Path) -> None:
    result = ekfviz("replay", str(SAMPLE), "--init-pose-sigma", "0.1", "0.1", "--save", "x.rrd",
                    cwd=tmp_path)  # fmt: skip
    assert result.returncode == 2 and list(tmp_path.iterdir()) == []
    assert result.stderr.strip() == (
        "error: --init-pose-sigma needs 3 numbers (SX SY STHETA), found '--save'"
    )


def test_vary_with_a_negative_sigma_says_it_must_be_positive() -> None:
    result = runner.invoke(app, ["sweep", str(SAMPLE), "--vary", "sigma_x=-1"])
    assert result.exit_code == 2 and "must be positive" in result.stderr


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


# -- convert ---------------------------------------------------------------------------------


def test_convert_keeps_every_number_as_written(tmp_path: Path) -> None:
    target = tmp_path / "ext.txt"
    assert runner.invoke(app, ["convert", str(SAMPLE), str(target)]).exit_code == 0
    first = target.read_text().splitlines()[1]
    assert first.startswith("observe 1 1.1077 6.6705 2 1.3180 12.4242")
    assert "control 3.0000 0.0000" in target.read_text()
    from ekfviz.io.extended import read_extended

    for converted, original in zip(read_extended(target), read_classic(SAMPLE), strict=True):
        assert type(converted) is type(original)
    again = runner.invoke(app, ["convert", str(target), str(tmp_path / "again.txt")])
    assert again.exit_code == 2 and "already in the extended format" in again.stderr
    assert not (tmp_path / "again.txt").exists()


# -- stale references -------------------------------------------------------------------------


def test_every_docs_file_the_project_cites_exists() -> None:
    cited: set[str] = set()
    for path in [*ROOT.glob("*.md"), *ROOT.glob("*.py"), *ROOT.glob("ekfviz/**/*.py"),
                 *ROOT.glob("examples/*.py"), *ROOT.glob("docs/*.md")]:  # fmt: skip
        cited |= set(re.findall(r"docs/[\w.-]+\.(?:md|png)", path.read_text()))
    assert cited, "the check found nothing to check"
    missing = sorted(name for name in cited if not (ROOT / name).is_file())
    assert missing == []


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
        result = ekfviz(*args)
        assert result.returncode == 2 and result.stderr == (
            f"error: {path}: {words}; expected a recording (.rrd)\n"
        ), result.stderr
    assert not (tmp_path / "t.tum").exists()


def test_a_multi_value_option_given_with_equals_is_read_as_click_reads_it(
    tmp_path: Path,
) -> None:
    """``--init-pose-sigma=0.1 0.1 0.1`` is click's syntax: ekfviz's own check counted the
    first value twice and refused it ("found fewer", "found '-o'")."""
    log, truth = tmp_path / "run.txt", tmp_path / "run.json"
    result = runner.invoke(app, ["simulate", "--init-pose-sigma=0.1", "0.2", "0.3", "-o",
                                 str(log), "--truth-out", str(truth)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads(truth.read_text())["init_pose_sigma"] == [0.1, 0.2, 0.3]


def test_two_filters_of_one_label_and_a_run_too_short_to_calibrate(tmp_path: Path) -> None:
    """Two rows named alike could not be told apart in a comparison's table or report; a
    run too short to calibrate on said numpy's "Singular matrix"."""
    result = runner.invoke(app, ["compare", str(SAMPLE), "--filter", "ekf", "--filter", "ekf",
                                 "--label", "A", "--label", "A"])  # fmt: skip
    assert result.exit_code == 2
    assert result.output.strip() == (
        "error: --label A given twice: give each filter a name of its own"
    )
    log, truth, short = tmp_path / "run.txt", tmp_path / "run.json", tmp_path / "short.txt"
    result = runner.invoke(app, ["simulate", "-o", str(log), "--truth-out", str(truth)])
    assert result.exit_code == 0, result.output
    short.write_text("\n".join(log.read_text().splitlines()[:5]) + "\n")
    result = runner.invoke(app, ["calibrate", str(short), "--truth", str(truth)])
    assert result.exit_code == 2, result.output
    assert "too short a run to calibrate on" in result.output
