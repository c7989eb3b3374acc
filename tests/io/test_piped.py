"""Logs that come through a pipe: ``ekfviz replay -`` and ``ekfviz replay <(zcat log.gz)``.

A shell's process substitution hands the command ``/dev/fd/N``, a descriptor it
inherits open on a pipe; here the test makes that pipe (``pass_fds``) and writes the
log into it from a thread, as ``zcat`` would. See :mod:`ekfviz.io.piped`.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import pty
import signal
import stat
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from commands import run_ekfviz, run_ekfviz_process
from conftest import catches_signal, entity_rows

from ekfviz.io.piped import PipedInputError, read_ahead

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="/dev/fd/N opens the descriptor's file on Linux"
)

DATA = Path(__file__).resolve().parents[2] / "data"
LOG, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"


def ekfviz(*args: str, **kwargs: object) -> subprocess.CompletedProcess[str]:
    """``python -m ekfviz ARGS`` on a standard input of its own: ``-`` reads descriptor 0,
    which in the test's process is the test runner's."""
    return run_ekfviz_process(*args, timeout=120, **kwargs)


def piped(content: bytes) -> int:
    """The read end of a pipe that a thread fills with ``content`` and then closes."""
    read_end, write_end = os.pipe()

    def write() -> None:
        with os.fdopen(write_end, "wb") as out:
            out.write(content)

    threading.Thread(target=write, daemon=True).start()
    return read_end


@pytest.fixture(scope="module")
def by_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, list[dict[str, object]]]:
    """What a replay of the bundled log and truth, given as files, prints and records."""
    rrd = tmp_path_factory.mktemp("by_file") / "file.rrd"
    done = run_ekfviz("replay", LOG, "--truth", TRUTH, "--save", rrd)
    assert done.returncode == 0, done.stderr
    return done.stdout, entity_rows(rrd, "/world/robot")


def _results(stdout: str) -> list[str]:
    """A replay's printed results without the line that says where it saved them."""
    return [line for line in stdout.splitlines() if not line.startswith("Saved ")]


def test_a_log_on_standard_input_replays_as_its_file(
    tmp_path: Path, by_file: tuple[str, list[dict[str, object]]]
) -> None:
    rrd = tmp_path / "stdin.rrd"
    done = ekfviz("replay", "-", "--truth", str(TRUTH), "--save", str(rrd), input=LOG.read_text())
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    stdout, robot = by_file
    # the same landmarks, errors, NEES and NIS; the last line says where it was saved
    assert _results(done.stdout) == _results(stdout)
    assert done.stdout.splitlines()[-1].startswith(f"Saved {rrd}; open it with: ")
    assert entity_rows(rrd, "/world/robot") == robot  # every pose, as recorded from the file
    info = run_ekfviz("info", rrd)
    assert "ekfviz replay - --truth" in info.stdout  # the command as it was given
    assert "input              stdin (3046 bytes)" in info.stdout
    assert f"input sha256       {hashlib.sha256(LOG.read_bytes()).hexdigest()}" in info.stdout


def test_a_process_substitution_of_log_and_truth_replays_as_their_files(
    tmp_path: Path, by_file: tuple[str, list[dict[str, object]]]
) -> None:
    log, truth = piped(LOG.read_bytes()), piped(TRUTH.read_bytes())
    rrd = tmp_path / "sub.rrd"
    try:
        done = run_ekfviz("replay", f"/dev/fd/{log}", f"--truth=/dev/fd/{truth}", "--save", rrd)
    finally:
        os.close(log)
        os.close(truth)
    assert done.returncode == 0, done.stderr
    stdout, robot = by_file
    assert _results(done.stdout) == _results(stdout)
    assert entity_rows(rrd, "/world/robot") == robot


def test_a_bad_line_in_a_piped_log_is_named_by_the_path_given(tmp_path: Path) -> None:
    log = piped(b"0.1 0.2 0.3 0.4\n0.5 zero\n")
    try:
        rrd = str(tmp_path / "x.rrd")
        done = run_ekfviz("replay", f"/dev/fd/{log}", "--save", rrd)
    finally:
        os.close(log)
    assert done.returncode == 2
    assert done.stderr == (
        f"error: /dev/fd/{log}:2: found 'zero', expected a decimal number; the recording of"
        f" everything before it is saved in {tmp_path / 'x.rrd'}\n"
    )


def test_standard_input_given_twice_is_refused(tmp_path: Path) -> None:
    done = ekfviz("replay", "-", "--truth", "-", "--save", str(tmp_path / "x.rrd"), input="")
    assert done.returncode == 2
    assert done.stderr == "error: -: standard input is given twice; it can be read once\n"


