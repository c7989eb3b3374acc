"""The bring-your-own-filter example runs and records what its filter computed."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from conftest import entity_rows

from ekfviz.core.types import FloatArray
from ekfviz.viz import Recorder, style

EXAMPLE = Path(__file__).parents[2] / "examples" / "byof_minimal.py"


def test_example_runs_and_records_a_full_run(tmp_path: Path) -> None:
    out = tmp_path / "byof.rrd"
    result = subprocess.run(
        [sys.executable, str(EXAMPLE), str(out)],
        capture_output=True,
        text=True,
        env=os.environ.copy(),
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    robot = entity_rows(out, f"/{style.ROBOT}")
    # the classic run: the initialisation, then 29 predicts and 29 updates
    assert [row["event"] for row in robot] == list(range(59))
    assert [row["step"] for row in robot] == [0] + [k for k in range(1, 30) for _ in (0, 1)]
    landmarks = entity_rows(out, f"/{style.LANDMARKS}")
    assert landmarks[-1]["Points2D:class_ids"] == [1, 2, 3, 4, 5, 6]
    nis = entity_rows(out, f"/{style.NIS}")
    assert len(nis) == 29 and all(np.isfinite(row["Scalars:scalars"]).all() for row in nis)  # type: ignore[call-overload]
    initial = entity_rows(out, f"/{style.LANDMARK_INITIAL}")
    assert [row["event"] for row in initial] == [0]


def test_counters_of_the_array_api(tmp_path: Path) -> None:
    """Step +1 per predict, or per update when the step already had one; event +1 per call."""
    out = tmp_path / "counters.rrd"
    rec = rr.RecordingStream("counters")
    rec.save(out)
    recorder = Recorder(rec, blueprint=False)
    x: FloatArray = np.array([0.0, 0.0, 0.0, 1.0, 1.0])
    P: FloatArray = np.eye(5) * 0.01
    z = np.array([[0.7, 1.4]])
    recorder.initialise(x[:3], P[:3, :3])
    recorder.update(x, P, landmark_ids=[7], z=z)  # a step of its own: step 0 had its update
    recorder.predict(x, P, control=(1.0, 0.0))
    recorder.update(x, P, landmark_ids=[7], z=z, z_pred=z, S=np.eye(2)[None] * 0.01)
    recorder.update(x, P, landmark_ids=[7], z=z)
    recorder.finish()
    rec.disconnect()
    rows = entity_rows(out, f"/{style.ROBOT}")
    assert [(row["event"], row["step"]) for row in rows] == [(0, 0), (1, 1), (2, 2), (3, 2), (4, 3)]
    landmarks = entity_rows(out, f"/{style.LANDMARKS}")
    assert landmarks[-1]["Points2D:class_ids"] == [7]
    initial = entity_rows(out, f"/{style.LANDMARK_INITIAL}")
    assert [row["event"] for row in initial] == [1]  # id 7 was new there, and only there
    nis = entity_rows(out, f"/{style.NIS}")
    assert [row["Scalars:scalars"] for row in nis] == [[0.0]]


def test_your_filters_covariance_is_checked_and_its_faults_logged(tmp_path: Path) -> None:
    """A filter of one's own whose update breaks P: the recording says so, at that event."""
    out = tmp_path / "broken.rrd"
    rec = rr.RecordingStream("broken")
    rec.save(out)
    recorder = Recorder(rec, blueprint=False)
    x: FloatArray = np.array([0.0, 0.0, 0.0, 1.0, 1.0])
    P: FloatArray = np.eye(5) * 0.01
    recorder.initialise(x, P, landmark_ids=[1], z=np.array([[0.78, 1.41]]))
    recorder.predict(x, P, control=(0.0, 0.0))
    P_asymmetric = P.copy()
    P_asymmetric[0, 3] = 0.002  # the typical slip: K H P written without its transpose
    recorder.update(x, P_asymmetric, landmark_ids=[1], z=np.array([[0.78, 1.41]]))
    P_indefinite = P.copy()
    P_indefinite[3, 3] = -0.01
    recorder.predict(x, P_indefinite, control=(0.0, 0.0))
    recorder.finish()
    rec.disconnect()
    warned = [
        (row["event"], str(row["TextLog:text"]))
        for row in entity_rows(out, f"/{style.LOG}")
        if row["TextLog:level"] == ["WARN"]
    ]
    assert [event for event, _ in warned] == [2, 3]
    assert "not symmetric (|P - P^T| up to 0.002," in warned[0][1]
    assert "not positive semi-definite" in warned[1][1]
    asymmetry = entity_rows(out, f"/{style.HEALTH_P_ASYMMETRY}")
    assert [row["Scalars:scalars"] for row in asymmetry] == [[0.0], [0.0], [0.002], [0.0]]
    landmark = entity_rows(out, f"/{style.HEALTH_LANDMARK_MIN_EIG}")
    assert [row["Scalars:scalars"] for row in landmark] == [[0.01], [0.01]]


def test_the_array_api_says_what_is_wrong_with_what_it_is_handed(tmp_path: Path) -> None:
    """A P of the wrong shape was numpy's broadcast error, a 1-D P a LinAlgError, ids and
    z of different lengths "cannot reshape array of size 4 into shape (1,2)", an array of
    ids "the truth value of an array ... is ambiguous"; an x of shape (7, 3), a control
    of three numbers and a P of NaN failed only at finish(), long after the call."""

    rec = rr.RecordingStream("mine")
    rec.save(tmp_path / "mine.rrd")
    recorder = Recorder(rec, blueprint=False, landmark_ids=np.array([7, 8]))
    x, P = np.zeros(7), np.eye(7)
    recorder.initialise(x[:, None], P)  # a column x is taken
    cases: list[tuple[Callable[[], None], str]] = [
        (lambda: recorder.predict(x, np.eye(6)), r"^P has shape \(6, 6\), expected \(7, 7\)"),
        (lambda: recorder.predict(x, np.ones(7)), r"^P has shape \(7,\), expected \(7, 7\)"),
        (lambda: recorder.predict(np.zeros((7, 3)), P), r"^x has shape \(7, 3\), expected"),
        (lambda: recorder.predict(x, P, control=(1.0, 0.0, 0.5)), r"^control has shape \(3,\)"),
        (lambda: recorder.predict(x, np.full((7, 7), np.nan)), r"^P is not finite"),
        (lambda: recorder.update(x, P, landmark_ids=[7], z=np.zeros(4)),
         r"^z has 4 numbers, expected 1 \(bearing, range\) pairs"),
        (lambda: recorder.update(x, P, landmark_ids=[2**64], z=np.zeros(2)),
         r"^landmark_ids: expected 64-bit integers"),
    ]  # fmt: skip
    for call, said in cases:
        with pytest.raises(ValueError, match=said):
            call()
    recorder.predict(x, P, control=(1.0, 0.0))  # the recording goes on
    recorder.finish()
    rec.disconnect()
