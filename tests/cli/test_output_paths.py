"""Every way a user can give an unusable output path, for every command that writes one
(an output that is an input among them), and a ``--connect`` to where no viewer answers:
one line, exit 2, nothing left behind, nothing of the user's replaced.

Script-style: the matrix below is tried in turn. Paths are checked in-process (they are
refused before any work, so a real process would show nothing more); the ``--connect``
cases run ``python -m ekfviz`` in a process of its own, whose timeout tells a run that
waits for ever.
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
from commands import one_error_line, run_ekfviz, run_ekfviz_process
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.io.files import OutputPathError, check_output_path, distinct_paths

DATA = Path(__file__).parents[2] / "data"
SAMPLE = DATA / "classic.txt"
OBS = "0.1 5.0 0.2 6.0"
CLASSIC = f"{OBS}\n3 0\n{OBS}\n3 0\n{OBS}\n"
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
# the commands tried by default (one of each way of writing: a recording, a report, a
# converted log, an extracted input, a dataset); every one under -m slow
COMMANDS_BY_DEFAULT = {"replay --save", "sweep --report", "convert", "info --extract-input",
                       "simulate --truth-out"}  # fmt: skip
LINKS_BY_DEFAULT = {"replay --save", "consistency --report", "convert", "simulate -o"}


def _by_default(kept: set[str]) -> list[object]:
    """Every command, those not in ``kept`` marked slow."""
    return [c if c in kept else pytest.param(c, marks=pytest.mark.slow) for c in COMMANDS]


@pytest.mark.parametrize("command", _by_default(COMMANDS_BY_DEFAULT))
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


def test_an_output_path_is_refused_before_the_replay_runs(place: Path) -> None:
    """As the user sees it: the whole replay is not run first, no .part is left."""
    started = time.monotonic()
    result = run_ekfviz("replay", SAMPLE, "--save", place / "folder", cwd=place)
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
    """``python -m ekfviz ARGS`` started in a process of its own, its output piped."""
    return subprocess.Popen(
        [sys.executable, "-m", "ekfviz", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


@pytest.mark.parametrize("kind", ["closed", pytest.param("deaf", marks=pytest.mark.slow)])
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


@pytest.mark.parametrize("command", _by_default(LINKS_BY_DEFAULT))
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


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``ekfviz ARGS`` in ``cwd`` without a display (a replay without --save saves)."""
    return run_ekfviz(*args, cwd=cwd, env={"DISPLAY": None, "WAYLAND_DISPLAY": None})


def _env(cwd: Path) -> dict[str, str]:
    env = {**os.environ, "XDG_CONFIG_HOME": str(cwd), "XDG_DATA_HOME": str(cwd), "CI": "1"}
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    return env


