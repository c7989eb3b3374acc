"""Inputs nobody planned for: each found by attacking the command line, each once a fault.

Every one must end in one line on stderr naming the file (and line) and what was
expected, exit code 2, no traceback, no hang, and nothing already saved lost; good input
next to it must keep working.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.errors import InputError
from ekfviz.io.extended import read_extended
from ekfviz.io.files import OutputPathError, check_output_path, distinct_paths
from ekfviz.io.text import numeric_blocks, numeric_lines, open_input

runner = CliRunner()
OBS = "0.1 5.0 0.2 6.0"
CLASSIC = f"{OBS}\n3 0\n{OBS}\n3 0\n{OBS}\n"
DATA = Path(__file__).resolve().parents[2] / "data"


def ekfviz(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ekfviz", *args], capture_output=True, text=True, timeout=timeout
    )


def one_error_line(output: str, expected: str) -> str:
    """The only line of ``output``, an error holding ``expected``."""
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    assert lines[0].startswith("error: ") and expected in lines[0], lines[0]
    assert "Traceback" not in output
    return lines[0]


# -- an output that is an input --------------------------------------------------------


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


# -- output paths the file system refuses -------------------------------------------------


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
    result = ekfviz("replay", str(log), "--save", target)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""  # Rerun warned twice on the command line it was given
    assert Path(target).stat().st_size > 0


# -- inputs that are not regular files ------------------------------------------------------


def test_a_fifo_is_refused_at_once_not_waited_on(tmp_path: Path) -> None:
    fifo = tmp_path / "log.txt"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="is a FIFO"):
        open_input(fifo)
    for args in (
        ["replay", str(fifo)],
        ["replay", str(DATA / "classic.txt"), "--truth", str(fifo)],
    ):
        result = ekfviz(*args, "--save", str(tmp_path / "r.rrd"), timeout=30)
        assert result.returncode == 2
        one_error_line(result.stderr, f"{fifo}: is a FIFO (named pipe), not a regular file")


def test_a_device_is_refused() -> None:
    with pytest.raises(InputError, match="/dev/zero: is a device"):
        open_input(Path("/dev/zero"))


# -- numbers and times ----------------------------------------------------------------------


@pytest.mark.parametrize("token", ["\u0661", "\uff11", "1_000", "\u0661.5"])
def test_digits_of_other_scripts_and_underscores_are_no_numbers(tmp_path: Path, token: str) -> None:
    """float() takes them; a log's reader must not (the classic reader, the extended one's
    ids and numbers, and the blocks of a dataset's files)."""
    classic = tmp_path / "log.txt"
    classic.write_text(f"{token} 5 0.2 6\n3 0\n")
    with pytest.raises(InputError, match="expected a decimal number"):
        list(numeric_lines(classic))
    extended = tmp_path / "ext.txt"
    extended.write_text(f"observe {token} 0.1 5\n")
    with pytest.raises(InputError, match="expected an integer >= 0"):
        list(read_extended(extended))
    table = tmp_path / "table.dat"
    table.write_text("1.0 2.0 3.0\n" * 5 + f"2.0 {token} 3.0\n")
    with pytest.raises(InputError, match=r":6: found .*expected a decimal number"):
        list(numeric_blocks(table, 3, "time v omega"))


@pytest.mark.parametrize("time", ["1e10", "-9.3e9", "2e11", "1e18"])
def test_a_time_a_recording_cannot_hold_is_refused_on_its_line(tmp_path: Path, time: str) -> None:
    """Rerun's timeline counts nanoseconds in 64 bits: such a time overflowed (a
    traceback) once the run was recorded."""
    log = tmp_path / "log.txt"
    log.write_text(f"1.0 observe 1 0.1 5 2 0.2 6\n{time} control 1 0\n")
    result = runner.invoke(app, ["replay", str(log), "--save", str(tmp_path / "r.rrd")])
    assert result.exit_code == 2
    one_error_line(result.output, f"{log}:2: found time {float(time):g}, expected seconds within")


