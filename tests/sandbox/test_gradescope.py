"""``grade --gradescope`` and the autograder zip: the zip unpacked into a fake
``/autograder`` tree and its ``run_autograder`` run there (as Gradescope runs it, ``setup.sh``
aside) for a correct and a buggy course module; the ``results.json`` read against
Gradescope's documented fields."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import students
from typer.testing import CliRunner

from ekfviz.app.gradescope import DEFAULT_RUBRIC, ROOT_VARIABLE, read_rubric
from ekfviz.cli import app

ROOT = Path(__file__).parents[2]
runner = CliRunner()
TEST_FIELDS = {"name", "score", "max_score", "status", "output", "visibility"}


@pytest.fixture(scope="module")
def unpacked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The autograder zip of the default rubric, unpacked as Gradescope does: its
    ``/autograder/source``."""
    folder = tmp_path_factory.mktemp("zip")
    result = runner.invoke(app, ["grade", "--gradescope-zip", str(folder / "autograder.zip")])
    assert result.exit_code == 0, result.output
    source = folder / "autograder" / "source"
    with zipfile.ZipFile(folder / "autograder.zip") as archive:
        names = set(archive.namelist())
        assert {"setup.sh", "run_autograder", "rubric.toml"} <= names
        assert {"ekfviz-src/pyproject.toml", "ekfviz-src/ekfviz/sandbox/child.py"} <= names
        archive.extractall(source)
        for name in ("setup.sh", "run_autograder"):  # (extractall drops the mode)
            mode = archive.getinfo(name).external_attr >> 16
            assert mode & stat.S_IXUSR, name
            (source / name).chmod(mode & 0o777)
    return source.parent


def run_autograder(root: Path, student: str, tmp_path: Path) -> dict[str, object]:
    """Gradescope's run of one submission in the tree ``root``: its results."""
    tree = tmp_path / "autograder"
    (tree / "submission").mkdir(parents=True)
    (tree / "source").symlink_to(root / "source")
    students.write(tree / "submission", student)
    env = {**os.environ, ROOT_VARIABLE: str(tree), "CI": "1", "XDG_CONFIG_HOME": str(tmp_path),
           "XDG_DATA_HOME": str(tmp_path),
           "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}  # fmt: skip
    done = subprocess.run([str(tree / "source" / "run_autograder")], capture_output=True,
                          text=True, env=env, cwd=tree, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return dict(json.loads((tree / "results" / "results.json").read_text()))


@pytest.mark.slow
def test_a_correct_module_gets_full_marks(unpacked: Path, tmp_path: Path) -> None:
    results = run_autograder(unpacked, "correct", tmp_path)
    tests = results["tests"]
    assert isinstance(tests, list) and len(tests) == 6
    for test in tests:
        assert set(test) == TEST_FIELDS, test
        assert test["status"] == "passed" and test["score"] == test["max_score"], test
    assert results["score"] == 100
    assert isinstance(results["execution_time"], int)
    assert "sandbox" in str(results["output"])


def test_a_buggy_module_loses_the_part_its_mistake_is_in_and_is_told_why(
    unpacked: Path, tmp_path: Path
) -> None:
    results = run_autograder(unpacked, "transposed", tmp_path)
    tests = {test["name"]: test for test in results["tests"]}  # type: ignore[union-attr]
    prediction = tests["Prediction"]
    assert prediction["status"] == "failed" and prediction["score"] == 0
    assert "Cause: motion_jacobian.transposed" in prediction["output"]
    assert "Hint: " in prediction["output"]
    assert tests["Landmark initialisation"]["status"] == "passed"
    assert results["score"] == sum(t["score"] for t in tests.values()) < 100


def test_the_sample_rubric_is_the_default_and_a_bad_one_is_one_line(tmp_path: Path) -> None:
    assert (ROOT / "examples" / "rubric.toml").read_text() == DEFAULT_RUBRIC
    assert [p.kind for p in read_rubric(ROOT / "examples" / "rubric.toml").parts] == [
        "init", "predict", "update", "log", "log", "consistency"]  # fmt: skip
    bad = tmp_path / "bad.toml"
    bad.write_text('[grade]\n[[part]]\nname = "x"\nkind = "everything"\n')
    (tmp_path / "submission").mkdir()
    result = runner.invoke(app, ["grade", "--gradescope", "--rubric", str(bad), "--submission",
                                 str(tmp_path / "submission"), "--results",
                                 str(tmp_path / "results.json")])  # fmt: skip
    assert result.exit_code == 2
    (line,) = result.output.strip().splitlines()
    assert "part 1 kind = 'everything': expected one of init, predict" in line
    assert not (tmp_path / "results.json").exists()


def test_a_rubric_accepts_a_cause_by_either_name_and_refuses_one_check_never_names(
    tmp_path: Path,
) -> None:
    from ekfviz.app.gradescope import RubricError

    rubric = tmp_path / "rubric.toml"
    part = '[[part]]\nname = "x"\nkind = "init"\npoints = 1\ntimeout = 5\nlog = "classic"\n'
    rubric.write_text('[grade]\naccept = ["transposed_motion_jacobian"]\n' + part)
    assert read_rubric(rubric).accept == ("motion_jacobian.transposed",)
    rubric.write_text('[grade]\naccept = ["motion_jacobian.sideways"]\n' + part)
    with pytest.raises(RubricError, match=r"accept: motion_jacobian\.sideways is not a cause"):
        read_rubric(rubric)


@pytest.mark.slow
def test_each_part_has_its_own_time(tmp_path: Path) -> None:
    """An update that never returns zeroes its own parts, not the prediction's."""
    submission = tmp_path / "submission"
    module = students.write(submission, "correct")
    endless = "def update(*a):\n    while True:\n        pass\n\n\ndef unused_update("
    module.write_text(module.read_text().replace("def update(", endless, 1))
    rubric = tmp_path / "rubric.toml"
    rubric.write_text(
        "[grade]\n"
        '[[part]]\nname = "P"\nkind = "predict"\npoints = 1\ntimeout = 30\n'
        '[[part]]\nname = "U"\nkind = "update"\npoints = 1\ntimeout = 3\n'
    )
    result = runner.invoke(app, ["grade", "--gradescope", "--rubric", str(rubric),
                                 "--submission", str(submission), "--results",
                                 str(tmp_path / "r.json")])  # fmt: skip
    assert result.exit_code == 0, result.output
    tests = json.loads((tmp_path / "r.json").read_text())["tests"]
    assert [(t["name"], t["status"]) for t in tests] == [("P", "passed"), ("U", "failed")]
    assert "time" in tests[1]["output"]


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--gradescope", "--timeout", "5"], "--gradescope does not take --timeout: a rubric"),
        (["--gradescope-zip", "z.zip", "--report", "g.csv"], "does not take --report"),
        (["class", "--rubric", "r.toml"], "--rubric is for --gradescope"),
    ],
)
def test_a_class_s_options_and_gradescope_s_do_not_mix(
    tmp_path: Path, args: list[str], said: str
) -> None:
    result = runner.invoke(app, ["grade", *args])
    assert result.exit_code == 2
    (line,) = result.output.strip().splitlines()
    assert said in line, line
