"""The standard streams of a real process: a full, closed or read-only standard output, a
standard error that is no terminal or is one, an output encoding without unicode, a
locale without UTF-8.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ekfviz.cli import app

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
SAMPLE = DATA / "classic.txt"
runner = CliRunner()


# -- standard output -----------------------------------------------------------------------


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full here")
@pytest.mark.parametrize(
    "args",
    [
        ["replay", str(SAMPLE), "--save", "run.rrd"],
        pytest.param(
            ["replay", str(SAMPLE), "--save", "run.rrd", "--json"], marks=pytest.mark.slow
        ),
        ["replay", "--help"],
        pytest.param(["--version"], marks=pytest.mark.slow),
    ],
    ids=["replay", "replay --json", "help", "version"],
)
def test_standard_output_on_a_full_disk_is_one_line_and_exit_2(
    tmp_path: Path, args: list[str]
) -> None:
    """``> /dev/full``: every write to it fails with "No space left on device"."""
    with open("/dev/full", "w") as full:
        result = subprocess.run(
            [sys.executable, "-m", "ekfviz", *args],
            stdout=full, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        )  # fmt: skip
    assert result.returncode == 2, result.stderr
    last = result.stderr.splitlines()[-1]
    assert last == (
        "error: standard output: No space left on device: what the command prints was not"
        " written whole"
    )
    assert "Traceback" not in result.stderr
    if "--json" not in args:  # (--json puts the tables on stderr)
        assert result.stderr.count("\n") == 1


def test_a_closed_standard_output_is_the_null_device_not_the_recording(tmp_path: Path) -> None:
    """``ekfviz replay ... >&-``: the recording would get descriptor 1, and standard
    output would be written into it."""
    from conftest import rrd_verify

    from ekfviz import readback

    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(SAMPLE), "--save", "run.rrd"],
        stderr=subprocess.PIPE, text=True, cwd=tmp_path, preexec_fn=lambda: os.close(1),
    )  # fmt: skip
    assert result.returncode == 0 and result.stderr == ""
    rrd_verify(tmp_path / "run.rrd")
    info = readback.read_recording_info(tmp_path / "run.rrd")
    assert info is not None and info.status is not None and info.status.state == "finished"


def _env(cwd: Path) -> dict[str, str]:
    env = {**os.environ, "XDG_CONFIG_HOME": str(cwd), "XDG_DATA_HOME": str(cwd), "CI": "1"}
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    return env


def test_help_to_a_standard_output_that_cannot_be_written_is_one_line(tmp_path: Path) -> None:
    with open(os.devnull) as read_only:  # stdout open for reading: EBADF at the write
        done = subprocess.run(
            [sys.executable, "-m", "ekfviz", "--help"], stdout=read_only,
            stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=_env(tmp_path), timeout=120,
        )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr == (
        "error: standard output: Bad file descriptor: what the command prints was not written"
        " whole\n"
    )


@pytest.mark.parametrize("encoding", ["ascii", pytest.param("latin-1", marks=pytest.mark.slow)])
def test_a_terminal_that_cannot_show_unicode_gets_the_results_not_a_traceback(
    tmp_path: Path, encoding: str
) -> None:
    """sigma, plus-minus and the tables' lines on an ASCII or Latin-1 standard output
    (``LC_ALL=C`` with ``PYTHONUTF8=0``, ``PYTHONIOENCODING``): replaced, not fatal."""
    import os

    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(SAMPLE), "--save",
         str(tmp_path / "run.rrd")],
        capture_output=True, env={**os.environ, "PYTHONIOENCODING": encoding},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr.decode(encoding, "replace")
    assert result.stderr == b""
    text = result.stdout.decode(encoding)
    assert "Landmarks at the end of the run" in text and "Final pose: x " in text
    assert "+----" in text  # the table drawn in ASCII


@pytest.mark.slow
def test_a_non_ascii_file_name_in_an_ascii_locale_is_one_line_and_recorded(
    tmp_path: Path,
) -> None:
    """With LC_ALL=C and Python's UTF-8 mode off, ``bäd.txt`` reaches Python as lone
    surrogates: Rerun refused them with two warnings before the error, the recording lost
    why the run stopped, and the error named ``b\\udcc3\\udca4d.txt``."""
    import json
    import os

    log = tmp_path / "bäd.txt"
    log.write_text((DATA / "classic.txt").read_text() + "1.0 abc\n")
    env = {**os.environ, "LC_ALL": "C", "PYTHONUTF8": "0", "XDG_CONFIG_HOME": str(tmp_path),
           "XDG_DATA_HOME": str(tmp_path)}  # fmt: skip
    run = [sys.executable, "-m", "ekfviz"]
    done = subprocess.run([*run, "replay", "bäd.txt", "--save", "o.rrd"], capture_output=True,
                          env=env, cwd=tmp_path, timeout=120)  # fmt: skip
    assert done.returncode == 2
    (line,) = done.stderr.decode("ascii", "replace").strip().splitlines()
    assert line.startswith("error: b?d.txt:60: found 'abc'"), line  # (ä in ASCII: ?)
    shown = subprocess.run([*run, "info", "o.rrd", "--json"], capture_output=True, env=env,
                           cwd=tmp_path, timeout=120)  # fmt: skip
    assert shown.returncode == 0 and not shown.stderr, shown.stderr
    info = json.loads(shown.stdout)
    assert info["status"]["reason"].startswith("bäd.txt:60: found 'abc'"), info
    assert info["name"] == "bäd"


# -- standard error ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def long_enough_for_a_bar(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A log over the progress bar's threshold (1 MiB), replayed in about a second."""
    from ekfviz.app.replay import PROGRESS_MIN_BYTES

    log = tmp_path_factory.mktemp("bar") / "long.txt"
    made = runner.invoke(
        app, ["simulate", "--scenario", "loop", "--steps", "20000", "--landmarks", "40",
              "-o", str(log), "--truth-out", str(log.with_suffix(".json"))],
    )  # fmt: skip
    assert made.exit_code == 0, made.output
    assert log.stat().st_size > PROGRESS_MIN_BYTES
    return log