def test_a_time_at_the_edge_of_the_timeline_is_recorded(tmp_path: Path) -> None:
    from ekfviz.io.text import MAX_TIME_S

    log = tmp_path / "log.txt"
    log.write_text(f"{MAX_TIME_S} observe 1 0.1 5 2 0.2 6\n{MAX_TIME_S} control 1 0\n")
    result = runner.invoke(app, ["replay", str(log), "--save", str(tmp_path / "r.rrd")])
    assert result.exit_code == 0, result.output


def test_datasets_refuse_such_times_naming_file_and_line(tmp_path: Path) -> None:
    from ekfviz.sim.mrclam import MrclamWorld, simulate_mrclam

    mrclam = tmp_path / "mrclam"
    mrclam.mkdir()
    for name, text in simulate_mrclam(world=MrclamWorld(duration_s=3.0)).items():
        (mrclam / name).write_text(text)
    odometry = mrclam / "Robot1_Odometry.dat"
    odometry.write_text(odometry.read_text() + "1e12 0.1 0.1\n")
    lines = len(odometry.read_text().splitlines())
    result = runner.invoke(app, ["replay", str(mrclam), "--no-truth",
                                 "--save", str(tmp_path / "m.rrd")])  # fmt: skip
    assert result.exit_code == 2
    assert f"{odometry}:{lines}: found time 1e+12" in result.output
    park = tmp_path / "park"
    park.mkdir()
    (park / "inputs.dat").write_text("1000.0 3 0\n1000.1 3 0\n2e10 3 0\n")
    (park / "measurements.dat").write_text("1000.05 10 1.5 0.3\n")
    result = runner.invoke(app, ["replay", str(park), "--save", str(tmp_path / "p.rrd")])
    assert result.exit_code == 2
    assert f"{park / 'inputs.dat'}:3: found time 2e+10" in result.output


# -- a user's filter -------------------------------------------------------------------------

TEXTBOOK = Path(__file__).parents[1] / "plugins" / "textbook.py"


def _plugin(tmp_path: Path, body: str) -> str:
    """A filter class ``Evil`` (the textbook filter with ``body`` added); its --filter."""
    module = tmp_path / "evil.py"
    module.write_text(TEXTBOOK.read_text() + "\n\n" + textwrap.dedent(body))
    return f"{module}:Evil"


def _replay_with(tmp_path: Path, spec: str, *extra: str) -> subprocess.CompletedProcess[str]:
    return ekfviz("replay", str(DATA / "classic.txt"), "--filter", spec,
                  "--save", str(tmp_path / "r.rrd"), *extra)  # fmt: skip


def test_a_filters_multi_line_or_huge_message_is_one_line(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        class Evil(Textbook):
            def __init__(self, params):
                raise ValueError("first\\nsecond\\r\\nthird" + "z" * 100_000)
    """,
    )
    result = _replay_with(tmp_path, spec)
    assert result.returncode == 2
    # its lines joined by spaces, its length cut (the whole of it with --debug)
    line = one_error_line(result.stderr, "construction raised ValueError: first second third")
    assert len(line) < 2_000 and "(100019 characters in all)" in line


def test_what_a_failing_filter_printed_comes_before_the_error(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import sys

        class Evil(Textbook):
            def predict(self, d, alpha):
                sys.stdout.write("a prompt with no line end")
                raise RuntimeError("no")
    """,
    )
    result = _replay_with(tmp_path, spec)
    assert result.returncode == 2
    lines = result.stderr.splitlines()
    assert lines[-1].startswith("error: ") and "predict raised RuntimeError: no" in lines[-1]
    assert any("a prompt with no line end" in line for line in lines[:-1]), result.stderr


