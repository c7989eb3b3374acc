"""``ekfviz watch``: a filter checked again at every save, each run a recording of its own.

The watch runs as a process (what it does is about the process: saves from outside it,
Ctrl-C, the workers it leaves); every wait is on the report's ``run`` counter, or on a
line it prints, never a fixed sleep.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import students
from conftest import entity_rows, rrd_verify
from typer.testing import CliRunner

from ekfviz.app.watch.checking import placed
from ekfviz.app.watch.files import Watcher, absolute, filter_files
from ekfviz.cli import app

ROOT = Path(__file__).resolve().parents[2]
SKELETON = ROOT / "examples" / "course_skeleton" / "ekf_slam.py"
MY_FILTER = ROOT / "examples" / "my_filter.py"
CLASSIC = ROOT / "data" / "classic.txt"
NUMPY1 = Path(os.environ.get("EKFVIZ_NUMPY1_PYTHON", ROOT / ".venv-numpy1" / "bin" / "python"))
# a wait for the watch's next run or line: a loaded machine takes seconds to start one;
# a watch that never gets there fails the test here instead of hanging it
WAIT_S = 180.0
# Ctrl-C ends a watch in well under a second (make bench measures it); this bound only
# tells an end from a hang on a loaded machine
EXIT_BOUND_S = 10.0
ROTATED, UNROTATED = "P[:3, :3] += W @ control_cov @ W.T", "P[:3, :3] += control_cov"
GHOST = "/filters/ekf_slam/world/previous/trajectory"
runner = CliRunner()


def _alive(pid: int) -> bool:
    """Whether a process exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def _command(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return "?"


def _descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (Linux: their parents read from /proc)."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        parents[int(stat.parent.name)] = int(fields[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


class Watching:
    """``ekfviz watch ARGS`` as a process in ``folder``, its output in files there."""

    def __init__(self, folder: Path, *args: str, report: str = "latest.json") -> None:
        self.folder = folder
        self.report = folder / report
        self.out, self.err = folder / "watch.out", folder / "watch.err"
        env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
        with self.out.open("w") as out, self.err.open("w") as err:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "ekfviz", *args], cwd=folder, stdout=out, stderr=err,
                env=env, start_new_session=True,
            )  # fmt: skip

    def _said(self) -> str:
        return f"stdout:\n{self.out.read_text()}\nstderr:\n{self.err.read_text()}"

    def wait_for(self, done: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + WAIT_S
        while not done():
            assert self.process.poll() is None, f"the watch ended before {what}\n{self._said()}"
            assert time.monotonic() < deadline, f"no {what} within {WAIT_S:g} s\n{self._said()}"
            time.sleep(0.02)

    def run(self, number: int) -> dict[str, object]:
        """The report once it is run ``number``'s (the watch's handshake)."""

        def reported() -> int:
            try:
                return int(json.loads(self.report.read_text())["run"])
            except (OSError, ValueError, KeyError):
                return 0

        self.wait_for(lambda: reported() >= number, f"run {number}")
        report: dict[str, object] = json.loads(self.report.read_text())
        assert report["run"] == number, f"run {report['run']} came, not {number}"
        return report

    def printed(self, text: str) -> None:
        self.wait_for(lambda: text in self.out.read_text(), repr(text))

    def echoed(self, text: str, count: int = 1) -> None:
        """Wait until the filter's output echoed on stderr holds ``text`` ``count`` times."""
        self.wait_for(lambda: self.err.read_text().count(text) >= count, repr(text))

    def stop(self) -> tuple[int, float, str]:
        """Ctrl-C (to the process group, as a terminal sends it): the exit code, how long
        the exit took, what it printed; every process it started is gone."""
        self.wait_for(lambda: bool(_descendants(self.process.pid)), "the next run's worker")
        started = _descendants(self.process.pid)
        sent = time.monotonic()
        os.killpg(self.process.pid, signal.SIGINT)
        code = self.process.wait(timeout=60)
        took = time.monotonic() - sent
        left = {pid: _command(pid) for pid in sorted(started) if _alive(pid)}
        assert not left, f"processes left behind: {left}"
        return code, took, self.out.read_text()

    def kill(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _labels(rows: list[dict[str, object]]) -> list[object]:
    return [value for row in rows for key, value in row.items() if key.endswith(":labels")]


def _log_text(path: Path) -> str:
    rows = entity_rows(path, "/log/watch")
    return "\n".join(str(v) for row in rows for k, v in row.items() if k.endswith(":text"))


@pytest.fixture
def skeleton(tmp_path: Path) -> Iterator[tuple[Path, Path]]:
    """The course skeleton and the classic log, copied into a folder of their own."""
    module, log = tmp_path / "ekf_slam.py", tmp_path / "classic.txt"
    shutil.copy(SKELETON, module)
    shutil.copy(CLASSIC, log)
    yield module, log


def test_a_mistake_a_syntax_error_and_the_fix_each_show_in_the_newest_run(
    skeleton: tuple[Path, Path],
) -> None:
    module, log = skeleton
    folder = module.parent
    latest = folder / "latest.rrd"
    watching = Watching(folder, "watch", module.name, log.name, "--save", latest.name,
                        "--report", "latest.json")  # fmt: skip
    try:
        first = watching.run(1)
        assert first["match"] is True and first["files"] == [] and first["error"] is None
        assert not entity_rows(latest, GHOST, static=True)  # nothing before the first run

        _edit(module, ROTATED, UNROTATED)  # a real mistake: Q added unrotated
        mistake = watching.run(2)
        assert mistake["match"] is False and mistake["causes"] == ["noise_jacobian.missing"]
        assert mistake["files"] == [str(absolute(module))]
        assert _labels(entity_rows(latest, GHOST, static=True)) == [["run 1"]]
        assert "cause: noise_jacobian.missing" in _log_text(latest)
        assert entity_rows(latest, "/filters/ekf_slam/world/divergence", static=True)
        kept = _digest(latest)

        lines = module.read_text().splitlines()
        line = next(k for k, text in enumerate(lines, 1) if UNROTATED in text)
        _edit(module, UNROTATED, f"{UNROTATED})")  # a syntax error on that line
        broken = watching.run(3)
        error = broken["error"]
        assert isinstance(error, dict)
        assert error["file"] == str(absolute(module)) and error["line"] == line
        assert "SyntaxError" in str(error["message"]) and broken["match"] is False
        assert _digest(latest) == kept  # the last good recording stays

        _edit(module, f"{UNROTATED})", ROTATED)  # the fix
        fixed = watching.run(4)
        assert fixed["match"] is True and fixed["error"] is None
        assert _digest(latest) != kept
        # the ghost is the last run that drew a map: run 3 drew none
        assert _labels(entity_rows(latest, GHOST, static=True)) == [["run 2"]]
        assert "match: all" in _log_text(latest)
        rrd_verify(latest)  # whole, its footer written

        code, took, printed = watching.stop()
    finally:
        watching.kill()
    assert code == 130 and took < EXIT_BOUND_S
    assert "Stopped (SIGINT) after 4 run(s)" in printed
    assert f"error: ekf_slam.py:{line}: SyntaxError" in watching.err.read_text()
    for number in range(1, 5):
        assert f"run {number} at " in printed


def _helper_filter(folder: Path) -> tuple[Path, Path]:
    """A filter class that imports a module beside it (the scale of its motion noise)."""
    helper = folder / "noise.py"
    helper.write_text("Q_SCALE = 1.0\n")
    module = folder / "my_filter.py"
    text = MY_FILTER.read_text().replace(
        "import numpy as np\n", "import numpy as np\n\nfrom noise import Q_SCALE\n", 1
    )
    module.write_text(
        text.replace("self.Q, self.R = params.Q,", "self.Q, self.R = Q_SCALE * params.Q,")
    )
    return module, helper


@pytest.mark.slow
def test_a_file_replaced_by_rename_and_one_deleted_then_made_again_are_still_followed(
    tmp_path: Path,
) -> None:
    module, helper = _helper_filter(tmp_path)
    shutil.copy(CLASSIC, tmp_path / "classic.txt")
    watching = Watching(tmp_path, "watch", f"{module.name}:MyFilter", "classic.txt",
                        "--save", "latest.rrd", "--report", "latest.json")  # fmt: skip
    try:
        assert watching.run(1)["match"] is True
        # the module beside it, replaced as vim and VS Code save: a new file renamed over it
        for number, scale, match in ((2, "2.0", False), (3, "1.0", True)):
            fresh = tmp_path / "noise.py.tmp"
            fresh.write_text(f"Q_SCALE = {scale}\n")
            os.replace(fresh, helper)
            report = watching.run(number)
            assert report["match"] is match and report["files"] == [str(absolute(helper))]
        text = module.read_bytes()
        module.unlink()
        watching.printed(f"waiting for {absolute(module)}")
        module.write_bytes(text)
        again = watching.run(4)
        assert again["match"] is True and again["files"] == [str(absolute(module))]
        watching.stop()
    finally:
        watching.kill()


@pytest.mark.slow
def test_a_burst_of_writes_is_one_change(tmp_path: Path) -> None:
    """An editor's save in several steps (the file written in pieces, its mode set, a
    backup made and removed) comes as one change; the next save as another."""
    module, other = tmp_path / "ekf_slam.py", tmp_path / "helpers.py"
    module.write_text("x = 1\n")
    other.write_text("y = 1\n")
    batches: list[set[Path]] = []
    seen = threading.Condition()

    def on_change(paths: set[Path]) -> None:
        with seen:
            batches.append(paths)
            seen.notify_all()

    # a generous quiet time: the burst is one change however loaded the machine is
    watcher = Watcher([absolute(module), absolute(other)], on_change, quiet_ms=400)

    def saved(count: int) -> None:
        with seen:
            assert seen.wait_for(lambda: len(batches) >= count, timeout=WAIT_S)

    try:
        for number in range(1, 100):  # until the watcher's thread has armed itself
            other.write_text(f"y = {number}\n")
            with seen:
                if seen.wait_for(lambda: batches, timeout=0.5):
                    break
        for _ in range(3):
            shutil.copy(module, tmp_path / "ekf_slam.py~")  # a backup, not followed
            with module.open("w") as handle:
                for piece in ("import numpy as np\n", "x = ", "2\n"):
                    handle.write(piece)
                    handle.flush()
                    os.fsync(handle.fileno())
            os.chmod(module, 0o644)
            (tmp_path / "ekf_slam.py~").unlink()
        saved(2)
        other.write_text("y = 0\n")  # a save after the burst's change came
        saved(3)
    finally:
        watcher.close()
    assert batches[-3:] == [{absolute(other)}, {absolute(module)}, {absolute(other)}]


def test_a_filter_finds_the_modules_beside_it_that_it_imports(tmp_path: Path) -> None:
    (tmp_path / "helpers.py").write_text("import numpy\nfrom .inner import g\n")
    (tmp_path / "inner.py").write_text("g = 1\n")
    (tmp_path / "unused.py").write_text("u = 1\n")
    package = tmp_path / "models"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "motion.py").write_text("import os\nimport broken\n")
    (tmp_path / "broken.py").write_text("def f(:\n")  # being edited: followed all the same
    module = tmp_path / "ekf_slam.py"
    module.write_text(
        "import json\nimport numpy as np\nimport helpers\nfrom models import motion\n"
        "from . import missing\n"
    )
    assert filter_files(module) == [
        absolute(module),
        absolute(tmp_path / "helpers.py"),
        absolute(package / "__init__.py"),
        absolute(package / "motion.py"),
        absolute(tmp_path / "inner.py"),
        absolute(tmp_path / "broken.py"),
    ]
    module.write_text("import helpers(\n")  # its own syntax error: itself only
    assert filter_files(module) == [absolute(module)]


def test_a_failure_is_placed_at_the_innermost_line_of_the_filters_own_files(
    tmp_path: Path,
) -> None:
    module, helper = tmp_path / "ekf_slam.py", tmp_path / "helpers.py"
    trace = (
        "Traceback (most recent call last):\n"
        f'  File "/somewhere/ekfviz/sandbox/child.py", line 770, in load\n'
        f'  File "{module}", line 12, in update\n'
        f'  File "{helper}", line 4, in wrap\n'
        '  File "/usr/lib/python3/numpy/core.py", line 99, in f\n'
        "ValueError: boom\n"
    )
    assert placed(trace, [module, helper], module) == (absolute(helper), 4)
    assert placed(trace, [module], module) == (absolute(module), 12)
    assert placed("no frames at all", [module], module) == (module, 0)


def _viewer_server(folder: Path) -> tuple[subprocess.Popen[bytes], str, Path]:
    """Rerun's viewer program as a gRPC server without a window: every recording it
    takes written to a file (a viewer's view of what arrived)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = int(probe.getsockname()[1])
    taken = folder / "viewer.rrd"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    server = subprocess.Popen(
        [str(Path(sys.executable).with_name("rerun")), "--port", str(port), "--save",
         str(taken)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
        start_new_session=True,
    )  # fmt: skip
    deadline = time.monotonic() + WAIT_S
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            assert server.poll() is None and time.monotonic() < deadline, "no Rerun server"
            time.sleep(0.05)
    return server, f"rerun+http://127.0.0.1:{port}/proxy", taken


SLOW_PREDICT = """
import sys as _sys, time as _time
_predict = predict
_said = []
def predict(X, P, control, control_cov, k):
    if not _said:  # the handshake: the worker's output is echoed on the watch's stderr
        print("slow run started", flush=True)
        _said.append(1)
    _time.sleep(0.5)
    return _predict(X, P, control, control_cov, k)
"""


def test_a_save_during_a_run_cancels_it_and_the_viewer_gets_complete_runs_only(
    skeleton: tuple[Path, Path],
) -> None:
    module, log = skeleton
    folder = module.parent
    server, url, taken = _viewer_server(folder)
    watching = Watching(folder, "watch", module.name, log.name, "--connect", url,
                        "--save", "latest.rrd", "--report", "latest.json")  # fmt: skip
    try:
        watching.run(1)
        correct = module.read_text()
        module.write_text(correct + SLOW_PREDICT)  # 29 predicts of half a second each
        watching.echoed("slow run started")
        slow_workers = _descendants(watching.process.pid)  # (the slow run's, sandboxed)
        module.write_text(correct.replace(ROTATED, UNROTATED))  # a save during that run
        report = watching.run(2)  # the slow run took no number: it never completed
        assert report["causes"] == ["noise_jacobian.missing"]
        assert slow_workers and not [pid for pid in slow_workers if _alive(pid)]  # ended
        module.write_text(correct + SLOW_PREDICT)
        watching.echoed("slow run started", 2)
        code, took, _ = watching.stop()  # Ctrl-C during a run: it ends too, and its worker
        assert code == 130 and took < EXIT_BOUND_S
    finally:
        watching.kill()
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=60)
    from rerun.chunk import RrdReader

    reader = RrdReader(taken)
    names = []
    for store in reader.recordings():
        assert store.application_id == "ekfviz"
        rows = [c.to_record_batch() for c in reader.stream(store=store)
                if c.entity_path == "/__properties"]  # fmt: skip
        names += [
            value[0]
            for batch in rows
            for name, column in zip(batch.schema.names, batch.columns, strict=True)
            if name == "RecordingInfo:name"
            for value in column.to_pylist()
        ]
    # two runs complete, two recordings, named to sort in the order of the runs
    assert sorted(name.split(" (")[0] for name in names) == ["ekf_slam run 001", "ekf_slam run 002"]


@pytest.mark.slow
def test_check_watch_runs_the_battery_under_the_interpreter_given(tmp_path: Path) -> None:
    """``check --watch`` without a log: every log of the battery at every run, a numpy-1
    module under its own interpreter (--python), a recording of each it can read kept."""
    assert NUMPY1.is_file(), f"{NUMPY1}: make test builds it"
    version = subprocess.run([str(NUMPY1), "-c", "import numpy; print(numpy.__version__)"],
                             capture_output=True, text=True, check=True).stdout  # fmt: skip
    if tuple(int(v) for v in version.split(".")[:2]) >= (1, 24):  # (Python 3.12+)
        pytest.skip(f"numpy {version.strip()} refuses ragged arrays too")
    module = students.write(tmp_path / "old", "ragged")
    watching = Watching(module.parent, "check", "--filter", module.name, "--watch",
                        "--python", str(NUMPY1), "--save", "latest.rrd", "--report",
                        "latest.json")  # fmt: skip
    try:
        report = watching.run(1)
        logs = report["logs"]
        assert isinstance(logs, list) and [entry["log"] for entry in logs] == [
            "classic",
            "edge",
            "midrun",
        ]
        assert all(entry["error"] is None for entry in logs), logs
        for name in ("latest-classic.rrd", "latest-edge.rrd"):
            assert (module.parent / name).is_file()
        # a course module cannot read the mid-run log: skipped, as check does, unsaved
        assert logs[2]["events_checked"] == 0 and not (module.parent / "latest-midrun.rrd").exists()
        watching.stop()
    finally:
        watching.kill()


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["watch", "ekf"], "watch follows a filter's file"),
        (["watch", "nowhere.py"], "nowhere.py: no such file"),
        (["watch", str(SKELETON), "nowhere.txt"], "nowhere.txt"),
        (["replay", str(CLASSIC), "--watch"], "--watch checks a filter of yours"),
        (
            ["replay", str(CLASSIC), "--filter", str(SKELETON), "--watch", "--association", "nn"],
            "--association: replay's own",
        ),
        (
            ["replay", str(CLASSIC), "--filter", str(SKELETON), "--watch", "--json"],
            "--json: replay's own",
        ),
    ],
)
def test_a_watch_that_cannot_start_says_why_in_one_line(args: list[str], said: str) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    assert said in result.output and "Traceback" not in result.output


def test_watchfiles_is_imported_only_once_a_watch_starts() -> None:
    code = (
        "import sys\nimport ekfviz.app.watch, ekfviz.cli.watch, ekfviz.cli.check\n"
        "from ekfviz.cli import app\nprint('watchfiles' in sys.modules)\n"
        "from ekfviz.app.watch.files import Watcher\n"
        "Watcher([], lambda paths: None).close()\nprint('watchfiles' in sys.modules)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.stdout.split() == ["False", "True"], result.stderr
