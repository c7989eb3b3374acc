"""Start-up and speed without timing: what a command imports, how the command line
leaves, and the model filter's deferred update against the textbook one.

Timings live in ``make bench`` (benchmarks/RESULTS.md); these tests check the causes:
the modules a classic replay imports, pyarrow's pandas question answered without pandas,
and the same numbers from the faster update.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ekfviz import startup
from ekfviz.core.params import FilterParams
from ekfviz.filters.ekf import DEFER_MIN_DIM
from ekfviz.filters.model_ekf import ModelEkfSlam
from ekfviz.models.angles import wrap_angle
from ekfviz.models.range_bearing import RangeBearing

ROOT = Path(__file__).resolve().parents[2]

# Runs the command line as the `ekfviz` script does; at its exit (the command line's
# own, which runs the exit handlers) writes, as JSON, what STATE evaluates to then.
AT_EXIT = """
import atexit, gc, json, sys
out = sys.argv.pop(1)
def dump():
    with open(out, "w") as handle:
        json.dump(STATE, handle)
atexit.register(dump)
sys.argv = ["ekfviz", *sys.argv[1:]]
from ekfviz.__main__ import main
main()
"""


def _classic_replay_at_exit(tmp_path: Path, state: str) -> tuple[object, str]:
    """``state`` (an expression) at the exit of a classic replay, and its stdout."""
    found, recording = tmp_path / "state.json", tmp_path / "run.rrd"
    done = subprocess.run(
        [sys.executable, "-c", AT_EXIT.replace("STATE", state), str(found), "replay",
         str(ROOT / "data" / "classic.txt"), "--save", str(recording)],
        env=_env(tmp_path), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert recording.stat().st_size > 0
    return json.loads(found.read_text()), done.stdout


# never needed by a replay of a classic log with ids: each costs start-up time
NOT_IMPORTED = (
    "pandas",
    "gtsam",
    "dask",
    "distributed",
    "matplotlib",
    "scipy",
    "rerun.dataframe",
    "pyarrow.dataset",
    "ekfviz.filters.gtsam",
    "typer.rich_utils",  # typer's help pages and boxed errors, with rich's markdown
    "markdown_it",
    "pygments",
    "pydantic",  # typer 0.29's per-parameter adapters (pyproject keeps typer below it)
    "ekfviz.studies.runs",  # a study's runs
    "ekfviz.association.associator",  # the association of id-less scans, and its view
    "ekfviz.association.jcbb",
    "ekfviz.viz.association",
    "pyarrow.compute",  # what the SDK's casts and masked list arrays import (30-45 ms)
    "importlib.resources",  # importlib.abc's (17 ms): a finder needs no base class
    "ekfviz.sandbox.host",  # a user's filter's worker: ekfviz's own runs in process
    "ekfviz.sandbox.remote",
    "ekfviz.sandbox.bwrap",
    "ekfviz.sandbox.submission",
)


def _env(tmp_path: Path) -> dict[str, str]:
    return dict(os.environ, XDG_CONFIG_HOME=str(tmp_path), XDG_DATA_HOME=str(tmp_path), CI="1")


def test_a_classic_replay_imports_nothing_it_does_not_use(tmp_path: Path) -> None:
    modules, stdout = _classic_replay_at_exit(tmp_path, "sorted(sys.modules)")
    assert "Final pose" in stdout  # the whole output came through the fast exit
    imported = set(modules)  # type: ignore[call-overload]
    assert "rerun" in imported and "pyarrow" in imported  # it did record
    assert sorted(m for m in imported if m.split(".")[0] in NOT_IMPORTED or m in NOT_IMPORTED) == []


def test_the_command_line_collects_garbage_less_often_with_its_imports_set_apart(
    tmp_path: Path,
) -> None:
    state, _ = _classic_replay_at_exit(
        tmp_path, '{"threshold": gc.get_threshold(), "frozen": gc.get_freeze_count()}'
    )
    assert isinstance(state, dict)
    assert state["threshold"][0] == startup.GC_YOUNG > 700  # Python's default: 700
    assert state["frozen"] > 10_000  # the imported modules' objects


def test_pyarrow_hears_pandas_is_absent_and_pandas_stays_importable(tmp_path: Path) -> None:
    """pyarrow's one question (asked at its import) is answered "absent" without pandas
    being imported; conversions whose type is stated (as ekfviz states its own, see
    ekfviz.viz.recording.any_values) never import it; pandas itself still imports."""
    code = """
import sys
from ekfviz import startup
startup.pyarrow_without_pandas()
import pyarrow as pa
assert pa.lib._pandas_api.have_pandas is False
assert pa.array([1.0, None], type=pa.float64()).null_count == 1
assert pa.array(["a", "b"], type=pa.string()).to_pylist() == ["a", "b"]
assert "pandas" not in sys.modules, "pyarrow imported pandas"
try:
    import pandas
except ImportError:  # not installed here: nothing more to check
    print("no pandas")
else:
    assert pandas.DataFrame({"a": [1]}).shape == (1, 1)
    print("pandas", pandas.__version__)
