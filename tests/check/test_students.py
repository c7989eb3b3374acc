"""Students' filters as handed in: course modules run in workers, every mistake named,
a class graded, comparisons of other people's code (filters written the way students write them)."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import students
from commands import run_ekfviz, run_ekfviz_process
from conftest import entity_rows

from ekfviz.check.mutations import resolve

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
# an interpreter with numpy 1.23 (make test builds it: .venv-numpy1)
NUMPY1 = Path(os.environ.get("EKFVIZ_NUMPY1_PYTHON", ROOT / ".venv-numpy1" / "bin" / "python"))


def ekfviz(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """``ekfviz ARGS`` in this process (the filters run in their sandboxes all the same)."""
    return run_ekfviz(*args, cwd=cwd)


# the mistakes checked by default, one or two of each operation; make test-all checks all
FAST_MISTAKES = {
    "correct", "transposed", "no_r", "joint", "degrees", "cos_sin_init",
}  # fmt: skip


@pytest.mark.parametrize(
    "name",
    [
        name if name in FAST_MISTAKES else pytest.param(name, marks=pytest.mark.slow)
        for name in sorted(set(students.MISTAKES) - {"ragged"})
    ],
)
def test_check_all_names_exactly_the_mistakes_in_the_code(tmp_path: Path, name: str) -> None:
    module = students.write(tmp_path / name, name)
    report = tmp_path / "check.json"
    # the edge log exercises everything the classic one does, and angle wrapping
    log = DATA / ("edge.txt" if "unwrapped" in name else "classic.txt")
    start = ["--init-pose", "4", "-2", "3.1365926535897932"] if log.stem == "edge" else []
    result = ekfviz("check", str(log), "--filter", str(module), "--all", "--report",
                    str(report), *start)  # fmt: skip
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    document = json.loads(report.read_text())
    expected = {resolve(cause) for cause in students.MISTAKES[name]}
    assert set(document["causes"]) == expected
    # every group of divergences names a cause, or says unknown; none names one not in the code
    for group in document["divergences"]:
        for cause in group["cause"].split("+"):
            assert cause in expected | {"unknown"}, group
    # the console says what the report says
    for cause in expected:
        assert cause in result.stdout


def test_the_course_skeleton_matches_and_says_what_the_log_left_untested() -> None:
    skeleton = ROOT / "examples" / "course_skeleton" / "ekf_slam.py"
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(skeleton))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "match: all 59 events agree" in result.stdout
    assert "no bearing within 0.1 rad of +-pi" in result.stdout
    battery = ekfviz("check", "--filter", str(skeleton), "--all")
    assert battery.returncode == 0, battery.stdout + battery.stderr
    # the edge log exercises angle wrapping: nothing said about it there
    edge = battery.stdout[battery.stdout.index("log edge") : battery.stdout.index("log midrun")]
    untested = [line for line in edge.splitlines() if line.lstrip().startswith("- ")]
    assert untested and not any("bearing" in line or "heading" in line for line in untested)


def test_without_all_the_first_divergence_and_how_many_more(tmp_path: Path) -> None:
    module = students.write(tmp_path / "t", "transposed")
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module))
    assert result.returncode == 1
    assert "course module, shapes detected: X (3+2k, 1), control (2, 1)" in result.stdout
    first = next(line for line in result.stdout.splitlines() if line.startswith("divergence"))
    more = result.stdout
    assert first.startswith("divergence at event 0 (step 0, init")
    assert re.search(r"\d+ more event\(s\) diverge; --all", more)


def test_the_console_prints_names_as_the_report_has_them(tmp_path: Path) -> None:
    folder = tmp_path / "[bold]x"
    module = students.write(folder, "unrotated")
    report = tmp_path / "r.json"
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module), "--report",
                    str(report))  # fmt: skip
    document = json.loads(report.read_text())
    entry = document["first_divergence"]["entry"]
    assert re.fullmatch(r"P\[[A-Za-z0-9.]+, [A-Za-z0-9.]+\]|x\[[A-Za-z0-9.]+\]", entry)
    assert f"worst entry {entry}:" in result.stdout
    assert "[bold]x" in result.stdout + result.stderr or "[bold]" in str(module)
    wrong = tmp_path / "wrong.py"
    wrong.write_text(students.source("correct").replace("X_pre[2, 0] = warp2pi(theta + alpha)",
                                                        "X_pre[2, 0] = theta"))  # fmt: skip
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(wrong), "--report",
                    str(report))  # fmt: skip
    document = json.loads(report.read_text())
    divergence = next(d for d in [document["first_divergence"]] if d)
    assert f"worst entry {divergence['entry']}:" in result.stdout


def test_wrong_shapes_name_the_function_the_array_and_the_shapes(tmp_path: Path) -> None:
    module = tmp_path / "broadcast.py"
    module.write_text(
        students.source("correct").replace(
            "    return X_pre, P_pre\n", "    return X_pre + X_pre.T, P_pre\n"
        )
    )
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module))
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "predict returned X of shape (15, 15), expected (15, 1) or (15,)" in line
    assert line.startswith(f"error: {DATA / 'classic.txt'}:2: event 1 (predict)")


FLAT = """
import numpy as np