@pytest.mark.slow
def test_a_long_replay_writes_nothing_to_a_standard_error_that_is_no_terminal(
    long_enough_for_a_bar: Path, tmp_path: Path
) -> None:
    """No progress bar on a pipe or a file: not even the blank line a bar ends with."""
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(long_enough_for_a_bar),
         "--save", str(tmp_path / "run.rrd")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert result.returncode == 0 and result.stderr == ""


@pytest.mark.slow
def test_a_long_replay_shows_its_progress_on_a_terminal_and_its_results_where_asked(
    long_enough_for_a_bar: Path, tmp_path: Path
) -> None:
    """The bar on a terminal, the JSON document where standard output goes (a file
    here): rich's bar, left to itself, sent standard output to its terminal too, and
    ``replay BIG --json > out.json`` wrote an empty file."""
    import os
    import pty

    leader, follower = pty.openpty()
    document = tmp_path / "out.json"
    with document.open("w") as stdout:
        process = subprocess.Popen(
            [sys.executable, "-m", "ekfviz", "replay", str(long_enough_for_a_bar), "--json",
             "--save", str(tmp_path / "run.rrd")],
            stdout=stdout, stderr=follower,
            env={**os.environ, "TERM": "xterm", "COLUMNS": "120"},
        )  # fmt: skip
        os.close(follower)
        shown = b""
        while True:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # the terminal's other end closed: the run is over
                break
            if not chunk:
                break
            shown += chunk
        os.close(leader)
        assert process.wait(timeout=60) == 0
    assert f"replaying {long_enough_for_a_bar.name}".encode() in shown
    assert b"Landmarks at the end of the run" in shown  # --json: the tables on stderr
    assert b"error" not in shown and b"Traceback" not in shown
    assert b'"final_pose"' not in shown
    assert "final_pose" in json.loads(document.read_text())