def test_a_filter_signalling_its_parent_does_not_stop_ekfviz(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import os, signal

        class Evil(Textbook):
            def predict(self, d, alpha):
                os.kill(os.getppid(), signal.SIGTERM)
                os.kill(os.getppid(), signal.SIGINT)
                super().predict(d, alpha)
    """,
    )
    result = _replay_with(tmp_path, spec)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "r.rrd").stat().st_size > 0


def test_a_filter_killing_itself_is_said_as_such(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import os, signal

        class Evil(Textbook):
            def predict(self, d, alpha):
                os.kill(os.getpid(), signal.SIGKILL)
    """,
    )
    result = _replay_with(tmp_path, spec)
    assert result.returncode == 2
    one_error_line(result.stderr, "the filter's process was killed by SIGKILL during predict")


def test_a_process_the_filter_forked_does_not_hold_the_command(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import os, time

        class Evil(Textbook):
            def predict(self, d, alpha):
                if not getattr(self, "forked", False):
                    self.forked = True
                    if os.fork() == 0:
                        time.sleep(60)
                        os._exit(0)
                super().predict(d, alpha)
    """,
    )
    result = ekfviz("replay", str(DATA / "classic.txt"), "--filter", spec, "--save",
                    str(tmp_path / "r.rrd"), "--no-sandbox", timeout=30)  # fmt: skip
    assert result.returncode == 0, result.stderr
    # in the sandbox a filter starts no process at all: its fork is the filter's error
    result = ekfviz("replay", str(DATA / "classic.txt"), "--filter", spec,
                    "--save", str(tmp_path / "r.rrd"), timeout=30)  # fmt: skip
    assert result.returncode == 2
    one_error_line(result.stderr, "predict raised PermissionError: [Errno 1] Operation not")


@pytest.mark.parametrize("where", ["import", "construction"])
def test_a_loop_at_import_or_construction_is_bounded_by_the_filter_timeout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    """Once bounded only by the 120 s of a worker's start, whatever --filter-timeout said."""
    from ekfviz.core.params import FilterParams
    from ekfviz.sandbox import host as worker
    from ekfviz.sandbox.host import WorkerFault, WorkerOptions
    from ekfviz.sandbox.remote import Target, WorkerFactory

    monkeypatch.setattr(worker, "MIN_LOAD_TIMEOUT_S", 0.5)
    module = tmp_path / "slow.py"
    loop = "while True:\n    pass\n"
    if where == "import":
        module.write_text(loop + "class Slow:\n    pass\n")
    else:
        module.write_text(
            "class Slow:\n    def __init__(self, params):\n" + textwrap.indent(loop, "        ")
        )
    options = WorkerOptions(timeout_s=0.2, echo=False)
    with pytest.raises(WorkerFault, match=f"{where} did not return within 0.5 s") as raised:
        factory = WorkerFactory(Target(str(module), None, "Slow"), options, "filter slow.py")
        try:
            factory(FilterParams())
        finally:
            factory.close()
    assert raised.value.kind == "timeout"
    assert np.isclose(worker.load_timeout(WorkerOptions(timeout_s=30.0)), 30.0)


def test_filter_timeout_nan_is_refused_and_inf_is_no_bound(tmp_path: Path) -> None:
    spec = f"{TEXTBOOK}:Textbook"
    result = _replay_with(tmp_path, spec, "--filter-timeout", "nan")
    assert result.returncode == 2
    one_error_line(result.stderr, "--filter-timeout nan: expected a number of seconds")
    result = _replay_with(tmp_path, spec, "--filter-timeout", "inf", "--filter-memory", "10" * 9)
    assert result.returncode == 0, result.stderr  # (select() overflowed; setrlimit too)
    assert result.stderr == ""


@pytest.mark.parametrize("program", ["cat", "yes"])
def test_an_interpreter_that_is_no_python_is_one_line_at_once(tmp_path: Path, program: str) -> None:
    """``yes`` answered four bytes read as a length of 2 GB, which ekfviz allocated
    and then failed on as JSON (a traceback)."""
    import shutil

    found = shutil.which(program)
    if found is None:
        pytest.skip(f"no {program} here")
    result = _replay_with(tmp_path, f"{TEXTBOOK}:Textbook", "--python", found)
    assert result.returncode == 2
    # (cat may first say that it has no file '{}', yes answers at once)
    one_error_line(result.stderr, "the filter's worker did not start")


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


# -- a disk that fills up while a recording is written -----------------------------------------


def _limited(size: int) -> None:  # (in the child, before exec)
    import resource
    import signal

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail (EFBIG)
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))