def init_landmarks(init_measure, init_measure_cov, init_pose, init_pose_cov):
    assert init_measure.ndim == 1 and init_pose.ndim == 1, "flat arrays only"
    k = len(init_measure) // 2
    x, y, theta = init_pose
    landmark = np.zeros(2 * k)
    for i in range(k):
        beta, r = init_measure[2 * i : 2 * i + 2]
        landmark[2 * i : 2 * i + 2] = [x + r * np.cos(theta + beta), y + r * np.sin(theta + beta)]
    return k, landmark, 0.1 * np.eye(2 * k)


def predict(X, P, control, control_cov, k):
    assert X.ndim == 1 and control.ndim == 1, "flat arrays only"
    d, alpha = control
    X = X.copy()
    X[:3] += [d * np.cos(X[2]), d * np.sin(X[2]), alpha]
    return X, P


def update(X, P, measure, measure_cov, k):
    assert X.ndim == 1 and measure.ndim == 1, "flat arrays only"
    return X, P
"""


def test_flat_shapes_are_detected_and_said(tmp_path: Path) -> None:
    from ekfviz.core.params import FilterParams
    from ekfviz.filters.spec import FilterSpec

    flat = tmp_path / "flat.py"
    flat.write_text(FLAT)
    remote: Any = FilterSpec(str(flat)).load()(FilterParams())
    remote.update(np.array([1, 2]), np.array([[0.5, 3.0], [1.0, 4.0]]))
    remote.predict(1.0, 0.1)
    assert remote.convention == {"X": "flat", "control": "flat", "measure": "flat"}
    assert remote.x.shape == (7,) and remote.x[0] == pytest.approx(1.0)
    remote.close()


def test_a_numpy1_solution_runs_under_its_own_interpreter(tmp_path: Path) -> None:
    assert NUMPY1.is_file(), f"{NUMPY1}: make test builds it (numpy 1.23)"
    version = subprocess.run(
        [str(NUMPY1), "-c", "import numpy; print(numpy.__version__)"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    if tuple(int(v) for v in version.split(".")[:2]) >= (1, 24):  # (Python 3.12+)
        pytest.skip(f"numpy {version.strip()} refuses ragged arrays too")
    module = students.write(tmp_path / "old", "ragged")
    # numpy 2 refuses the ragged array: one line that says what to do
    refused = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module))
    assert refused.returncode == 2
    assert "ragged array" in refused.stderr and "--python" in refused.stderr
    report = tmp_path / "old.json"
    result = ekfviz("check", "--filter", str(module), "--all", "--python", str(NUMPY1),
                    "--report", str(report))  # fmt: skip
    assert result.returncode == 1, result.stdout + result.stderr
    assert set(json.loads(report.read_text())["causes"]) == _resolved("ragged")


def test_a_filter_that_prints_never_breaks_json_and_its_exit_is_contained(tmp_path: Path) -> None:
    chatty = tmp_path / "chatty.py"
    chatty.write_text(
        students.source("correct")
        .replace("def predict(X, P, control, control_cov, k):",
                 "def predict(X, P, control, control_cov, k):\n    print('predicting', k)")
        + "\nprint('imported')\nimport os\nos.write(1, b'raw C-level output\\n')\n"
    )  # fmt: skip
    # a process of its own: what the filter writes to descriptor 1 must not reach ekfviz's
    result = run_ekfviz_process("replay", DATA / "classic.txt", "--filter", chatty, "--json",
                                "--save", tmp_path / "c.rrd")  # fmt: skip
    assert result.returncode == 0, result.stderr
    json.loads(result.stdout)  # nothing but the document on stdout
    assert "predicting 6" in result.stderr and "raw C-level output" in result.stderr
    quitter = tmp_path / "quitter.py"
    quitter.write_text(students.source("correct").replace(
        "    P_pre = G @ P @ G.T + Q", "    import sys\n    sys.exit(0)"))  # fmt: skip
    save = tmp_path / "q.rrd"
    result = ekfviz("replay", str(DATA / "classic.txt"), "--filter", str(quitter), "--save",
                    str(save))  # fmt: skip
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "event 1 (predict)" in line and "sys.exit(0)" in line and ":2:" in line
    assert len(entity_rows(save, "/world/robot")) == 1  # the initialisation, kept
    at_import = tmp_path / "at_import.py"
    at_import.write_text("import sys\nsys.exit(3)\n")
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(at_import))
    assert result.returncode == 2 and "sys.exit(3)" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_crash_and_a_hang_are_bounded_and_named(tmp_path: Path) -> None:
    crash = tmp_path / "crash.py"
    crash.write_text(students.source("correct").replace(
        "    P_pre = G @ P @ G.T + Q",
        "    import ctypes\n    ctypes.string_at(0)\n    P_pre = G @ P @ G.T + Q"))  # fmt: skip
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(crash))
    assert result.returncode == 2
    assert "killed by SIGSEGV during predict" in result.stderr and "Traceback" not in result.stderr
    hang = tmp_path / "hang.py"
    hang.write_text(students.source("correct").replace(
        "    P_pre = G @ P @ G.T + Q", "    while True:\n        pass"))  # fmt: skip
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(hang),
                    "--filter-timeout", "1")  # fmt: skip
    assert result.returncode == 2
    assert "predict did not return within 1 s (--filter-timeout)" in result.stderr


def test_compare_of_three_students_and_a_broken_one_records_the_three(tmp_path: Path) -> None:
    paths = [students.write(tmp_path / n, n) for n in ("tkagg", "correct", "joint")]
    broken = tmp_path / "broken.py"
    broken.write_text("def predict(:\n")
    save, report = tmp_path / "cmp.rrd", tmp_path / "cmp.json"
    result = ekfviz("compare", str(DATA / "classic.txt"), *[a for p in paths for a in
                    ("--filter", str(p))], "--filter", f"broken={broken}", "--label", "alice",
                    "--save", str(save), "--report", str(report))  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = json.loads(report.read_text())["filters"]
    labels = [row["label"] for row in rows]
    assert labels[0] == "alice" and "broken" in labels
    # the students' files share a name: each is called by its folder
    assert {"correct/ekf_slam", "joint/ekf_slam"} <= set(labels)
    assert next(r for r in rows if r["label"] == "broken")["failure"].count("SyntaxError") == 1
    for row in rows:
        if row["label"] != "broken":
            key = row["label"].replace("/", "_")
            assert len(entity_rows(save, f"/filters/{key}/world/robot")) == 59, key


def test_grade_gives_each_submission_its_row(tmp_path: Path) -> None:
    """A class of modules that run and one that does not parse: the table's columns and
    recordings."""
    folder = tmp_path / "class"
    students.write(folder / "ada", "correct")
    students.write(folder / "bob", "transposed_and_missing_pose_term")
    (folder / "syntax.py").write_text("def predict(:\n")
    csv = tmp_path / "grades.csv"
    result = ekfviz("grade", str(folder), "--report", str(csv), "--json",
                    "--save-dir", str(tmp_path / "rec"))  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = {row["submission"]: row for row in json.loads(result.stdout)["submissions"]}
    assert {name: row["status"] for name, row in rows.items()} == {
        "ada": "diverged", "bob": "diverged", "syntax.py": "error"
    }  # fmt: skip
    assert set(rows["bob"]["causes"]) == _resolved("transposed_and_missing_pose_term")
    assert csv.read_text().splitlines()[0] == (
        "submission,status,causes,first_divergence,seconds,detail,cause,sentence,hint,"
        "operation,mutation,source_line,numbers,sandbox,complete"
    )
    assert (tmp_path / "rec" / "ada-classic.rrd").is_file()


def test_grade_gives_a_module_that_hangs_hogs_or_quits_its_row(tmp_path: Path) -> None:
    """A class of modules that break, hang or hog (a short --timeout for the one that
    hangs)."""
    hostile = "def predict(X, P, c, q, k):\n    return X, P\n\ndef update(X, P, m, r, k):\n" \
              "    return X, P\n\ndef init_landmarks(m, r, p, c):\n{body}\n"  # fmt: skip
    bodies = {
        "loop.py": "    while True:\n        pass",
        "hog.py": "    import numpy as np\n    return np.ones(1 << 33)",
        "quitter.py": "    import sys\n    sys.exit(0)",
        "suicide.py": "    import os, signal\n    os.kill(os.getpid(), signal.SIGKILL)",
    }
    broken = tmp_path / "broken"
    broken.mkdir()
    for name, body in bodies.items():
        (broken / name).write_text(hostile.format(body=body))
    result = ekfviz("grade", str(broken), "--timeout", "4", "--memory", "1024", "--json")
    assert result.returncode == 0, result.stderr
    rows = {row["submission"]: row for row in json.loads(result.stdout)["submissions"]}
    assert {name: row["status"] for name, row in rows.items()} == {
        "loop.py": "timeout", "hog.py": "memory", "quitter.py": "crashed", "suicide.py": "crashed",
    }  # fmt: skip
    assert rows["loop.py"]["seconds"] < 30


def test_a_submission_neither_file_nor_folder_is_named_as_what_it_is(tmp_path: Path) -> None:
    """A FIFO, or a link to nothing, among the submissions gets a row saying so (it had
    "no .py file in it"), and nothing waits on the FIFO."""
    from ekfviz.app.grade import NoModule, module_of

    fifo = tmp_path / "fifo.py"
    os.mkfifo(fifo)
    with pytest.raises(NoModule, match=r"^fifo.py is a FIFO \(named pipe\), expected a \.py file"):
        module_of(fifo)
    dangling = tmp_path / "gone"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(NoModule, match=r"^gone is a symbolic link \(a submission is a file or"):
        module_of(dangling)
    # where its target was given: named as the entry of the class's folder
    with pytest.raises(NoModule, match=r"^gone is unreadable \(No such file or directory\)"):
        module_of(dangling.resolve(), "gone")


def test_the_battery_is_the_bundled_data(tmp_path: Path) -> None:
    from ekfviz.samples import write_battery

    for log, truth, _ in write_battery(tmp_path):
        assert log.read_bytes() == (DATA / log.name).read_bytes()
        assert truth.read_bytes() == (DATA / truth.name).read_bytes()


@pytest.mark.parametrize("exposed", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_an_open_source_style_filter_gets_its_predict_mistakes_named(
    tmp_path: Path, exposed: bool
) -> None:
    name = "RoboticsStyleExposed" if exposed else "RoboticsStyle"
    report = tmp_path / "r.json"
    spec = f"{ROOT / 'tests' / 'plugins' / 'robotics_style.py'}:{name}"
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", spec, "--all", "--report",
                    str(report))  # fmt: skip
    assert result.returncode == 1, result.stderr
    found = json.loads(report.read_text())
    predict = next(g for g in found["divergences"] if g["kind"] == "predict")
    if exposed:  # its declared noise is named, never adopted; G and the skipped P_rm with it
        assert set(found["causes"]) == {
            "motion_noise.declared", "measurement_noise.declared",
            "motion_jacobian.transposed", "cross_covariance.skipped",
        }  # fmt: skip
        assert predict["cause"] == (
            "motion_noise.declared+motion_jacobian.transposed+cross_covariance.skipped"
        )
    else:  # a noise of its own it does not declare, read off its result; G and P_rm named
        assert predict["cause"] == (
            "motion_jacobian.transposed+cross_covariance.skipped+motion_noise.own"
        ), predict


@pytest.mark.slow  # a whole class again (each kind of row is graded by default above)
def test_grade_on_a_dask_cluster_gives_the_same_rows(tmp_path: Path) -> None:
    """Each submission in its sandbox on the cluster's workers: one that dials the
    scheduler (its address was in an ancestor's command line) reaches nothing."""
    from distributed import LocalCluster

    folder = tmp_path / "class"
    students.write(folder / "ada", "correct")
    students.write(folder / "bob", "joint")
    (folder / "quitter.py").write_text("import sys\nsys.exit(1)\n")
    with LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:  # fmt: skip
        host, port = str(cluster.scheduler_address).removeprefix("tcp://").split(":")
        (folder / "dialer.py").write_text(
            "import socket\n\n\ndef predict(X, P, c, q, k):\n    return X, P\n\n\n"
            "def update(X, P, m, r, k):\n    return X, P\n\n\n"
            "def init_landmarks(m, r, pose, cov):\n"
            f"    socket.create_connection(({host!r}, {port}), timeout=5)\n"
        )
        result = ekfviz("grade", str(folder), "--executor", "dask", "--scheduler",
                        str(cluster.scheduler_address), "--json")  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = {r["submission"]: r for r in json.loads(result.stdout)["submissions"]}
    assert {n: r["status"] for n, r in rows.items()} == {
        "ada": "diverged", "bob": "diverged", "quitter.py": "crashed", "dialer.py": "error"
    }  # fmt: skip
    assert set(rows["bob"]["causes"]) == _resolved("joint")
    assert "PermissionError: [Errno 1] Operation not permitted" in rows["dialer.py"]["detail"]


def test_a_state_turning_complex_is_one_line_without_a_warning(tmp_path: Path) -> None:
    module = tmp_path / "complex.py"
    module.write_text(students.source("correct").replace(
        "    P_pre = G @ P @ G.T + Q", "    P_pre = (G @ P @ G.T + Q) * (1 + 0j)"))  # fmt: skip
    result = ekfviz("replay", str(DATA / "classic.txt"), "--filter", str(module), "--save",
                    str(tmp_path / "c.rrd"))  # fmt: skip
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "predict returned P with complex numbers, expected real ones" in line
    assert "Warning" not in result.stderr


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["grade", "{tmp}/missing"], "{tmp}/missing: no such directory"),
        (["grade", "{tmp}/file.py"], "{tmp}/file.py: not a directory"),
        (["grade", "{tmp}/empty"], "{tmp}/empty: no submissions in it"),
        (["grade", "{tmp}/class", "--log", "{tmp}/no.txt"], "--log {tmp}/no.txt: no such file"),
        (["check", "--filter", "{tmp}/file.py", "--python", "{tmp}/nopython"],
         "--python {tmp}/nopython: no such interpreter"),
        (["check", "--filter", "{tmp}/missing.py"], "{tmp}/missing.py: no such file"),
        (["check", "--filter", "{tmp}/empty"], "{tmp}/empty is a directory"),
        (["check", "--filter", "{tmp}/file.py"], "has no function init_landmarks or predict"),
    ],
)  # fmt: skip
def test_bad_input_of_grade_and_check_is_one_line(
    tmp_path: Path, args: list[str], expected: str
) -> None:
    (tmp_path / "file.py").write_text("x = 1\n")
    (tmp_path / "empty").mkdir()
    students.write(tmp_path / "class" / "ada", "correct")
    result = ekfviz(*[a.format(tmp=tmp_path) for a in args])
    assert result.returncode == 2, result.stdout + result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("error: ") and expected.format(tmp=tmp_path) in line, line