"""
    done = subprocess.run(
        [sys.executable, "-c", code], env=_env(tmp_path), capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert "pandas" in done.stdout


def test_without_the_answer_pyarrow_imports_pandas_if_installed(tmp_path: Path) -> None:
    """The check above can fail: left to itself, pyarrow's first conversion of a list
    imports pandas where it is installed."""
    code = (
        "import sys, importlib.util\n"
        "import pyarrow as pa\n"
        "pa.array([1.0], type=pa.float64())\n"
        "print(importlib.util.find_spec('pandas') is None or 'pandas' in sys.modules)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], env=_env(tmp_path), capture_output=True, text=True
    )
    assert done.stdout.strip() == "True", done.stderr


@pytest.mark.parametrize("code", [0, 2])
def test_the_command_line_exits_with_the_commands_code(tmp_path: Path, code: int) -> None:
    log = ROOT / "data" / "classic.txt" if code == 0 else tmp_path / "missing.txt"
    done = subprocess.run(
        [sys.executable, "-m", "ekfviz", "replay", str(log), "--save", str(tmp_path / "r.rrd")],
        env=_env(tmp_path), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == code, done.stderr
    if code:
        assert done.stderr.strip().splitlines() == [
            f"error: {log}: no such file, expected a text file"
        ]
    else:
        assert (tmp_path / "r.rrd").stat().st_size > 0


def _textbook_update(
    x: np.ndarray,
    P: np.ndarray,
    slots: list[int],
    z: np.ndarray,
    sensor: RangeBearing,
    R: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Sequential EKF updates with the dense H and gain, one landmark after another."""  # fmt: skip
    x, P = x.copy(), P.copy()
    n = len(x)
    for j, z_k in zip(slots, z, strict=True):
        z_pred = sensor.measure(x[:3], x[j : j + 2])
        H_pose, H_landmark = sensor.jacobians(x[:3], x[j : j + 2])
        H = np.zeros((2, n))
        H[:, :3], H[:, j : j + 2] = H_pose, H_landmark
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        nu = z_k - z_pred
        nu[0] = wrap_angle(float(nu[0]))
        x = x + K @ nu
        x[2] = wrap_angle(float(x[2]))
        P = P - K @ S @ K.T
    return x, P


def test_the_model_filters_deferred_update_is_the_textbook_sequential_one() -> None:
    """A state past DEFER_MIN_DIM (the deferred path), an offset sensor, 12 landmarks of
    one line folded in: the same x and P as dense updates one after another."""
    rng = np.random.default_rng(7)
    sensor = RangeBearing(a=3.78, b=0.5)
    n_landmarks = DEFER_MIN_DIM  # dim 3 + 2N, well past DEFER_MIN_DIM
    slam = ModelEkfSlam(FilterParams(), sensor=sensor)
    ids = list(range(1, n_landmarks + 1))
    truth = rng.uniform(-30.0, 30.0, size=(n_landmarks, 2))
    pose = np.zeros(3)
    z0 = np.array([sensor.measure(pose, xy) for xy in truth])
    slam.observe(ids, z0 + rng.normal(0.0, [0.01, 0.05], size=z0.shape))
    slam.predict(1.0, 0.1)
    assert slam.dim >= DEFER_MIN_DIM
    x0, P0 = slam.x.copy(), slam.P.copy()
    seen = [int(i) for i in rng.choice(ids, size=12, replace=False)]
    moved = np.array([1.0, 0.0, 0.1])
    z = np.array([sensor.measure(moved, truth[i - 1]) for i in seen])
    z += rng.normal(0.0, [0.01, 0.05], size=z.shape)
    slam.observe(seen, z)
    slots = [3 + 2 * slam.landmark_ids.index(i) for i in seen]
    x, P = _textbook_update(x0, P0, slots, z, sensor, FilterParams().R)
    np.testing.assert_allclose(slam.x, x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(slam.P, P, rtol=0, atol=1e-9 * float(np.abs(P).max()))
    assert np.array_equal(slam.P, slam.P.T)  # exactly symmetric, as the filter promises
    assert math.isfinite(float(np.linalg.eigvalsh(slam.P)[0]))


def test_the_command_line_runs_blas_on_one_thread_unless_the_user_chose(
    tmp_path: Path,
) -> None:
    code = """
import os, sys
from ekfviz import startup
startup.one_blas_thread()
import numpy
print(" ".join(os.environ.get(name, "-") for name in startup.BLAS_THREADS))
"""
    env = {k: v for k, v in _env(tmp_path).items() if not k.endswith("_NUM_THREADS")}
    plain = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert plain.stdout.split() == ["1", "1", "1"], plain.stderr
    chosen = subprocess.run(
        [sys.executable, "-c", code], env={**env, "OMP_NUM_THREADS": "2"},
        capture_output=True, text=True,
    )  # fmt: skip
    assert chosen.stdout.split() == ["-", "2", "-"], chosen.stderr
    empty = subprocess.run(  # set to nothing: no number chosen (OpenBLAS would take all)
        [sys.executable, "-c", code], env={**env, "OPENBLAS_NUM_THREADS": ""},
        capture_output=True, text=True,
    )  # fmt: skip
    assert empty.stdout.split() == ["1", "1", "1"], empty.stderr


def test_after_import_adjusts_a_module_when_it_comes_and_only_then(tmp_path: Path) -> None:
    code = """
import sys
from ekfviz import startup
seen = []
startup.after_import("json.tool", lambda module: seen.append(module.__name__))
assert "json.tool" not in sys.modules and seen == []
import json.tool
assert seen == ["json.tool"], seen
startup.after_import("json.tool", lambda module: seen.append("again"))  # imported: now
assert seen == ["json.tool", "again"], seen
print("ok")
"""
    done = subprocess.run(
        [sys.executable, "-c", code], env=_env(tmp_path), capture_output=True, text=True
    )
    assert done.stdout.strip() == "ok", done.stderr
