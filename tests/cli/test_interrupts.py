"""Interrupts, saved recordings and exposure: Ctrl-C and SIGTERM stop every
command at once with one line, and a signalled replay keeps a whole recording of what it
did; a failed run never replaces a recording; ``--serve`` listens on loopback only; the
recorded truth digest is the file's sha256.

Each signal is sent once the process is where it should find it: its handler in place,
its workers started, or events in its recording."""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from commands import run_ekfviz
from conftest import catches_signal, recording_holds
from typer.testing import CliRunner

from ekfviz.cli import app

ROOT = Path(__file__).parents[2]
OBS = "0.1 5.0 0.2 6.0"
DATA = ROOT / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
EXIT_BOUND_S = 10.0  # generous for a loaded machine; measured well under 2 s when idle
# the bytes of a replay's temporary recording once events are in it (its header and the
# static data that comes first take some 15 KB): the replay is under way
RECORDED = 100_000
runner = CliRunner()


@pytest.fixture(scope="module")
def long_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A loop of 12,000 steps: long enough that no study of it ends within seconds (a
    replay of it does: a signalled replay takes ``slow_log``)."""
    folder = tmp_path_factory.mktemp("long")
    log, truth = folder / "long.txt", folder / "long.json"
    made = run_ekfviz(
        "simulate", "--scenario", "loop", "--steps", "12000", "--landmarks", "40",
        "-o", str(log), "--truth-out", str(truth),
    )  # fmt: skip
    assert made.returncode == 0, made.stderr
    return log, truth


def _interrupt(
    args: list[str], signum: int, group: bool, ready: Callable[[int], bool]
) -> tuple[int, str, float]:
    """Run ekfviz, wait until ``ready(pid)`` (where the signal is to find it), send
    ``signum`` (to its whole process group, as a terminal's Ctrl-C does, or to it alone, as
    ``kill`` does), and return its exit code, its stderr and how long it took to exit."""
    process = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.monotonic() + 60.0  # a loaded machine takes seconds to import
    while not ready(process.pid):
        assert process.poll() is None, "the command ended before the signal: make it longer"
        assert time.monotonic() < deadline, "the command never got where the signal should be"
        time.sleep(0.02)
    assert process.poll() is None, "the command ended before the signal: make it longer"
    sent = time.monotonic()
    if group:
        os.killpg(process.pid, signum)
    else:
        process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    took = time.monotonic() - sent
    _until_group_gone(process.pid, timeout=EXIT_BOUND_S)
    with pytest.raises(ProcessLookupError):  # no worker is left running
        os.killpg(process.pid, 0)
    return process.returncode, stderr, took


def _group(pgid: int) -> list[int]:
    """The processes of process group ``pgid`` (Linux: /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rpartition(")")[2].split()
        except OSError:  # ended meanwhile
            continue
        if int(fields[2]) == pgid:
            found.append(int(stat.parent.name))
    return found


def _workers_started(pid: int) -> bool:
    """Whether the command started as a session of its own has started a worker."""
    return any(other != pid for other in _group(pid))


def _until_group_gone(pgid: int, timeout: float) -> None:
    """Wait (at most ``timeout`` s) for the last process of a group to end."""
    deadline = time.monotonic() + timeout
    while _group(pgid) and time.monotonic() < deadline:
        time.sleep(0.02)


def _handles(signum: int) -> Callable[[int], bool]:
    """Whether a process has its handler of ``signum`` in place (a signal before the
    command starts is held and acted on as it starts, with the same line)."""
    return lambda pid: catches_signal(pid, signum)


@pytest.mark.parametrize(
    ("command", "signum", "group"),
    [
        ("sweep", signal.SIGINT, True),
        pytest.param("consistency", signal.SIGINT, True, marks=pytest.mark.slow),
        pytest.param("compare", signal.SIGINT, True, marks=pytest.mark.slow),
        pytest.param("sweep", signal.SIGTERM, False, marks=pytest.mark.slow),
        pytest.param("compare", signal.SIGTERM, False, marks=pytest.mark.slow),
    ],
)
def test_a_study_stops_at_once_with_one_line(
    command: str,
    signum: int,
    group: bool,
    long_log: tuple[Path, Path],
    slow_log: Path,
    tmp_path: Path,
) -> None:
    log, truth = long_log
    save = tmp_path / "kept.rrd"
    save.write_bytes(b"an earlier recording")
    args = {
        "sweep": ["sweep", str(log), "--truth", str(truth), "--preset", "tuning", "--workers", "2"],
        "consistency": ["consistency", "--scenario", "loop", "--steps", "3000", "--runs", "40"],
        # (four replays of the long log end within 7 s here: a replay is fast now)
        "compare": ["compare", str(slow_log), *["--filter", "ekf"] * 4, "--workers", "2"],
    }[command] + ["--save", str(save)]
    code, stderr, took = _interrupt(args, signum, group, ready=_workers_started)
    name = signal.Signals(signum).name
    assert code == 128 + signum, stderr
    assert stderr.count("\n") == 1, stderr  # one line, no worker traceback
    assert f"interrupted ({name})" in stderr and "Traceback" not in stderr
    # said by the study once its runs started, else by the command line
    assert ("cancelled; nothing was saved" in stderr and f"{save} left as it was" in stderr) or (
        "nothing was written; existing files are left as they were" in stderr
    )
    assert save.read_bytes() == b"an earlier recording"
    print(f"{command} {name}: exited {took:.2f} s after the signal")
    assert took < EXIT_BOUND_S


def test_a_command_without_a_message_of_its_own_still_says_one_line(tmp_path: Path) -> None:
    """simulate stopped by SIGTERM: the generic line, exit 143."""
    out = tmp_path / "big.txt"
    code, stderr, took = _interrupt(
        ["simulate", "--scenario", "loop", "--steps", "200000", "--landmarks", "400",
         "-o", str(out), "--truth-out", str(tmp_path / "big.json")],
        signal.SIGTERM, group=False, ready=_handles(signal.SIGTERM),
    )  # fmt: skip
    assert code == 143 and stderr == (
        "error: interrupted (SIGTERM): nothing was written; existing files are left as they were\n"
    )
    assert not out.exists() and took < EXIT_BOUND_S


def _typo(tmp_path: Path) -> Path:
    lines = SAMPLE.read_text().splitlines()
    fields = lines[19].split()
    fields[-1] = "1.x"
    lines[19] = " ".join(fields)
    typo = tmp_path / "typo.txt"
    typo.write_text("\n".join(lines) + "\n")
    return typo


def test_a_failed_replay_leaves_an_existing_recording_byte_for_byte(tmp_path: Path) -> None:
    keep = tmp_path / "keep.rrd"
    assert runner.invoke(app, ["replay", str(SAMPLE), "--save", str(keep)]).exit_code == 0
    before = keep.read_bytes()
    result = run_ekfviz("replay", str(_typo(tmp_path)), "--save", str(keep))
    assert result.returncode == 2
    assert keep.read_bytes() == before
    partial = tmp_path / "keep.partial.rrd"
    assert partial.stat().st_size > 0
    assert result.stderr.count("\n") == 1, result.stderr
    assert "typo.txt:20:" in result.stderr
    assert f"saved in {partial} ({keep} is left as it was)" in result.stderr
    info = json.loads(run_ekfviz("info", str(partial), "--json").stdout)
    assert info["status"]["state"] == "stopped"
    # with nothing at the path, the partial recording goes there, as before
    fresh = tmp_path / "fresh.rrd"
    result = run_ekfviz("replay", str(_typo(tmp_path)), "--save", str(fresh))
    assert result.returncode == 2 and fresh.is_file()
    assert f"saved in {fresh}" in result.stderr and "left as it was" not in result.stderr


def test_an_interrupted_replay_leaves_an_existing_recording(slow_log: Path, tmp_path: Path) -> None:
    keep = tmp_path / "run.rrd"
    keep.write_bytes(b"a finished recording")
    code, stderr, took = _interrupt(
        ["replay", str(slow_log), "--save", str(keep)],
        signal.SIGINT,
        group=True,
        ready=lambda pid: recording_holds(tmp_path, keep.name, RECORDED),
    )
    assert code == 130 and stderr.count("\n") == 1, (code, stderr)
    assert keep.read_bytes() == b"a finished recording"
    assert (tmp_path / "run.partial.rrd").is_file()
    assert "run.partial.rrd" in stderr and took < EXIT_BOUND_S


def test_stale_part_files_of_dead_runs_are_removed_on_the_next_run(tmp_path: Path) -> None:
    target = tmp_path / "run.rrd"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True)  # fmt: skip
    stale = tmp_path / f".run.rrd.{int(dead.stdout)}.0123abcd.part"
    live = tmp_path / f".run.rrd.{os.getpid()}.4567cdef.part"  # a run still writing
    other = tmp_path / f".other.rrd.{int(dead.stdout)}.89abcdef.part"  # another path's
    for path in (stale, live, other):
        path.write_bytes(b"half a recording")
    assert runner.invoke(app, ["replay", str(SAMPLE), "--save", str(target)]).exit_code == 0
    assert not stale.exists() and live.exists() and other.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["run.rrd", live.name, other.name])