# -- students of the wild (hand-ins in styles no handout shows) ------------------


def test_without_all_the_students_own_mistake_follows_the_handouts(tmp_path: Path) -> None:
    module = students.write(tmp_path / "s", "return_in_loop")
    report = tmp_path / "r.json"
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module), "--report",
                    str(report))  # fmt: skip
    assert result.returncode == 1, result.stdout + result.stderr
    assert "the handout's main() builds it, block_diag(pose_cov, landmark_cov)" in result.stdout
    following = result.stdout[
        result.stdout.index("next divergence (not explained by the first one's causes)") :
    ]
    assert following.startswith(
        "next divergence (not explained by the first one's causes) at event 2 (step 1, update"
    )
    assert f"cause: {resolve('only_first_landmark')}" in following
    assert re.search(r"\n  28 more event\(s\) diverge", result.stdout)
    document = json.loads(report.read_text())
    assert document["first_divergence"]["cause"] == resolve("independent_landmark_init")
    assert document["next_divergence"]["cause"] == resolve("only_first_landmark")
    assert document["next_divergence"]["event"] == 2
    # a correct module has nothing after the handout's initialisation
    correct = students.write(tmp_path / "c", "correct")
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(correct))
    assert "next divergence" not in result.stdout and "more event(s)" not in result.stdout


