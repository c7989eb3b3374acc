"""Users' filters that do what real code does and ekfviz must outlive: a helper process
started in a session of its own, a clean-up of the folder, lines of megabytes, a silenced
``sys.stdout``, 64-bit hashed ids, a module list grown until memory runs out; and a class
whose file names are not UTF-8 or collide once made safe. Each through the real command
line; the filter in the worker process ekfviz starts for it."""

from __future__ import annotations

import csv
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from commands import run_ekfviz, run_ekfviz_process

ROOT = Path(__file__).parents[2]
SAMPLE = ROOT / "data" / "classic.txt"
BASE = ROOT / "examples" / "my_filter.py"  # a class filter of the protocol: MyFilter


def ekfviz(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``ekfviz ARGS`` in ``cwd``."""
    return run_ekfviz(*args, cwd=cwd)


def filter_module(folder: Path, body: str, name: str = "f.py") -> str:
    """A module of class ``F``, a subclass of the example filter, with ``body`` in it;
    its spec."""
    shutil.copy(BASE, folder / "basef.py")
    (folder / name).write_text("import os, sys\nfrom basef import MyFilter as Base\n" + body)
    return f"{name}:F"


def refused(spec: str, folder: Path, *options: str) -> str:
    """The stderr of a replay with the filter ``spec`` that must fail: exit 2, no
    traceback of ekfviz's."""
    result = ekfviz("replay", str(SAMPLE), "--filter", spec, "--save", "run.rrd", *options,
                    cwd=folder)  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    return result.stderr


@pytest.mark.slow
def test_a_helper_process_in_a_session_of_its_own_does_not_hold_the_run(tmp_path: Path) -> None:
    """It outlives the worker's process group and held the worker's output pipe: ekfviz,
    closing that pipe while a thread read it, waited for the helper to end (a class's
    grade waited past its --timeout, and was killed with no table)."""
    spec = filter_module(
        tmp_path,
        "import subprocess\n"
        "helper = subprocess.Popen(['sleep', '600'], start_new_session=True)\n"
        "open('helper.pid', 'w').write(str(helper.pid))\n"
        "class F(Base):\n    pass\n",
    )
    try:  # in a process of its own: a run held by the helper fails at the time-out
        result = run_ekfviz_process("replay", SAMPLE, "--filter", spec, "--save", "run.rrd",
                                    "--no-sandbox", cwd=tmp_path, timeout=60)  # fmt: skip
        assert result.returncode == 0, result.stderr
        assert (tmp_path / "run.rrd").stat().st_size > 0
    finally:
        pid = int((tmp_path / "helper.pid").read_text())
        os.kill(pid, signal.SIGKILL)
    # in the sandbox no helper starts (and its pid file would be nowhere of the caller's)
    (tmp_path / "helper.pid").unlink()
    stderr = refused(spec, tmp_path)
    assert "PermissionError: [Errno 1] Operation not permitted" in stderr
    assert not (tmp_path / "helper.pid").exists()


def test_a_recording_s_temporary_file_removed_by_the_filter_is_one_line(tmp_path: Path) -> None:
    """ "Start from a clean results folder": the filter removes the recording being written;
    the move into place then failed with ekfviz's traceback."""
    spec = filter_module(
        tmp_path,
        "class F(Base):\n"
        "    n = 0\n"
        "    def predict(self, d, alpha):\n"
        "        F.n += 1\n"
        "        if F.n == 5:\n"
        "            for name in os.listdir('.'):\n"
        "                if name.endswith('.part'):\n"
        "                    os.remove(name)\n"
        "        super().predict(d, alpha)\n",
    )
    result = ekfviz("replay", str(SAMPLE), "--filter", spec, "--save", "keep.rrd", cwd=tmp_path)
    assert result.returncode == 0, result.stderr  # in the sandbox it sees none of the folder
    (tmp_path / "keep.rrd").unlink()
    result = ekfviz("replay", str(SAMPLE), "--filter", spec, "--save", "keep.rrd",
                    "--no-sandbox", cwd=tmp_path)  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("error: keep.rrd: the recording could not be saved: its temporary")
    assert "removed during the run?" in line
    assert not (tmp_path / "keep.rrd").exists()


def test_a_line_of_megabytes_is_neither_kept_whole_nor_quoted_whole(tmp_path: Path) -> None:
    """The error quoted the filter's last line whole (20 MB in "one line"), and every
    line it printed was kept whole (200 of them: gigabytes)."""
    spec = filter_module(
        tmp_path,
        "class F(Base):\n"
        "    def predict(self, d, alpha):\n"
        "        print('x' * (5 << 20), flush=True)\n"
        "        os._exit(1)\n",
    )
    stderr = refused(spec, tmp_path)
    error = stderr.strip().splitlines()[-1]
    assert "its last output: xxxx" in error and " ...;" in error
    assert len(error) < 1000


def test_a_filter_that_silences_its_prints_runs(tmp_path: Path) -> None:
    """``sys.stdout = None`` is harmless in plain Python; the worker's own flush of it
    failed, and the run stopped blaming the filter with the worker's traceback."""
    spec = filter_module(
        tmp_path,
        "class F(Base):\n"
        "    def predict(self, d, alpha):\n"
        "        sys.stdout = None\n"
        "        super().predict(d, alpha)\n",
    )
    result = ekfviz("replay", str(SAMPLE), "--filter", spec, "--save", "run.rrd", "--json",
                    cwd=tmp_path)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr


def test_ids_beyond_a_64_bit_signed_integer_are_the_filter_s_named_fault(tmp_path: Path) -> None:
    """A map keyed by 64-bit unsigned hashes: ekfviz's own conversion overflowed, and the
    message said the user's update raised."""
    spec = filter_module(
        tmp_path,
        "import numpy as np\n"
        "class F:\n"
        "    def __init__(self, params):\n"
        "        self.x, self.P, self.keys = np.zeros(3), np.eye(3) * 0.01, []\n"
        "    @property\n"
        "    def landmark_ids(self):\n"
        "        return np.array(self.keys, dtype=np.uint64)\n"
        "    def predict(self, d, alpha):\n"
        "        pass\n"
        "    def update(self, ids, z):\n"
        "        for i in ids.tolist():\n"
        "            self.keys.append(2**64 - 1 - i)\n"
        "            self.x = np.append(self.x, [0.0, 0.0])\n"
        "            P = np.eye(len(self.x)) * 0.01\n"
        "            P[:-2, :-2] = self.P\n"
        "            self.P = P\n",
    )
    stderr = refused(spec, tmp_path)
    assert "landmark_ids holds 18446744073709551614, expected ids that fit a 64-bit signed" \
        " integer" in stderr  # fmt: skip
    assert "raised OverflowError" not in stderr


def test_a_list_grown_until_memory_runs_out_is_said_as_memory(tmp_path: Path) -> None:
    """The memory stays held by the module's list: formatting the fault ran out again and
    the worker died with its own traceback, the run read "exited with code 1"."""
    spec = filter_module(
        tmp_path,
        "history = []\n"
        "class F(Base):\n"
        "    def predict(self, d, alpha):\n"
        "        while True:\n"
        "            history.append([0.0] * 1000)\n",
    )
    stderr = refused(spec, tmp_path, "--filter-memory", "256")
    assert (
        stderr.strip()
        .splitlines()[-1]
        .startswith(
            f"error: {SAMPLE}:2: event 1 (predict): filter {spec}: predict raised MemoryError"
        )
    )


@pytest.mark.slow
def test_a_class_graded_whatever_its_file_names(tmp_path: Path) -> None:
    """A name that is not UTF-8 (a zip from another system) crashed the CSV for the whole
    class; two names made alike by making them safe (``a b.py``, ``a_b.py``) wrote one
    recording over the other."""
    if sys.platform != "linux":
        pytest.skip("a file name of bytes that are not UTF-8")
    group = tmp_path / "class"
    group.mkdir()
    source = (ROOT / "examples" / "course_skeleton" / "ekf_slam.py").read_text()
    for name in ("a b.py", "a_b.py"):
        (group / name).write_text(source)
    os.close(os.open(os.fsencode(group) + b"/M\xfcller.py", os.O_CREAT | os.O_WRONLY))
    with open(os.fsencode(group) + b"/M\xfcller.py", "w") as handle:
        handle.write(source)
    result = ekfviz("grade", "class", "--log", str(SAMPLE), "--workers", "1", "--report",
                    "grades.csv", "--save-dir", "recs", cwd=tmp_path)  # fmt: skip
    assert result.returncode == 0, result.stderr
    with (tmp_path / "grades.csv").open(encoding="utf-8") as handle:
        names = sorted(row["submission"] for row in csv.DictReader(handle))
    assert names == ["M\ufffdller.py", "a b.py", "a_b.py"]
    recordings = sorted(p.name for p in (tmp_path / "recs").iterdir())
    assert len(recordings) == 3, recordings
    assert "a_b.py-classic.rrd" in recordings  # a safe name as it was


@pytest.mark.slow
def test_an_answer_too_large_to_take_is_refused_before_it_is_allocated(tmp_path: Path) -> None:
    """A covariance "preallocated" for 6,000 landmarks (lazy zeros: nothing to the
    filter) took ekfviz to 2.4 GB reading it before the shapes were checked."""
    spec = filter_module(
        tmp_path,
        "import numpy as np\n"
        "class F(Base):\n"
        "    def predict(self, d, alpha):\n"
        "        super().predict(d, alpha)\n"
        "        big = np.zeros((12003, 12003))\n"
        "        big[: len(self.P), : len(self.P)] = self.P\n"
        "        self.P = big\n",
    )
    stderr = refused(spec, tmp_path)
    assert "after predict, its arrays ((15,), (12003, 12003)) are 1.2 GB, more than the 1 GiB" \
        " ekfviz takes from a filter" in stderr  # fmt: skip


def test_a_state_the_reference_cannot_step_from_is_named_with_the_filter(tmp_path: Path) -> None:
    """Landmarks left at a placeholder of 1e200: the reference's update from that state
    overflowed and ``check`` said only "the state became non-finite in update", naming
    neither the filter nor the event, and lost what it had found before."""
    spec = filter_module(
        tmp_path,
        "import numpy as np\n"
        "class F(Base):\n"
        "    def update(self, ids, z):\n"
        "        for i in ids.tolist():\n"
        "            if i not in self.landmark_ids:\n"
        "                self.landmark_ids.append(i)\n"
        "                self.x = np.append(self.x, [1e200, 1e200])\n"
        "                P = np.eye(len(self.x))\n"
        "                P[:-2, :-2] = self.P\n"
        "                self.P = P\n",
    )
    result = ekfviz("check", str(SAMPLE), "--filter", spec, "--all", cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert f"{SAMPLE}:3: event 2 (update): the reference cannot update from the state" \
        f" filter {spec} gave before it: the state became non-finite in update (the largest" \
        " |x| is 1e+200" in result.stderr  # fmt: skip
    assert "divergence at event 0 (step 0, init" in result.stdout  # found before: still said


def test_a_submission_whose_time_ran_out_before_a_log_is_a_timeout(tmp_path: Path) -> None:
    """Its row said "error: the filter's worker did not start (it needs Python >= 3.8
    with numpy >= 1.17)", where its time had run out on the logs before."""
    from ekfviz.app.grade import GradeTask, grade_one
    from ekfviz.core.params import FilterParams

    module = tmp_path / "ekf_slam.py"
    shutil.copy(ROOT / "examples" / "course_skeleton" / "ekf_slam.py", module)
    task = GradeTask(name="ekf_slam.py", path=module, logs=((SAMPLE, None, None, None),),
                     params=FilterParams(), timeout_s=0.0, memory_mb=None)  # fmt: skip
    row = grade_one(task)
    assert (row.status, row.detail) == (
        "timeout",
        "its time (--timeout 0 s) ran out before the classic log",
    )


def test_grade_finds_a_class_whose_predict_is_the_course_s(tmp_path: Path) -> None:
    """``class AliceFilter(MyFilter)`` with only its own ``update`` was an error row (no
    ``def predict(`` in it), and a module's hint named the imported base class."""
    from ekfviz.app.grade import spec_text

    module = tmp_path / "ekf_slam.py"
    module.write_text(
        "from base_filter import MyFilter\n\n\n"
        "class Helper:\n    pass\n\n\n"
        "class AliceFilter(MyFilter):\n"
        "    def update(self, ids, z):\n"
        "        super().update(ids, z)\n"
    )
    assert spec_text(module) == f"{module}:AliceFilter"
    shutil.copy(BASE, tmp_path / "basef.py")
    (tmp_path / "g.py").write_text("from basef import MyFilter as Base\n\n\nclass F(Base):\n"
                                   "    pass\n")  # fmt: skip
    result = ekfviz("replay", str(SAMPLE), "--filter", "g.py", "--save", "x.rrd", cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip().endswith("g.py:F"), result.stderr  # not g.py:Base


def test_grade_finds_a_module_s_only_class_whose_methods_are_all_inherited(
    tmp_path: Path,
) -> None:
    """``class F(Base): pass`` (or only its own ``__init__``) was graded as a course module
    of functions: an error row, "has no function init_landmarks"."""
    from ekfviz.app.grade import spec_text

    module = tmp_path / "ekf_slam.py"
    module.write_text("from basef import MyFilter as Base\n\n\nclass F(Base):\n    pass\n")
    assert spec_text(module) == f"{module}:F"
    module.write_text(
        "from basef import MyFilter as Base\n\n\nclass Mine(Base):\n"
        "    def __init__(self, params):\n        super().__init__(params)\n"
    )
    assert spec_text(module) == f"{module}:Mine"
    module.write_text("class A:\n    pass\n\n\nclass B:\n    pass\n")  # which? none
    assert spec_text(module) == str(module)


def test_a_module_that_imports_the_files_beside_it_relatively_loads(tmp_path: Path) -> None:
    """``from .utils import ...`` in a submission's module was "ImportError: attempted
    relative import with no known parent package", with no way around it."""
    folder = tmp_path / "alice"
    folder.mkdir()
    (folder / "__init__.py").write_text("raise RuntimeError('a package __init__ is not run')\n")
    (folder / "utils.py").write_text("def wrap(a):\n    return (a + 3.141592653589793) %"
                                     " (2 * 3.141592653589793) - 3.141592653589793\n")  # fmt: skip
    skeleton = (ROOT / "examples" / "course_skeleton" / "ekf_slam.py").read_text()
    (folder / "ekf_slam.py").write_text(skeleton + "\nfrom .utils import wrap  # noqa\n")
    result = ekfviz("check", str(SAMPLE), "--filter", "alice/ekf_slam.py", cwd=tmp_path)
    assert result.returncode == 0 and result.stdout.startswith("course module"), result.stderr
    shutil.copy(BASE, folder / "basef.py")
    (folder / "g.py").write_text("from . import utils\nfrom .basef import MyFilter\n\n\n"
                                 "class G(MyFilter):\n    pass\n")  # fmt: skip
    replayed = ekfviz("replay", str(SAMPLE), "--filter", "alice/g.py:G", "--save", "g.rrd",
                      cwd=tmp_path)  # fmt: skip
    assert replayed.returncode == 0, replayed.stderr


def test_the_worker_closes_its_streams_under_pythonwarnings(tmp_path: Path) -> None:
    """With PYTHONWARNINGS=default the worker printed a ResourceWarning for each stream of
    its own it left to the garbage collector (commands, answers, /dev/null), as the
    filter's output; with =error, "Exception ignored" tracebacks before the error line."""
    # in a process of its own: the variable sets the warnings of ekfviz's process too, from
    # its start to the collection of its streams at exit ("Exception ignored")
    env = {**os.environ, "PYTHONWARNINGS": "default"}
    done = run_ekfviz_process("replay", SAMPLE, "--filter", f"{BASE}:MyFilter", "--save",
                              tmp_path / "run.rrd", env=env, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "ResourceWarning" not in done.stderr and "Exception ignored" not in done.stderr


def test_grade_of_a_log_takes_the_noise_its_header_states(tmp_path: Path) -> None:
    """As ``check`` of that log does: ``grade --log`` judged a filter of the log's own noise
    against the defaults (``different_motion_noise``)."""
    log = tmp_path / "noisy.txt"
    log.write_text("# noise: sigma_x=0.1 sigma_y=0.05 sigma_alpha=0.02\n" + SAMPLE.read_text())
    submission = tmp_path / "class" / "alice"  # (its base class in its own folder)
    submission.mkdir(parents=True)
    shutil.copy(BASE, submission / "basef.py")
    (submission / "ekf_slam.py").write_text(
        "import numpy as np\nfrom basef import MyFilter as Base\n\n\nclass Alice(Base):\n"
        "    def predict(self, d, alpha):\n"
        "        self.Q = np.diag([0.1, 0.05, 0.02]) ** 2\n"
        "        super().predict(d, alpha)\n"
    )
    checked = ekfviz("check", str(log), "--filter", "class/alice/ekf_slam.py:Alice", cwd=tmp_path)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    report = tmp_path / "grades.csv"
    graded = ekfviz("grade", "class", "--log", str(log), "--report", str(report), cwd=tmp_path)
    assert graded.returncode == 0, graded.stderr
    rows = {row["submission"]: row for row in csv.DictReader(report.open())}
    assert (rows["alice"]["status"], rows["alice"]["causes"]) == ("match", "")
    assert "noisy.txt: the noise its header states: --sigma-x 0.1" in graded.stdout


def test_a_compare_s_table_has_a_row_for_each_filter_that_failed(tmp_path: Path) -> None:
    """One that failed before its first event had no row (only a line on stderr); one
    stopped in step 3 read "consistent", judged on its first steps without a word."""
    broken = "class Broken(Base):\n    def __init__(self, params):\n        raise OSError\n"
    filter_module(tmp_path, broken, name="broken.py")
    filter_module(
        tmp_path,
        "class Stops(Base):\n"
        "    n = 0\n"
        "    def predict(self, d, alpha):\n"
        "        Stops.n += 1\n"
        "        if Stops.n == 3:\n"
        "            raise RuntimeError('stop')\n"
        "        super().predict(d, alpha)\n",
        name="stops.py",
    )
    result = ekfviz("compare", str(SAMPLE), "--filter", "ekf", "--filter", "broken.py:Broken",
                    "--filter", "stops.py:Stops", "--workers", "1", "--save", "c.rrd",
                    cwd=tmp_path)  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = {line.split()[0]: line for line in result.stdout.splitlines() if line.strip()}
    assert rows["Broken"].rstrip().endswith("failed before its first event"), result.stdout
    assert "stopped after step 2; till then: consistent" in rows["Stops"], result.stdout
