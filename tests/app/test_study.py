"""sweep and compare in-process: one mechanism (ekfviz.app.study), their tables and
reports as data, what stopped them said."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import ekfviz.app.compare as compare_module
import ekfviz.app.sweep as sweep_module
from ekfviz.app import study
from ekfviz.app.compare import CompareRequest, compare
from ekfviz.app.errors import UsageError
from ekfviz.app.reporting import Silent
from ekfviz.app.settings import ExecutionSettings
from ekfviz.app.study import StudyRequest
from ekfviz.app.sweep import SweepRequest, sweep

DATA = Path(__file__).parents[2] / "data"
ONE_WORKER = ExecutionSettings(workers=1)


def test_compare_and_sweep_share_one_mechanism() -> None:
    shared = study.run_study
    assert vars(compare_module)["run_study"] is shared is vars(sweep_module)["run_study"]


def test_a_comparison_returns_its_table_and_writes_its_recording_and_report(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    request = StudyRequest(
        DATA / "classic.txt", DATA / "classic_truth.json", save=tmp_path / "c.rrd",
        report=tmp_path / "c.json", execution=ONE_WORKER,
    )  # fmt: skip
    outcome = compare(CompareRequest(request, ("ekf", "twin=ekf")), Silent())
    assert capfd.readouterr().out == ""
    assert [row[0] for row in outcome.table.rows] == ["ekf", "twin"]
    assert outcome.saved.startswith(f"Saved {tmp_path / 'c.rrd'}; open it with: ")
    filters = json.loads((tmp_path / "c.json").read_text())["filters"]
    assert filters[0]["final_pose"] == filters[1]["final_pose"]
    assert (tmp_path / "c.rrd").stat().st_size > 0


def test_a_sweep_without_variants_is_a_usage_error_and_writes_nothing(tmp_path: Path) -> None:
    request = StudyRequest(DATA / "classic.txt", save=tmp_path / "s.rrd", execution=ONE_WORKER)
    with pytest.raises(UsageError, match="nothing to vary"):
        sweep(SweepRequest(request), Silent())
    with pytest.raises(UsageError, match="give one or the other"):
        sweep(SweepRequest(request, vary=("sigma_x=x2",), preset=sweep_module.Preset.TUNING),
              Silent())  # fmt: skip
    assert list(tmp_path.iterdir()) == []