def test_an_integer_array_is_named_by_its_whole_numbers(tmp_path: Path) -> None:
    module = students.write(tmp_path / "s", "int_landmarks")
    report = tmp_path / "r.json"
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module), "--report",
                    str(report))  # fmt: skip
    assert result.returncode == 1, result.stderr
    first = json.loads(report.read_text())["first_divergence"]
    assert first["cause"] == "unknown" and first["event"] == 0
    # landmark 1 of the classic log is at (2.97985, 5.96792): truncated to (2, 5)
    assert "x[L1.x] = 2 (expected 2.97985), x[L1.y] = 5 (expected 5.96792)" in first["hint"]
    assert "integer array" in first["hint"] and "make it float" in first["hint"]
    assert (
        "Differs: " in first["hint"]
        and "landmark mean at landmarks 1, 2, 3, 4, ..." in (first["hint"])
    )


def test_the_parts_that_differ_are_listed_with_their_landmarks() -> None:
    from ekfviz.check.lockstep import differing_blocks, whole_numbers
    from ekfviz.check.rerun import State

    x = np.array([1.0, 2.0, 0.5, 3.5, 4.25, -1.5, 2.75])
    P = np.eye(7) * 0.1
    expected = State(x, P, np.array([7, 9]))
    # the filter holds its landmarks in the other order: compared by id
    got_x = np.array([1.0, 2.0, 0.5, -1.5, 2.75, 3.0, 4.25])
    got_P = P.copy()
    got_P[0, 3] = got_P[3, 0] = 0.02  # x with landmark 9's x
    got = State(got_x, got_P, np.array([9, 7]))
    assert differing_blocks(expected, got, 1e-6) == (
        "pose-landmark cross-covariance at landmark 9; landmark mean at landmark 7"
    )
    assert whole_numbers(expected, got, 1e-6) == ["x[L7.x] = 3 (expected 3.5)"]
    assert differing_blocks(expected, expected, 1e-6) == ""
    assert differing_blocks(expected, State(x[:5], P[:5, :5], np.array([7])), 1e-6) == ""