def test_standard_input_on_a_terminal_is_refused_at_once(tmp_path: Path) -> None:
    main, terminal = pty.openpty()
    try:
        done = ekfviz("replay", "-", "--save", str(tmp_path / "x.rrd"), stdin=terminal)
    finally:
        os.close(main)
        os.close(terminal)
    assert done.returncode == 2
    assert done.stderr.startswith("error: -: standard input is a terminal, expected a log piped in")


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_stops_a_wait_for_a_pipe_that_does_not_end(
    tmp_path: Path, signum: int, code: int
) -> None:
    read_end, write_end = os.pipe()  # the writer stays open: the pipe never ends
    try:
        process = subprocess.Popen(
            [sys.executable, "-m", "ekfviz", "replay", "-", "--save", str(tmp_path / "x.rrd")],
            stdin=read_end, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            # SIGINT ignored, as a script's "ekfviz ... &" has it: Python then installs no
            # handler of its own, so a handler seen is ekfviz's (it handles SIGINT anyway)
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
        )  # fmt: skip
        deadline = time.monotonic() + 60
        while not catches_signal(process.pid, signum) and time.monotonic() < deadline:
            time.sleep(0.005)  # ekfviz defers signals from its first line on
        # one that lands during start-up stays deferred (a replay honours it later): sent
        # again until one lands in the wait for the pipe
        while process.poll() is None and time.monotonic() < deadline:
            process.send_signal(signum)
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=0.5)
        _, stderr = process.communicate(timeout=30)
    finally:
        os.close(read_end)
        os.close(write_end)
    assert process.returncode == code
    name = signal.Signals(signum).name
    assert stderr == (
        f"error: interrupted ({name}): before the piped input had ended; nothing was written\n"
    )
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def pipe() -> Iterator[tuple[int, int]]:
    read_end, write_end = os.pipe()
    yield read_end, write_end
    for fd in (read_end, write_end):
        with contextlib.suppress(OSError):  # (the test closed it)
            os.close(fd)


def test_a_pipe_read_ahead_opens_whole_again_and_again(pipe: tuple[int, int]) -> None:
    read_end, write_end = pipe
    os.write(write_end, b"1 2 3\n4 5 6\n")
    os.close(write_end)
    path = f"/dev/fd/{read_end}"
    assert read_ahead(path) == path
    for _ in range(3):  # the format's first line, the events, the run's digest
        assert Path(path).read_bytes() == b"1 2 3\n4 5 6\n"
    assert Path(path).is_file() and Path(path).stat().st_size == 12


def test_a_pipe_that_gives_too_much_is_refused(pipe: tuple[int, int]) -> None:
    read_end, write_end = pipe
    os.write(write_end, b"0" * 5000)
    os.close(write_end)
    with pytest.raises(PipedInputError) as refused:
        read_ahead(f"/dev/fd/{read_end}", limit=4096)
    assert str(refused.value).startswith(f"/dev/fd/{read_end}: the pipe gave more than ")


def test_a_pipe_open_for_writing_is_left_alone(pipe: tuple[int, int]) -> None:
    read_end, write_end = pipe
    assert read_ahead(f"/dev/fd/{write_end}") == f"/dev/fd/{write_end}"
    assert all(stat.S_ISFIFO(os.fstat(fd).st_mode) for fd in pipe)  # still the pipe
    os.write(write_end, b"still the pipe")
    assert os.read(read_end, 100) == b"still the pipe"


def test_standard_input_is_read_only_where_an_input_is_given_as_dash(tmp_path: Path) -> None:
    """``-`` as an output's value is not standard input: ``simulate -o -`` writes ./-"""
    done = run_ekfviz("simulate", "-o", "-", "--truth-out", "t.json", cwd=tmp_path,
                      input="the piped text\n")  # fmt: skip
    assert done.returncode == 0, done.stderr
    written = (tmp_path / "-").read_text().splitlines()  # the simulated log
    assert len(written) > 50 and all(len(line.split()) in (2, 12) for line in written)


def test_a_bad_piped_truth_is_named_as_given(tmp_path: Path) -> None:
    done = ekfviz(
        "replay", str(LOG), "--truth", "-", "--save", str(tmp_path / "x.rrd"), input="1 2 3\n"
    )
    assert done.returncode == 2
    assert done.stderr.startswith("error: /dev/stdin:1: ")
    assert len(done.stderr.splitlines()) == 1


def test_a_consistency_whose_reader_went_away_still_writes_its_files(tmp_path: Path) -> None:
    """``consistency ... | head -1`` printed its table first: the closed pipe ended it
    before its report and recording were written (replay, sweep and compare keep them)."""
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path), "XDG_DATA_HOME": str(tmp_path)}
    report, save = tmp_path / "mc.json", tmp_path / "mc.rrd"
    reader, writer = os.pipe()
    os.close(reader)  # nobody reads: the first write to stdout breaks the pipe
    try:
        done = subprocess.run(
            [sys.executable, "-m", "ekfviz", "consistency", "--runs", "2", "--report",
             str(report), "--save", str(save)],
            stdout=writer, stderr=subprocess.PIPE, env=env, timeout=300,
        )  # fmt: skip
    finally:
        os.close(writer)
    assert report.is_file() and save.is_file(), done.stderr