@pytest.mark.parametrize("command", ["convert", "simulate"])
def test_convert_and_simulate_refuse_to_overwrite_without_force(
    command: str, tmp_path: Path
) -> None:
    target = tmp_path / "out.txt"
    target.write_text("keep me\n")
    truth_out = tmp_path / "t.json"
    args = (
        ["convert", str(SAMPLE), str(target)]
        if command == "convert"
        else ["simulate", "-o", str(target), "--truth-out", str(truth_out)]
    )
    refused = run_ekfviz(*args)
    assert refused.returncode == 2
    assert refused.stderr == f"error: {'TARGET' if command == 'convert' else '--output'}" \
        f" {target}: exists; add --force to replace it\n"  # fmt: skip
    assert target.read_text() == "keep me\n" and not truth_out.exists()
    forced = run_ekfviz(*args, "--force")
    assert forced.returncode == 0, forced.stderr
    assert target.read_text() != "keep me\n"


def test_the_recorded_truth_digest_is_the_files_sha256(tmp_path: Path) -> None:
    rrd = tmp_path / "run.rrd"
    result = runner.invoke(app, ["replay", str(SAMPLE), "--truth", str(TRUTH), "--save", str(rrd)])
    assert result.exit_code == 0, result.output
    info = json.loads(run_ekfviz("info", str(rrd), "--json").stdout)
    assert info["truth"]["sha256"] == hashlib.sha256(TRUTH.read_bytes()).hexdigest()
    assert info["input"]["sha256"] == hashlib.sha256(SAMPLE.read_bytes()).hexdigest()