def test_a_new_landmarks_position_is_said_in_metres_where_nothing_explains_it() -> None:
    """A divergence no mutation reproduces names the first operation that differs and
    its numbers in their units: a new landmark's position, or a known one's innovation as
    the filter's change of the mean implies it."""
    from ekfviz.check.rerun import Noise, Rerun, State, Step
    from ekfviz.check.unknown import unexplained
    from ekfviz.core.params import FilterParams

    params = FilterParams()
    noise = Noise(params.Q, params.R)
    before = State(np.zeros(3), np.diag([1e-4, 1e-4, 1e-2]), np.zeros(0, dtype=np.int64))
    step = Step(ids=np.array([4]), z=np.array([[0.1, 5.0]]))
    expected = Rerun(noise).run(before, step)
    x = expected.x.copy()
    x[3:] += (0.3, -0.2)  # 30 cm east, 20 cm south of where the reference puts it
    found = unexplained(noise, before, State(x, expected.P, expected.ids), step, 1e-6)
    assert found is not None and found.operation == "landmark_position"
    assert found.units == ("m", "m")
    assert np.allclose(np.subtract(found.got, found.expected), (0.3, -0.2))
    assert "a new landmark's position differs first: new landmark 4's position" in found.sentence()
    # a known landmark whose innovation's bearing is pi off (an arctan behind the robot)
    known = Rerun(noise).run(before, step)
    seen = Step(ids=np.array([4]), z=np.array([[0.12, 5.1]]))
    right = Rerun(noise).run(known, seen)
    K_like = right.x - known.x  # the reference's correction; the filter's goes the other way
    wrong = State(known.x - 40.0 * K_like, right.P, right.ids)
    found = unexplained(noise, known, wrong, seen, 1e-6)
    assert found is not None and found.operation == "innovation" and found.implied
    assert found.units == ("rad", "m")
    assert "landmark 4's innovation (bearing, range)" in found.of


