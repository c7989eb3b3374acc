"""Every way a user can give an unusable output path, for every command that writes one,
and a ``--connect`` to where no viewer answers: one line, exit 2, nothing left behind.

Script-style: the matrix below is tried in turn. Paths are checked in-process (they are
refused before any work, so a real process would show nothing more); the ``--connect``
cases and one path case run ``python -m ekfviz`` in a process of its own, as a user does.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ekfviz.cli import app

DATA = Path(__file__).parents[2] / "data"
SAMPLE = DATA / "classic.txt"
runner = CliRunner()


def _snapshot(root: Path) -> set[Path]:
    return {p.relative_to(root) for p in root.rglob("*")}


@pytest.fixture
def place(tmp_path: Path) -> Path:
    """A working folder with an existing folder and an existing file in it."""
    (tmp_path / "folder").mkdir()
    (tmp_path / "file.txt").write_text("a file\n")
    return tmp_path


# (name, how the bad path is made from the working folder, what the message says)
PATHS: list[tuple[str, Callable[[Path], str], str]] = [
    ("not writable", lambda _: "/proc/x.rrd", "cannot write in /proc"),
    ("dot", lambda _: ".", "names a folder"),
    ("existing folder", lambda root: str(root / "folder"), "is a folder"),
    ("folder with a slash", lambda root: str(root / "folder") + "/", "folder"),
    ("under a file", lambda root: str(root / "file.txt" / "run.rrd"), "is a file, not a folder"),
    ("missing parent", lambda root: str(root / "missing" / "run.rrd"), "does not exist"),
    ("missing under /", lambda _: "/ekfviz-no-such-folder/run.rrd", "does not exist"),
]


def _command(name: str, path: str, place: Path) -> list[str]:
    """The command line of ``name`` with ``path`` as its output."""
    recording = place / "made.rrd"
    return {
        "replay --save": ["replay", str(SAMPLE), "--save", path],
        "replay --report": ["replay", str(SAMPLE), "--save", str(recording), "--report", path],
        "sweep --save": ["sweep", str(SAMPLE), "--vary", "sigma_x=x10", "--save", path],
        "sweep --report": [
            "sweep", str(SAMPLE), "--vary", "sigma_x=x10", "--save", str(recording),
            "--report", path,
        ],
        "consistency --save": ["consistency", "--runs", "2", "--save", path],
        "consistency --report": ["consistency", "--runs", "2", "--report", path],
        "convert": ["convert", str(SAMPLE), path],
        "info --extract-input": ["info", str(recording), "--extract-input", path],
        "compare --save": ["compare", str(SAMPLE), "--filter", "ekf", "--save", path],
        "check --report": ["check", str(SAMPLE), "--filter", "ekf", "--report", path],
        "check --save": ["check", str(SAMPLE), "--filter", "ekf", "--save", path],
        "simulate -o": ["simulate", "-o", path, "--truth-out", str(place / "t.json")],
        "simulate --truth-out": ["simulate", "-o", str(place / "l.txt"), "--truth-out", path],
    }[name]  # fmt: skip


COMMANDS = [
    "replay --save", "replay --report", "sweep --save", "sweep --report",
    "consistency --save", "consistency --report", "convert", "info --extract-input",
    "compare --save", "check --report", "check --save",
    "simulate -o", "simulate --truth-out",
]  # fmt: skip


@pytest.mark.parametrize("command", COMMANDS)
def test_every_unusable_output_path_is_one_line_before_any_work(
    place: Path, command: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(place)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if command.startswith("info"):  # a recording to read the input from
        made = runner.invoke(app, ["replay", str(SAMPLE), "--save", str(place / "made.rrd")])
        assert made.exit_code == 0, made.output
    before = _snapshot(place)
    for case, make, message in PATHS:
        path = make(place)
        result = runner.invoke(app, _command(command, path, place))
        where = f"{command} {case} ({path})"
        assert result.exit_code == 2, f"{where}: {result.output}"
        lines = result.stderr.strip().splitlines()
        assert 1 <= len(lines) <= 3, f"{where}: {result.stderr}"
        assert message in result.stderr and path.rstrip("/") in result.stderr, where
        assert "Traceback" not in result.stderr, where
        assert result.stdout == "", f"{where}: work was done: {result.stdout}"
        assert _snapshot(place) == before, f"{where}: left {_snapshot(place) - before}"
        assert not Path("/ekfviz-no-such-folder").exists()
    assert not [p for p in Path("/proc").iterdir() if p.name.endswith((".part", ".probe"))]


def test_an_output_path_refused_in_a_process_of_its_own(place: Path) -> None:
    """As the user sees it: the whole replay is not run first, no .part is left."""
    started = time.monotonic()
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(SAMPLE), "--save", str(place / "folder")],
        capture_output=True,
        text=True,
        cwd=place,
    )
    assert result.returncode == 2
    assert (
        result.stderr.strip()
        == f"error: --save {place / 'folder'}: is a folder, expected a file name"
    )
    assert not list(place.rglob("*.part")) and time.monotonic() - started < 30


def test_a_dataset_folder_needs_its_parent(place: Path) -> None:
    """``simulate --layout mrclam`` writes a folder: it may exist, its parent must."""
    before = _snapshot(place)
    for path, message in (
        (place / "missing" / "ds", "does not exist"),
        (place / "file.txt", "exists and is not a folder"),
    ):
        result = runner.invoke(app, ["simulate", "--layout", "mrclam", "-o", str(path)])
        assert result.exit_code == 2 and message in result.stderr, result.stderr
        assert _snapshot(place) == before


def test_two_outputs_of_one_command_must_be_two_files(place: Path) -> None:
    same = str(place / "same.json")
    result = runner.invoke(app, ["replay", str(SAMPLE), "--save", same, "--report", same])
    assert result.exit_code == 2 and "are the same file" in result.stderr


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class DeafPort(int):
    """A port number, and the event set once something connected to it."""

    connected: threading.Event


@pytest.fixture
def deaf_listener() -> Iterator[DeafPort]:
    """A port that accepts connections and never answers: no viewer, yet no refusal."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    accepted: list[socket.socket] = []
    stop = threading.Event()
    port = DeafPort(server.getsockname()[1])
    port.connected = threading.Event()

    def accept() -> None:
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                accepted.append(server.accept()[0])
            except OSError:
                continue
            port.connected.set()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    yield port
    stop.set()
    thread.join()
    for connection in accepted:
        connection.close()
    server.close()