def _outward_address() -> str | None:
    """An address of this machine that is not loopback, if it has one."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("192.0.2.1", 9))  # TEST-NET: no packet is sent for UDP connect
        except OSError:
            return None
        address = str(probe.getsockname()[0])
    return None if address.startswith("127.") or address == "0.0.0.0" else address


def _reachable(host: str, port: int) -> bool:
    try:
        socket.create_connection((host, port), timeout=2.0).close()
    except OSError:
        return False
    return True


def test_serve_listens_on_loopback_only() -> None:
    from ekfviz.viz.viewer import GRPC_PORT, WEB_PORT

    outward = _outward_address()
    if outward is None:
        pytest.skip("no non-loopback address to try")
    if _reachable("127.0.0.1", WEB_PORT) or _reachable("127.0.0.1", GRPC_PORT):
        pytest.skip("the viewer ports are taken on this machine")
    process = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", "replay", str(SAMPLE), "--serve"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        for line in process.stdout:
            if line.startswith("Serving the web viewer at"):
                assert "http://localhost:9090/" in line
                break
        else:
            pytest.fail(f"no web viewer: {process.communicate()[1]}")
        assert _reachable("127.0.0.1", WEB_PORT) and _reachable("127.0.0.1", GRPC_PORT)
        assert not _reachable(outward, WEB_PORT) and not _reachable(outward, GRPC_PORT)
    finally:
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=30)
    assert process.returncode in (0, 130) and "Traceback" not in stderr  # Ctrl-C ends serving
    deadline = time.monotonic() + EXIT_BOUND_S
    while _reachable("127.0.0.1", WEB_PORT) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _reachable("127.0.0.1", WEB_PORT)  # the viewer program ended with it


def test_bind_says_what_it_expects() -> None:
    result = run_ekfviz("replay", str(SAMPLE), "--serve", "--bind", "everywhere")
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "--bind everywhere: expected an IP address" in result.stderr
    alone = run_ekfviz("replay", str(SAMPLE), "--bind", "0.0.0.0")
    assert alone.returncode == 2 and "add --serve" in alone.stderr


def test_an_interrupt_python_had_to_drop_is_raised_again(capfd: pytest.CaptureFixture[str]) -> None:
    """A signal handled where its exception cannot propagate (an at-fork hook, a
    finaliser) still stops the command at its next wait, and Python says nothing of it."""
    from ekfviz import signals

    class Dropper:
        def __del__(self) -> None:
            signal.raise_signal(signal.SIGINT)  # handled here: the exception is dropped

    signals.as_interrupts()
    try:
        Dropper()
        with pytest.raises(signals.Interrupted):
            signals.raise_if_interrupted()
    finally:
        signals.reset()
    signals.raise_if_interrupted()  # nothing left once reset
    assert capfd.readouterr().err == ""


def test_a_signal_while_a_recording_is_finished_is_acted_on_once_it_is() -> None:
    """signals.held(): SIGTERM inside the block (a replay finishing its recording) waits
    for the block's end, then raises as the replay's handlers do; none: nothing raised."""
    from ekfviz import signals

    done: list[str] = []
    with signals.as_exceptions():
        with pytest.raises(signals.Terminated), signals.held():
            signal.raise_signal(signal.SIGTERM)  # remembered, not raised here
            done.append("finished")
        assert done == ["finished"]
        with signals.held():
            done.append("again")  # no signal: the block ends as usual
        with pytest.raises(KeyboardInterrupt):  # the replay's handlers are back
            signal.raise_signal(signal.SIGINT)
        with pytest.raises(KeyboardInterrupt), signals.held():  # asked twice: at once
            signal.raise_signal(signal.SIGINT)
            done.append("held one")
            signal.raise_signal(signal.SIGINT)
            done.append("not reached")
    assert done == ["finished", "again", "held one"]


def test_a_signal_held_by_an_outer_block_outlives_an_inner_one() -> None:
    """signals.held() inside signals.held() (an atomic write in a grade's last write):
    a signal the outer block remembered is acted on at its end, not forgotten by the
    inner block; one the inner block remembered too."""
    from ekfviz import signals

    with signals.as_exceptions():
        with pytest.raises(signals.Terminated), signals.held():
            signal.raise_signal(signal.SIGTERM)  # before the inner block
            with signals.held():
                pass
        reached = []
        with pytest.raises(signals.Terminated), signals.held():
            with signals.held():
                signal.raise_signal(signal.SIGTERM)  # inside it: the outer block's end
            reached.append("the outer block's rest")
        assert reached == ["the outer block's rest"]


def test_ctrl_c_while_a_replay_finishes_keeps_the_whole_recording_and_says_where(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every event replayed, the recording being finished: Ctrl-C then waits for it, and
    the recording, whole, replaces the file at its path as a finished run's does; exit
    130 and the line say so (what a signalled replay's test must not mistake for a cut)."""
    from ekfviz import readback
    from ekfviz.viz.run import RunLogger

    finish = RunLogger.finish

    def pressed(self: RunLogger, evaluation: object) -> None:
        signal.raise_signal(signal.SIGINT)  # as the recording is finished
        finish(self, evaluation)  # type: ignore[arg-type]

    monkeypatch.setattr(RunLogger, "finish", pressed)
    keep = tmp_path / "run.rrd"
    keep.write_bytes(b"an earlier recording")
    result = runner.invoke(app, ["replay", str(SAMPLE), "--save", str(keep)])
    assert result.exit_code == 130
    assert result.output.strip().splitlines()[-1] == (
        f"error: {SAMPLE}: interrupted (SIGINT): the finished recording is saved in {keep}"
    )
    info = readback.read_recording_info(keep)
    assert info is not None and info.status is not None and info.status.state == "finished"
    assert not list(tmp_path.glob("*.partial.rrd")) and not list(tmp_path.glob(".*.part"))


def test_a_failed_replay_names_the_recording_it_kept_as_it_was_given(tmp_path: Path) -> None:
    """A relative --save path, a run cut short by a bad line: the line names the file as
    the user wrote it, and says "left as it was" only where a file was left."""
    typo = _typo(tmp_path)

    def replay() -> str:
        result = run_ekfviz("replay", typo.name, "--save", "run.rrd", cwd=tmp_path)
        assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
        return result.stderr

    assert replay().endswith("; the recording of everything before it is saved in run.rrd\n")
    assert replay().endswith(
        "; the recording of everything before it is saved in run.partial.rrd"
        " (run.rrd is left as it was)\n"
    )


def test_a_consistency_stopped_after_its_report_says_the_report_was_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It said "nothing was written; existing files are left as they were" with the new
    report in place."""
    from ekfviz import signals
    from ekfviz.app import consistency

    def stopped_saving(*args: object) -> None:
        raise signals.Interrupted

    monkeypatch.setattr(consistency, "_save", stopped_saving)
    report, save = tmp_path / "mc.json", tmp_path / "mc.rrd"
    result = CliRunner().invoke(app, ["consistency", "--runs", "2", "--report", str(report),
                                      "--save", str(save)])  # fmt: skip
    assert result.exit_code == 130, result.output
    assert (
        f"{report} written whole before it; {save} not written (an existing file left as it"
        " was)" in " ".join(result.output.split())
    ), result.output
    assert report.is_file() and not save.exists()


def test_a_grade_stopped_says_what_it_kept_and_removes_its_workers_temporary_files(
    tmp_path: Path,
) -> None:
    from ekfviz.app.class_grade import GradeRequest, _stopped
    from ekfviz.app.grade import GradeTask
    from ekfviz.core.params import FilterParams

    task = GradeTask(name="s1.py", path=tmp_path / "s1.py", logs=((SAMPLE, None, None, None),),
                     params=FilterParams(), timeout_s=10.0, memory_mb=None)  # fmt: skip
    saved = tmp_path / "recs"
    saved.mkdir()
    (saved / ".s1.py-classic.rrd.4242.0badcafe.part").write_bytes(b"half")  # a killed worker's
    (saved / "s1.py-classic.rrd").write_bytes(b"whole")
    (saved / ".mine.part").write_bytes(b"not ekfviz's")
    request = GradeRequest.__new__(GradeRequest)
    object.__setattr__(request, "save_dir", saved)
    said = _stopped(request, [task])
    assert said == f"the recordings of the submissions checked before it are in {saved}"
    assert sorted(p.name for p in saved.iterdir()) == [".mine.part", "s1.py-classic.rrd"]


# -- a signalled replay keeps its recording ------------------------------------------------


@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [(2, 130, "SIGINT"), pytest.param(15, 143, "SIGTERM", marks=pytest.mark.slow)],
)
def test_a_signal_leaves_a_complete_recording(
    tmp_path: Path, slow_log: Path, signum: int, code: int, word: str
) -> None:
    from conftest import entity_rows, rrd_verify

    rrd = tmp_path / "run.rrd"
    returned, stderr, _ = _interrupt(
        ["replay", str(slow_log), "--save", str(rrd)],
        signum,
        group=False,
        ready=lambda pid: recording_holds(tmp_path, rrd.name, RECORDED),  # before its end
    )
    assert returned == code, stderr
    assert f"interrupted ({word})" in stderr or f"terminated ({word})" in stderr
    assert "Traceback" not in stderr
    rrd_verify(rrd)
    last = entity_rows(rrd, "/log")[-1]
    assert word in str(last["TextLog:text"]) and "after input line" in str(last["TextLog:text"])
    assert not list(tmp_path.glob("*.part"))


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [pytest.param(2, 130, "SIGINT", marks=pytest.mark.slow), (15, 143, "SIGTERM")],
)
def test_a_signal_during_start_up_still_leaves_a_recording(
    tmp_path: Path, signum: int, code: int, word: str
) -> None:
    """Even while rerun is still being imported, and with SIGINT ignored by the parent
    (as ``ekfviz ... &`` in a script has it)."""
    import os
    import signal
    import time

    from conftest import catches_signal, entity_rows, rrd_verify

    log = tmp_path / "log.txt"
    log.write_text(f"{OBS}\n" + "1 0.1\n0.1 5 0.2 6\n" * 50)
    rrd = tmp_path / "run.rrd"
    process = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", "replay", str(log), "--save", str(rrd)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    deadline = time.monotonic() + 30
    while not catches_signal(process.pid, signum) and time.monotonic() < deadline:
        time.sleep(0.005)
    os.kill(process.pid, signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == code, stderr
    assert f"({word}) after input line 1;" in stderr and "Traceback" not in stderr
    rrd_verify(rrd)
    assert word in str(entity_rows(rrd, "/log")[-1]["TextLog:text"])


def test_info_says_a_run_cut_by_sigterm_stopped_early_and_where(
    tmp_path: Path, slow_log: Path
) -> None:
    rrd = tmp_path / "cut.rrd"
    code, stderr, _ = _interrupt(
        ["replay", str(slow_log), "--save", str(rrd)],
        signal.SIGTERM,
        group=False,
        ready=lambda pid: recording_holds(tmp_path, rrd.name, RECORDED),  # before its end
    )
    assert code == 143, stderr
    document = json.loads(run_ekfviz("info", str(rrd), "--json").stdout)
    status = document["status"]
    assert status["state"] == "stopped" and status["stopped_early"] is True
    assert "terminated (SIGTERM)" in status["reason"]
    assert status["event"] >= 0 and status["line"] >= 1
    text = run_ekfviz("info", str(rrd)).stdout
    assert re.search(r"^status +stopped early after event \d+, step \d+, input line", text, re.M)