def test_solutions_that_do_not_run_get_the_line_of_their_own_file(tmp_path: Path) -> None:
    order = students.write(tmp_path / "order", "p_x_order")
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(order))
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "predict returned (P, X), expected (X, P): its first value has shape (15, 15)" in line
    size = students.write(tmp_path / "size", "q_wrong_size")
    number = students.source("q_wrong_size").splitlines().index(
        "    P_pre = G @ P @ G.T + control_cov") + 1  # fmt: skip
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(size))
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert line.endswith(
        f"predict raised ValueError: operands could not be broadcast together with shapes"
        f" (15,15) (3,3) (at ekf_slam.py:{number} in predict: P_pre = G @ P @ G.T + control_cov)"
    ), line


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (("    return X, P\n", "    pass\n"),
         "update returned None (no return statement?), expected (X, P)"),
        (("    X, P = X_pre.copy(), P_pre.copy()\n", "    raise NotImplementedError\n"),
         "update raised NotImplementedError (at ekf_slam.py:{line} in update:"
         " raise NotImplementedError)"),
        # numpy >= 1.24's message runs over several lines: one line of it
        (("np.zeros((2 * k, 1))", "np.zeros((2 * k, 1), dtype=np.float)"),
         "init_landmarks raised AttributeError: module 'numpy' has no attribute 'float'."
         " `np.float` was a deprecated alias for the builtin `float`."),
        # numpy 1's float() of an array of one element: numpy 2 refuses it (in either
        # shape of the control, so that no other convention runs it)
        (("d, alpha = control[0, 0], control[1, 0]",
          "d, alpha = float(control[0:1]), float(control[1:2])"),
         "predict raised TypeError: only 0-dimensional arrays can be converted to Python"
         " scalars (at ekf_slam.py:{line} in predict: d, alpha = float(control[0:1]),"
         " float(control[1:2])) (float() or int() of an array of one element, such as"
         " control[0] of a (2, 1) column:"),
        # the gain of every landmark from the predicted P, the correction of the current one
        (("S = H @ P @ H.T + measure_cov\n        K = P @ H.T",
          "S = H @ P_pre @ H.T + measure_cov\n        K = P_pre @ H.T"),
         "after update, P is not symmetric (|P - P^T| up to 0.345, 0.319 of its largest"
         " entry; at most 1e-09): the corrected covariance (I - K H) P (or P - K S K^T, or"
         " Joseph's form) is symmetric only with K = P H^T S^-1 of that same P and H: is a"
         " factor missing (P - K H, or K without S^-1), or K made from another P (P_pre"
         " inside a loop over the landmarks)?"),
    ],
)  # fmt: skip
def test_an_unfinished_update_is_one_line(
    tmp_path: Path, edit: tuple[str, str], expected: str
) -> None:
    text = students.source("correct").replace(*edit)
    module = tmp_path / "ekf_slam.py"
    module.write_text(text)
    line = next((n for n, code in enumerate(text.splitlines(), 1) if edit[1].strip() in code), 0)
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module))
    assert result.returncode == 2
    (said,) = result.stderr.strip().splitlines()
    assert expected.format(line=line) in said, said