def test_a_recording_that_cannot_be_written_whole_replaces_nothing(tmp_path: Path) -> None:
    """Rerun's file writer stops; its flush raised, which was taken for a viewer that did
    not answer: the truncated file then replaced the finished one at --save."""
    target = tmp_path / "run.rrd"
    target.write_bytes(b"an earlier finished recording")
    command = [sys.executable, "-m", "ekfviz", "replay", str(DATA / "classic.txt")]
    result = subprocess.run(
        [*command, "--save", str(target)], capture_output=True, text=True, timeout=60,
        preexec_fn=lambda: _limited(100_000),
    )  # fmt: skip
    assert result.returncode == 2
    one_error_line(result.stderr, f"--save {target}: the recording could not be written whole")
    assert target.read_bytes() == b"an earlier finished recording"
    assert [p.name for p in tmp_path.iterdir()] == ["run.rrd"]  # no temporary file left


def test_a_full_disk_stops_a_flush_at_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A flush whose file's disk is full stops waiting (Rerun's would wait out its timeout
    for a writer that has stopped)."""
    import threading

    from ekfviz.viz import flush

    class Stuck:
        def flush(self, timeout_sec: float) -> None:
            threading.Event().wait(timeout_sec)

    stuck = Stuck()
    monkeypatch.setattr(flush, "_FILES", {stuck: tmp_path / "x.rrd"})
    monkeypatch.setattr(flush, "disk_full", lambda path: True)
    with pytest.raises(flush.DiskFull, match="no space left"):
        flush.flush_interruptibly(stuck, 30.0)  # type: ignore[arg-type]


def test_a_writer_is_taken_for_stopped_only_where_it_was_seen_running(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A flush stops at once when the stream's file writer, seen running, is gone; where
    it was never seen (another version of Rerun naming its thread otherwise) its absence
    says nothing, and the flush waits as Rerun's does."""
    import threading
    import weakref

    from ekfviz.viz import flush

    class Stuck:
        def flush(self, timeout_sec: float) -> None:
            threading.Event().wait(timeout_sec)

    stuck = Stuck()
    monkeypatch.setattr(flush, "_FILES", {stuck: tmp_path / "x.rrd"})
    monkeypatch.setattr(flush, "_WRITERS", weakref.WeakSet())
    monkeypatch.setattr(flush, "disk_full", lambda path: False)
    monkeypatch.setattr(flush, "writer_running", lambda: False)
    flush.note_writer(stuck)  # type: ignore[arg-type]  # not running: not seen
    flush.flush_interruptibly(stuck, 0.8)  # type: ignore[arg-type]  # waited out, no error
    monkeypatch.setattr(flush, "writer_running", lambda: True)
    flush.note_writer(stuck)  # type: ignore[arg-type]
    monkeypatch.setattr(flush, "writer_running", lambda: False)
    with pytest.raises(flush.DiskFull, match="file writer stopped"):
        flush.flush_interruptibly(stuck, 30.0)  # type: ignore[arg-type]