@pytest.mark.slow
def test_a_path_too_long_for_its_file_system_is_one_line(tmp_path: Path) -> None:
    """A log name of 256 bytes was a traceback (OSError: File name too long, from a check
    of the path); so was the default recording's name of a 251-byte log's second run.

    In a process of its own: such an error reaches the command line's last resort, in
    ``main()``, for a path no command's own checks named."""
    log = "a" * 256 + ".txt"
    done = run_ekfviz_process("replay", log, cwd=tmp_path, env=_env(tmp_path), timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("error: aaa") and line.endswith("File name too long"), line
    stem = "b" * 251  # the log's name is 255 bytes, its recording's 255, then 257
    (tmp_path / f"{stem}.txt").write_text((DATA / "classic.txt").read_text())
    first = _cli("replay", f"{stem}.txt", cwd=tmp_path)  # (its recording: the first name)
    assert first.returncode == 0, first.stderr
    second = run_ekfviz_process("replay", f"{stem}.txt", cwd=tmp_path, env=_env(tmp_path))
    assert second.returncode == 2 and "Traceback" not in second.stderr
    (line,) = second.stderr.strip().splitlines()
    assert "cannot save the recording as recordings/bbb" in line and "--save" in line, line


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


# -- an output that is an input ------------------------------------------------------------


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


def test_save_over_the_input_log_is_refused_and_the_log_kept(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    result = runner.invoke(app, ["replay", str(log), "--save", str(log)])
    assert result.exit_code == 2
    one_error_line(result.output, f"--save {log}: is the input {log}")
    assert log.read_text() == CLASSIC


def test_a_hard_link_or_a_symbolic_link_to_the_input_is_the_input(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    hard, soft = tmp_path / "hard.rrd", tmp_path / "soft.rrd"
    os.link(log, hard)
    soft.symlink_to(log)
    for output in (hard, soft):
        result = runner.invoke(app, ["replay", str(log), "--save", str(output)])
        assert result.exit_code == 2
        one_error_line(result.output, "is the input")
    assert log.read_text() == CLASSIC


def test_report_over_the_truth_or_the_log_is_refused(tmp_path: Path) -> None:
    log, truth = tmp_path / "log.txt", tmp_path / "truth.txt"
    log.write_text(CLASSIC)
    truth.write_text("3 6\n3 12\n")
    for report in (log, truth):
        result = runner.invoke(app, ["replay", str(log), "--truth", str(truth), "--save",
                                     str(tmp_path / "r.rrd"), "--report", str(report)])  # fmt: skip
        assert result.exit_code == 2
        one_error_line(result.output, f"--report {report}: is the input")
    assert log.read_text() == CLASSIC and truth.read_text() == "3 6\n3 12\n"


def test_a_dataset_directorys_file_is_not_written_over(tmp_path: Path) -> None:
    from ekfviz.sim.mrclam import MrclamWorld, simulate_mrclam

    for name, text in simulate_mrclam(world=MrclamWorld(duration_s=3.0)).items():
        (tmp_path / name).write_text(text)
    odometry = tmp_path / "Robot1_Odometry.dat"
    before = odometry.read_bytes()
    result = runner.invoke(app, ["replay", str(tmp_path), "--save", str(odometry)])
    assert result.exit_code == 2
    assert f"--save {odometry}: " in result.output  # (refused: not a .rrd, and the input)
    assert odometry.read_bytes() == before
    ran = runner.invoke(app, ["replay", str(tmp_path), "--save", str(tmp_path / "x.rrd")])
    assert ran.exit_code == 0, ran.output  # the same directory, saved elsewhere


def test_info_and_export_do_not_write_over_the_recording(tmp_path: Path) -> None:
    rrd = tmp_path / "run.rrd"
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    assert runner.invoke(app, ["replay", str(log), "--save", str(rrd)]).exit_code == 0
    before = rrd.read_bytes()
    for args in (["info", str(rrd), "--extract-input", str(rrd)],
                 ["export", str(rrd), "--tum", str(rrd)]):  # fmt: skip
        result = runner.invoke(app, args)
        assert result.exit_code == 2
        one_error_line(result.output, f"{rrd}: is the input {rrd}")
    assert rrd.read_bytes() == before


def test_export_refuses_a_device_and_two_options_naming_one_file(tmp_path: Path) -> None:
    """/dev/full is refused before anything is written (a root user's export would
    otherwise have replaced the device with a regular file)."""
    rrd = tmp_path / "run.rrd"
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    assert runner.invoke(app, ["replay", str(log), "--save", str(rrd)]).exit_code == 0
    result = runner.invoke(app, ["export", str(rrd), "--tum", "/dev/full"])
    assert result.exit_code == 2
    one_error_line(result.output, "--tum /dev/full: exists and is not a regular file")
    twice = tmp_path / "t.txt"
    result = runner.invoke(app, ["export", str(rrd), "--tum", str(twice), "--csv", str(twice)])
    assert result.exit_code == 2
    one_error_line(result.output, "--tum and --csv are the same file")
    assert not twice.exists()


def test_check_does_not_write_over_its_log_or_the_filters_module(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    module = tmp_path / "mine.py"
    module.write_text("x = 1\n")
    for option, path in (("--report", log), ("--save", module)):
        result = runner.invoke(app, ["check", "--filter", str(module), str(log), option, str(path)])
        assert result.exit_code == 2
        one_error_line(result.output, f"{option} {path}: is the input")
    assert log.read_text() == CLASSIC and module.read_text() == "x = 1\n"


def test_grade_does_not_write_its_report_over_a_submission(tmp_path: Path) -> None:
    folder = tmp_path / "class"
    folder.mkdir()
    submission = folder / "alice.py"
    submission.write_text("x = 1\n")
    (folder / "loop.py").symlink_to("loop.py")  # a loop of links: a row, not a traceback
    result = runner.invoke(app, ["grade", str(folder), "--report", str(submission)])
    assert result.exit_code == 2
    one_error_line(result.output, f"--report {submission}: is the input")
    assert submission.read_text() == "x = 1\n"
    result = runner.invoke(app, ["grade", str(folder), "--timeout", "nan"])
    assert result.exit_code == 2  # (a ranged option refuses NaN as every one does)
    one_error_line(result.output, "'--timeout': found nan, expected a number")


# -- output paths the file system refuses --------------------------------------------------


def test_a_file_name_too_long_is_one_line_before_any_work(tmp_path: Path) -> None:
    too_long = tmp_path / ("a" * 300 + ".rrd")
    with pytest.raises(OutputPathError, match="the file name is 304 bytes long, expected at most"):
        check_output_path(too_long, "--save")
    deep = tmp_path.joinpath(*["d" * 200] * 30, "x.rrd")  # past PATH_MAX
    with pytest.raises(OutputPathError, match="--save"):
        check_output_path(deep, "--save")
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    result = runner.invoke(app, ["replay", str(log), "--save", str(too_long)])
    assert result.exit_code == 2
    one_error_line(result.output, "bytes long")


def test_a_name_near_the_limit_is_saved_whole(tmp_path: Path) -> None:
    """Its temporary file beside it (its name and more) must fit too."""
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    target = tmp_path / ("b" * 250 + ".rrd")
    result = runner.invoke(app, ["replay", str(log), "--save", str(target), "--report",
                                 str(tmp_path / ("c" * 250 + ".json"))])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert target.stat().st_size > 0 and (tmp_path / ("c" * 250 + ".json")).is_file()
    assert sorted(p.name[:1] for p in tmp_path.iterdir()) == ["b", "c", "l"]  # no leftovers


def test_a_loop_of_links_as_an_output_or_a_source_is_no_traceback(tmp_path: Path) -> None:
    loop = tmp_path / "loop.rrd"
    loop.symlink_to(loop.name)
    assert distinct_paths({"--save": loop, "--report": tmp_path / "r.json"}) is None
    result = runner.invoke(app, ["convert", str(loop), str(tmp_path / "x.txt")])
    assert result.exit_code == 2
    one_error_line(result.output, f"{loop}: cannot be read")
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    report = tmp_path / "report.json"
    report.symlink_to(report.name)  # refused, as the same loop as an input is: the link kept
    args = ["replay", str(log), "--save", str(tmp_path / "r.rrd"), "--report", str(report)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    one_error_line(result.output, f"--report {report}: a loop of symbolic links")
    assert report.is_symlink() and not (tmp_path / "r.rrd").exists()


def test_a_name_that_is_not_utf8_is_saved_without_a_warning(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text(CLASSIC)
    target = os.fsdecode(os.fsencode(tmp_path) + b"/\xff\xfe.rrd")
    # Rerun's own log lines go to the standard error of the process, which only a process
    # of its own shows
    result = run_ekfviz_process("replay", log, "--save", target, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""  # Rerun warned twice on the command line it was given
    assert Path(target).stat().st_size > 0