def test_the_handouts_main_at_import_is_skipped_and_said(tmp_path: Path) -> None:
    module = tmp_path / "hw2.py"
    module.write_text(students.source("return_in_loop") + students.MAIN_AT_IMPORT)
    number = module.read_text().splitlines().index("main()") + 1
    report = tmp_path / "r.json"
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module), "--report",
                    str(report))  # fmt: skip
    assert result.returncode == 1, result.stderr
    assert f"its line {number} calls main() at import (no `if __name__" in result.stderr
    assert "FileNotFoundError" in result.stderr and "ekfviz skipped it and" in result.stderr
    assert json.loads(report.read_text())["next_divergence"]["cause"] == resolve(
        "only_first_landmark"
    )
    # a script: the handout's loop at top level, and a constant after it
    script = tmp_path / "script.py"
    loop = 'data_file = open("../data/data.txt")\nfor line in data_file:\n    print(line)\n'
    script.write_text(students.source("correct") + loop + "SIGMA = 0.1\n")
    number = script.read_text().splitlines().index('data_file = open("../data/data.txt")') + 1
    result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(script))
    assert result.returncode == 1, result.stderr
    assert f"its line {number} runs at import" in result.stderr
    assert f"ekfviz skipped it (and line {number + 1}) and loaded the rest" in result.stderr
    # an import that fails, or a raise, is the error, in one line
    for code, said in (("import no_such_module_h14", "raised ModuleNotFoundError: No module"
                        " named 'no_such_module_h14'"),
                       ("raise RuntimeError('not finished')", "raised RuntimeError: not"
                        " finished")):  # fmt: skip
        broken = tmp_path / "broken.py"
        broken.write_text(module.read_text() + code + "\n")
        result = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(broken))
        assert result.returncode == 2
        (line,) = result.stderr.strip().splitlines()
        assert said in line, line