def _ekfviz(*args: str, cwd: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "ekfviz", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


@pytest.mark.parametrize("kind", ["closed", "deaf"])
def test_connect_where_no_viewer_answers_is_one_line_and_exit_2(
    tmp_path: Path, kind: str, request: pytest.FixtureRequest
) -> None:
    port = _free_port() if kind == "closed" else request.getfixturevalue("deaf_listener")
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    process = _ekfviz("replay", str(SAMPLE), "--connect", url, cwd=tmp_path)
    _, stderr = process.communicate(timeout=15)  # a generous bound; it takes a few seconds
    assert process.returncode == 2
    assert stderr.strip().splitlines() == [
        f"error: no Rerun viewer at {url} (start one with: rerun; or use --save PATH)"
    ] or (len(stderr.strip().splitlines()) == 1 and f"no Rerun viewer at {url}" in stderr), stderr
    assert list(tmp_path.iterdir()) == []


def test_connect_without_a_viewer_still_saves_and_says_so(tmp_path: Path) -> None:
    url = f"rerun+http://127.0.0.1:{_free_port()}/proxy"
    process = _ekfviz("replay", str(SAMPLE), "--connect", url, "--save", "run.rrd", cwd=tmp_path)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 2
    assert stderr.strip() == f"error: no Rerun viewer at {url}; the recording is saved in run.rrd"
    from ekfviz import readback

    assert readback.read_recording_info(tmp_path / "run.rrd").status.state == "finished"  # type: ignore[union-attr]
    assert not list(tmp_path.glob(".*.part"))


def test_ctrl_c_while_connecting_to_a_deaf_port_ends_the_run_with_130(
    tmp_path: Path, deaf_listener: DeafPort
) -> None:
    """SIGINT while the run waits for the viewer to answer ends it (exit 130): had the
    wait been deaf to it, it would have given up on the viewer (exit 2), or hung in
    Rerun's own client for some 100 s."""
    url = f"rerun+http://127.0.0.1:{deaf_listener}/proxy"
    process = _ekfviz("replay", str(SAMPLE), "--connect", url, cwd=tmp_path)
    assert deaf_listener.connected.wait(60), "the run never tried the port"
    process.send_signal(signal.SIGINT)
    try:
        _, stderr = process.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        pytest.fail("SIGINT did not end the run")
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr


# -- standard output itself -------------------------------------------------------------


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full here")
@pytest.mark.parametrize(
    "args",
    [
        ["replay", str(SAMPLE), "--save", "run.rrd"],
        ["replay", str(SAMPLE), "--save", "run.rrd", "--json"],
        ["replay", "--help"],
        ["--version"],
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


@pytest.mark.parametrize("command", COMMANDS)
def test_an_output_path_that_is_a_symbolic_link_writes_its_target_and_keeps_the_link(
    place: Path, command: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file moved over its path would replace the link itself, wherever it points
    (``--save /dev/stdout`` replaced the system's link with a recording, as root)."""
    monkeypatch.chdir(place)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if command.startswith("info"):
        made = runner.invoke(app, ["replay", str(SAMPLE), "--save", str(place / "made.rrd")])
        assert made.exit_code == 0, made.output
    suffix = ".rrd" if command.endswith("--save") else ".file"  # (a recording is a .rrd)
    elsewhere = place / "folder" / f"out{suffix}"
    link = place / f"link{suffix}"
    link.symlink_to(elsewhere)  # dangling: convert and simulate write no existing file
    result = runner.invoke(app, _command(command, str(link), place))
    assert result.exit_code == 0, result.output
    assert link.is_symlink() and os.readlink(link) == str(elsewhere)
    assert elsewhere.is_file() and elsewhere.stat().st_size > 0
    assert not list(place.glob(".*.part")) and not list((place / "folder").glob(".*"))


def test_a_recording_saved_through_a_link_replaces_the_file_it_points_to(
    tmp_path: Path,
) -> None:
    from ekfviz import readback

    (tmp_path / "runs").mkdir()
    real = tmp_path / "runs" / "run.rrd"
    real.write_bytes(b"an earlier recording")
    link = tmp_path / "latest.rrd"
    link.symlink_to(Path("runs") / "run.rrd")
    result = runner.invoke(app, ["replay", str(SAMPLE), "--save", str(link)])
    assert result.exit_code == 0, result.output
    assert link.is_symlink() and link.resolve() == real.resolve()
    info = readback.read_recording_info(real)
    assert info is not None and info.status is not None and info.status.state == "finished"


@pytest.mark.parametrize(
    ("command", "input_name"),
    [
        (["sweep", "run.txt", "--vary", "sigma_x=x2", "--workers", "1", "--report", "run.txt"],
         "run.txt"),
        (["sweep", "run.txt", "--vary", "sigma_x=x2", "--workers", "1", "--save", "run.txt"],
         "run.txt"),
        (["compare", "run.txt", "--truth", "truth.json", "--filter", "ekf", "--workers", "1",
          "--report", "truth.json"], "truth.json"),
        (["compare", "run.txt", "--filter", "ekf", "--filter", "mine.py", "--workers", "1",
          "--save", "mine.py"], "mine.py"),
        (["consistency", "--runs", "2", "--workers", "1", "--filter", "mine.py", "--report",
          "mine.py"], "mine.py"),
    ],
)  # fmt: skip
def test_a_study_s_output_never_replaces_its_input(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: list[str], input_name: str
) -> None:
    """``replay`` refused it; a sweep, a compare and a consistency study wrote their report
    or recording over the log, the truth or the user's filter, exit 0."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "run.txt").write_text(SAMPLE.read_text())
    (tmp_path / "truth.json").write_text((DATA / "classic_truth.json").read_text())
    (tmp_path / "mine.py").write_text("# a user's filter\n")
    before = (tmp_path / input_name).read_bytes()
    result = runner.invoke(app, command)
    assert result.exit_code == 2, result.output
    assert result.output.strip().endswith(
        f"is the input {input_name}, which writing it would replace: give another file"
    )
    assert (tmp_path / input_name).read_bytes() == before


def _env(cwd: Path) -> dict[str, str]:
    env = {**os.environ, "XDG_CONFIG_HOME": str(cwd), "XDG_DATA_HOME": str(cwd), "CI": "1"}
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    return env


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ekfviz", *args], capture_output=True, text=True, cwd=cwd,
        env=_env(cwd), timeout=120,
    )  # fmt: skip


def test_a_path_too_long_for_its_file_system_is_one_line(tmp_path: Path) -> None:
    """A log name of 256 bytes was a traceback (OSError: File name too long, from a check
    of the path); so was the default recording's name of a 251-byte log's second run."""
    log = "a" * 256 + ".txt"
    done = _cli("replay", log, cwd=tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("error: aaa") and line.endswith("File name too long"), line
    stem = "b" * 251  # the log's name is 255 bytes, its recording's 255, then 257
    (tmp_path / f"{stem}.txt").write_text((DATA / "classic.txt").read_text())
    first = _cli("replay", f"{stem}.txt", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    second = _cli("replay", f"{stem}.txt", cwd=tmp_path)
    assert second.returncode == 2 and "Traceback" not in second.stderr
    (line,) = second.stderr.strip().splitlines()
    assert "cannot save the recording as recordings/bbb" in line and "--save" in line, line


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


@pytest.mark.parametrize(
    "args",
    [
        ["replay", "LOG", "--save", "newdir/"],
        ["replay", "LOG", "--save", "x.rrd", "--report=newdir/"],
        ["simulate", "--output", "sim.txt", "--truth-out", "newdir/"],
    ],
)
def test_an_output_file_named_with_a_trailing_slash_is_refused(
    tmp_path: Path, args: list[str]
) -> None:
    """``--save newdir/`` made a file ``newdir``: the path as typer hands it has lost its
    slash."""
    args = [str(DATA / "classic.txt") if a == "LOG" else a for a in args]
    done = _cli(*args, cwd=tmp_path)
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert line.endswith("newdir/: ends with '/', expected the name of a file"), line
    assert not (tmp_path / "newdir").exists()


def test_an_output_that_is_a_loop_of_symbolic_links_is_refused(tmp_path: Path) -> None:
    """``--save lp1`` with lp1 -> lp2 -> lp1 replaced the link with a file, where the same
    loop as an input is refused."""
    (tmp_path / "lp1").symlink_to("lp2")
    (tmp_path / "lp2").symlink_to("lp1")
    done = _cli("replay", str(DATA / "classic.txt"), "--save", "lp1", cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr == "error: --save lp1: a loop of symbolic links\n"
    assert (tmp_path / "lp1").is_symlink() and os.readlink(tmp_path / "lp1") == "lp2"


@pytest.mark.parametrize("command", [["replay"], ["sweep", "--vary", "sigma_x=x2"]])
def test_a_recording_saved_under_another_suffix_is_refused(
    tmp_path: Path, command: list[str]
) -> None:
    """``--save out.png`` wrote a recording named ``.png``: one line, nothing written."""
    target = tmp_path / "out.png"
    result = runner.invoke(app, [*command, str(DATA / "classic.txt"), "--save", str(target)])
    assert result.exit_code == 2, result.output
    assert result.output.strip().splitlines() == [
        f"error: --save {target}: a recording is a .rrd file (expected a name ending in .rrd,"
        " such as out.rrd)"
    ]
    assert not target.exists()


def test_replay_says_where_it_saved_and_how_to_open_it(tmp_path: Path) -> None:
    target = tmp_path / "run.rrd"
    result = runner.invoke(app, ["replay", str(DATA / "classic.txt"), "--save", str(target)])
    assert result.exit_code == 0, result.output
    last = result.output.strip().splitlines()[-1]
    assert last.startswith(f"Saved {target}; open it with: ") and last.endswith(str(target))
