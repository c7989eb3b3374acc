"""Recordings are read in a child process: a damaged one that makes Rerun's reader abort
(a flipped length asking for exabytes: Rust's out-of-memory handler aborts) is one line
and exit code 2, not a dead ekfviz (``ekfviz.readback.apart``)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ekfviz import readback
from ekfviz.cli import app
from ekfviz.readback import apart, export, info

pytestmark = pytest.mark.skipif(not apart.FORKS, reason="reads in the process without fork")

runner = CliRunner()


def _dies(path: Path) -> object:
    print("memory allocation of 7311705562807561833 bytes failed", file=sys.stderr)
    os.abort()


def _answers(path: Path) -> object:
    return {"path": path, "values": np.arange(200_000, dtype=np.float64)}  # > a pipe's buffer


def _refuses(path: Path) -> object:
    raise readback.NotARecordingError(f"{path}: not a Rerun recording (.rrd)")


def _panics(path: Path) -> object:
    raise ZeroDivisionError("chunk\nwith more lines")


def test_a_reader_that_aborts_is_one_line_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "damaged.rrd"
    path.write_bytes(b"RRF2" + bytes(100))
    with pytest.raises(readback.NotARecordingError) as caught:
        apart.read_apart(_dies, path)
    message = str(caught.value)
    assert message == (
        f"{path}: a damaged recording: Rerun's reader gave up on it (killed by SIGABRT:"
        " memory allocation of 7311705562807561833 bytes failed)"
    )
    assert isinstance(caught.value.__cause__, apart.ReaderDied)


def test_what_the_child_reads_or_refuses_comes_back_as_it_is(tmp_path: Path) -> None:
    path = tmp_path / "run.rrd"
    got = apart.read_apart(_answers, path)
    assert isinstance(got, dict) and got["path"] == path
    np.testing.assert_array_equal(got["values"], np.arange(200_000))
    with pytest.raises(readback.NotARecordingError, match=r"\.rrd\)$"):
        apart.read_apart(_refuses, path)
    with pytest.raises(readback.NotARecordingError) as caught:  # any other error: still one line
        apart.read_apart(_panics, path)
    assert str(caught.value) == f"{path}: not a Rerun recording (.rrd): chunk"
    assert "ZeroDivisionError" in str(caught.value.__cause__)


def test_a_child_stuck_past_its_patience_is_killed_and_the_file_read_here(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    parent = os.getpid()

    def stuck_in_the_child(path: Path) -> str:
        if os.getpid() != parent:
            time.sleep(60)
        return "read here"

    monkeypatch.setattr(apart, "patience", lambda path: 0.5)
    start = time.monotonic()
    assert apart.read_apart(stuck_in_the_child, tmp_path / "run.rrd") == "read here"
    assert time.monotonic() - start < 30


@pytest.mark.parametrize(
    ("command", "module", "name"),
    [("info", info, "_read_recording_info"), ("export", export, "_read_recorded_run")],
)
def test_the_commands_say_one_line_where_the_reader_aborts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: str, module: object, name: str
) -> None:
    """As with a real damaged file (found by tests/test_fuzz_readers.py: Rerun's reader
    aborted pytest itself before): exit 2, one line, nothing else."""
    path = tmp_path / "damaged.rrd"
    path.write_bytes(b"RRF2" + bytes(100))
    monkeypatch.setattr(module, name, _dies)
    args = [command, str(path)] + (
        ["--tum", str(tmp_path / "out.tum")] if command == "export" else []
    )
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "killed by SIGABRT" in lines[0] and str(path) in lines[0]
    assert not (tmp_path / "out.tum").exists()


def test_a_path_as_text_reads_and_an_interrupt_leaves_no_child(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A str path (a notebook's habit) failed in the parent after the fork, an interrupt
    while the child read too: each left a zombie child behind."""
    path = tmp_path / "x.rrd"
    path.write_bytes(b"")
    answer = apart.read_apart(_answers, str(path))
    assert isinstance(answer, dict) and answer["path"] == path
    forked: list[int] = []
    fork = os.fork

    def recorded_fork() -> int:
        pid = fork()
        if pid:
            forked.append(pid)
        return pid

    def interrupted(reader: int, timeout_s: float) -> bytes:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fork", recorded_fork)
    monkeypatch.setattr(apart, "_answer", interrupted)
    with pytest.raises(KeyboardInterrupt):
        apart.read_apart(_answers, path)
    (pid,) = forked
    with pytest.raises(ChildProcessError):  # reaped already
        os.waitpid(pid, os.WNOHANG)