@pytest.mark.slow  # a whole class again (each kind of row is graded by default above)
def test_grade_of_wild_students_names_each_ones_mistake(tmp_path: Path) -> None:
    folder = tmp_path / "class"
    students.write(folder / "ada", "stale_linearisation")
    (folder / "bob.py").write_text(students.class_based())
    students.write(folder / "cy", "control_swapped")
    students.write(folder / "eve", "r_thrice")
    # a mistake of no family (R plus a constant in S): its row says unknown
    students.write(folder / "dee", "correct").write_text(
        students.source("correct").replace(
            "S = H @ P @ H.T + measure_cov", "S = H @ P @ H.T + measure_cov + 0.01"
        )
    )
    result = ekfviz("grade", str(folder), "--json")
    assert result.returncode == 0, result.stderr
    rows = {row["submission"]: row for row in json.loads(result.stdout)["submissions"]}
    assert {name: row["status"] for name, row in rows.items()} == {
        "ada": "diverged", "bob.py": "diverged", "cy": "diverged", "dee": "diverged",
        "eve": "diverged",
    }  # fmt: skip
    # a correct module's causes, and divergences of no known cause: "unknown", last, tells
    # the two apart in the causes column too
    assert rows["dee"]["causes"][-1] == "unknown"
    assert set(rows["dee"]["causes"]) == _resolved("correct") | {"unknown"}
    assert re.fullmatch(
        r"\d+ divergent event\(s\) of no known cause, the first classic:3"
        r" event 2 \(update\): .+",
        rows["dee"]["detail"],
    ), rows["dee"]
    assert rows["bob.py"]["detail"] == "" and rows["ada"]["detail"] == ""
    assert set(rows["ada"]["causes"]) == _resolved("stale_linearisation")
    # the class's methods are the handout's functions: the correct module's verdict
    assert set(rows["bob.py"]["causes"]) == _resolved("correct")
    assert set(rows["cy"]["causes"]) == _resolved("control_swapped")
    assert set(rows["eve"]["causes"]) == _resolved("r_thrice")  # R used 3 times too large


def test_pairs_of_update_mutations_re_run_on_a_line_of_known_and_new() -> None:
    """Mutations of an update and an initialisation, alone and in pairs (a sample), re-run
    on a line of known and new landmarks: a state of the line's landmarks, or one of the
    errors a re-run may raise (a mutation that does not fit the state)."""
    import itertools
    import random

    from ekfviz.check.mutations import MUTATIONS
    from ekfviz.check.rerun import FORMS, RERUN_ERRORS, Form, Noise, Rerun, State, Step

    x = np.array([1.0, 2.0, 0.3, 6.0, 5.0, -2.0, 4.0])
    before = State(x, np.diag(np.linspace(0.1, 0.7, 7)), np.array([3, 8]))
    step = Step(ids=np.array([8, 5, 3]), z=np.array([[2.4, 4.9], [0.2, 7.0], [0.5, 6.0]]))
    noise = Noise(np.diag([0.0625, 0.01, 0.01]), np.diag([0.01, 0.04]))
    chosen = [m for m in MUTATIONS if m.event != "predict" and m.family not in ("own", "form")]
    pairs = [p for p in itertools.combinations(chosen, 2) if p[0].operation != p[1].operation]
    sample = [(m,) for m in chosen] + random.Random(7).sample(pairs, 300)
    ran = 0
    for mutations in sample:
        for form in (*FORMS, Form(True)):
            try:
                after = Rerun.with_mutations(noise, mutations, form, None).run(before, step)
            except RERUN_ERRORS:
                continue
            ran += 1
            assert sorted(after.ids.tolist()) == [3, 5, 8], mutations
            assert after.P.shape == (9, 9), mutations
    assert ran > 0.8 * 4 * len(sample)


def _resolved(name: str) -> set[str]:
    """The causes a student of :data:`students.MISTAKES` must be named by, as today's ids."""
    return {resolve(cause) for cause in students.MISTAKES[name]}


def test_debug_shows_the_student_s_own_traceback(tmp_path: Path) -> None:
    """``--debug`` showed ekfviz's own frames (replay) or nothing more (check): the
    student's code ran in the worker, and its traceback was kept but never shown."""
    module = tmp_path / "ekf_slam.py"
    module.write_text(
        students.source("correct").replace(
            "    X, P = X_pre.copy(), P_pre.copy()\n",
            "    X, P = X_pre.copy(), P_pre.copy()\n    X[99, 0] = 1.0\n",
        )
    )
    for command in ("check", "replay"):
        args = ["--debug", command, str(DATA / "classic.txt"), "--filter", str(module)]
        if command == "replay":
            args += ["--save", str(tmp_path / "run.rrd")]
        result = ekfviz(*args)
        assert result.returncode != 0
        said = result.stderr.split("the filter's own traceback, in its worker:\n", 1)
        assert len(said) == 2, (command, result.stderr)
        assert f'File "{module}", line' in said[1] and "X[99, 0] = 1.0" in said[1], said[1]
    plain = ekfviz("check", str(DATA / "classic.txt"), "--filter", str(module))
    assert "own traceback" not in plain.stderr