def test_a_file_written_whole_or_not_at_all_on_a_full_disk(tmp_path: Path) -> None:
    """convert, --report, export: their files are written beside and renamed; a write
    that fails (here past a file-size limit) was a traceback."""
    target = tmp_path / "ext.txt"
    target.write_text("an earlier file\n")
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "convert", str(DATA / "classic.txt"), str(target),
         "--force"],
        capture_output=True, text=True, timeout=60, preexec_fn=lambda: _limited(1_000),
    )  # fmt: skip
    assert result.returncode == 2
    one_error_line(result.stderr, f"{target}: cannot write (File too large); nothing was replaced")
    assert target.read_text() == "an earlier file\n"
    assert [p.name for p in tmp_path.iterdir()] == ["ext.txt"]


def test_a_landmark_surveyed_twice_is_refused(tmp_path: Path) -> None:
    """Two true positions for one MRCLAM subject: the second silently won."""
    from ekfviz.io.mrclam import read_landmark_truth

    truth = tmp_path / "Landmark_Groundtruth.dat"
    truth.write_text("# Subject x y sx sy\n6 1.0 2.0 0 0\n7 3.0 -1.0 0 0\n6 5.0 5.0 0 0\n")
    with pytest.raises(InputError, match=r":4: found subject 6 twice, expected each landmark once"):
        read_landmark_truth(truth)


def test_a_submission_named_with_a_line_break_keeps_its_row_one_line() -> None:
    """grade's table: a file named with a line break split its row over two lines."""
    from ekfviz.app.grade_rows import GradeRow

    row = GradeRow("alice\nbob.py", "error", (), "", 0.1, detail="it raised")
    name = row.cells()[0].text
    assert name == "alice\\nbob.py" and "\n" not in "".join(c.text for c in row.cells())


# -- a map larger than the memory ----------------------------------------------------------


def _first_line_of(landmarks: int, path: Path) -> Path:
    """A classic log whose first line sees ``landmarks`` landmarks (11 bytes each)."""
    line = " ".join(["0.1 5.0"] * landmarks)
    path.write_text(f"{line}\n1 0.1\n{line}\n")
    return path


def test_a_map_whose_covariance_cannot_fit_is_one_line_at_once(tmp_path: Path) -> None:
    """40,000 landmarks on a first line (640 KB of log) ask for a 51 GB covariance: the
    replay says so and stops, instead of filling memory it was lazily granted."""
    log = _first_line_of(40_000, tmp_path / "wide.txt")
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(log), "--save", str(tmp_path / "r.rrd")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert result.stderr.startswith(
        f"error: {log}:1: 40000 landmarks make the covariance 80003 x 80003 (51.2 GB)"
    )
    assert "of memory available" in result.stderr and not (tmp_path / "r.rrd").exists()


def test_the_memory_bound_follows_what_is_available(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A map of 3000 landmarks (a 288 MB covariance) is refused with 1 GB free, fits in 8."""
    from ekfviz.core.errors import FilterError
    from ekfviz.filters import ekf

    log = _first_line_of(3000, tmp_path / "wide.txt")  # P: 6003^2 doubles, 288 MB
    monkeypatch.setattr(ekf, "available_memory", lambda: 1 << 30)
    refused = runner.invoke(app, ["replay", str(log), "--save", str(tmp_path / "a.rrd")])
    assert refused.exit_code == 2
    assert "3000 landmarks make the covariance 6003 x 6003 (0.3 GB)" in refused.stderr
    assert "more than the 1.1 GB of memory available" in refused.stderr
    monkeypatch.setattr(ekf, "available_memory", lambda: 8 << 30)
    with pytest.raises(FilterError):
        ekf.room_for(3 + 2 * 8000)  # 1 GB: more than a sixth of 8 GB
    ekf.room_for(3 + 2 * 3000)  # 288 MB: fits


def test_available_memory_is_a_positive_number_of_bytes_here() -> None:
    from ekfviz.core.memory import available_memory

    available = available_memory()
    if not Path("/proc/meminfo").exists():
        pytest.skip("no /proc/meminfo")
    assert available is not None and 0 < available < 1 << 50
