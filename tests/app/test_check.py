"""The check use case in-process: a filter checked on a log or on the battery, the verdicts
and the report as data, nothing printed, and callable again in one process (as a front
end that checks a filter each time its file changes does)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ekfviz.app.check import CheckRequest, check, check_log
from ekfviz.app.errors import UsageError
from ekfviz.app.reporting import Silent
from ekfviz.core.params import FilterParams
from ekfviz.filters.spec import FilterSpec
from ekfviz.samples import BATTERY, sample_request, simulate_arguments

ROOT = Path(__file__).parents[2]
DATA = ROOT / "data"
PLUGINS = ROOT / "tests" / "plugins" / "textbook.py"


def test_a_correct_filter_matches_and_a_wrong_one_diverges_with_its_cause(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    log = DATA / "classic.txt"
    right = check(CheckRequest(f"{PLUGINS}:Textbook", data=log), Silent())
    wrong = check(CheckRequest(f"{PLUGINS}:NoRInS", data=log, report=tmp_path / "r.json"), Silent())
    assert capfd.readouterr().out == ""
    assert not right.diverged and not right.failed and right.logs[0].result.first_divergence is None
    assert wrong.diverged and not wrong.failed
    report = json.loads((tmp_path / "r.json").read_text())
    assert report == json.loads(json.dumps(wrong.report))
    assert report["match"] is False and "innovation_covariance.noise_missing" in report["causes"]
    assert wrong.logs[0].name == str(log)


def test_the_battery_is_the_bundled_classic_edge_and_midrun_logs(tmp_path: Path) -> None:
    outcome = check(CheckRequest(f"{PLUGINS}:Textbook", save=tmp_path / "b.rrd"), Silent())
    assert outcome.battery and [log.name for log in outcome.logs] == list(BATTERY)
    saved = sorted(p.name for p in tmp_path.iterdir())
    assert saved == ["b-classic.rrd", "b-edge.rrd", "b-midrun.rrd"]
    assert all(log.saved is not None and log.saved.startswith("Saved ") for log in outcome.logs)
    with pytest.raises(UsageError, match="the battery brings its own truth"):
        check(CheckRequest(f"{PLUGINS}:Textbook", truth=DATA / "classic_truth.json"), Silent())


def test_the_battery_is_what_the_command_line_writes_for_the_samples(tmp_path: Path) -> None:
    """The battery written through the use case (sample_request) and the samples of data/
    (written through the command line, simulate_arguments): one file each, byte for byte."""
    from ekfviz.app.simulate import simulate

    for stem in BATTERY:
        assert "--precision" in simulate_arguments(tmp_path, stem)
        written = simulate(sample_request(tmp_path, stem))
        for path in written.files:
            assert path.read_bytes() == (DATA / path.name).read_bytes(), path.name


def test_check_log_runs_again_and_again_in_one_process_into_the_sinks_given(
    tmp_path: Path,
) -> None:
    from ekfviz import viz
    from ekfviz.readback import read_recording_info

    spec = FilterSpec(f"{PLUGINS}:WrongJacobianSign")
    verdicts = []
    for k in range(2):
        result, coverage = check_log(
            DATA / "classic.txt", None, spec, FilterParams(), tolerance=1e-6, save=None,
            sinks=viz.Sinks(save=tmp_path / f"{k}.rrd"), command="a front end's own",
        )  # fmt: skip
        verdicts.append((result.to_json(), [item.to_json() for item in coverage]))
        info = read_recording_info(tmp_path / f"{k}.rrd")
        assert (info.kind, info.command) == ("check", "a front end's own")
    assert verdicts[0] == verdicts[1] and verdicts[0][0]["match"] is False
