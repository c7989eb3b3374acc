"""The replay use case in-process: a request of plain values in, a result out, nothing
printed, ekfviz's own errors raised, and callable again and again in one process, into
a recording it opens or one it is given."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows

from ekfviz import viz
from ekfviz.app.errors import InputError, OutputError, RunStopped, UsageError
from ekfviz.app.replay import (
    RecordingOutput,
    ReplayRequest,
    open_replay,
    replay,
    replay_into,
)
from ekfviz.app.reporting import Silent
from ekfviz.app.settings import FilterSettings
from ekfviz.core.params import FilterParams
from ekfviz.runner.replay import replay as run_filter
from ekfviz.sources import read_log

DATA = Path(__file__).parents[2] / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"


def _request(tmp_path: Path, name: str = "run", **changes: object) -> ReplayRequest:
    fields: dict[str, object] = {
        "data": SAMPLE, "truth": TRUTH, "report": tmp_path / f"{name}.json",
        "output": RecordingOutput(save=tmp_path / f"{name}.rrd"),
    }  # fmt: skip
    fields.update(changes)
    return ReplayRequest(**fields)  # type: ignore[arg-type]


def test_a_replay_returns_its_results_prints_nothing_and_writes_its_outputs(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    reporter = Silent()
    result = replay(_request(tmp_path), reporter)
    assert capfd.readouterr() == ("", "")
    # the same estimate as the filter run directly on the log's events
    last = list(run_filter(read_log(SAMPLE), FilterParams()))[-1].last
    np.testing.assert_allclose(result.evaluation.pose, last.pose, atol=1e-12)
    assert result.saved_to == tmp_path / "run.rrd"
    assert len(entity_rows(tmp_path / "run.rrd", "/world/robot")) == 59  # every event
    report = json.loads((tmp_path / "run.json").read_text())
    assert report == json.loads(json.dumps(result.report))
    assert report["input"]["name"] == "classic.txt" and report["filter"] == "ekf"
    assert result.table.rows and result.lines[0].startswith("Final pose")  # type: ignore[union-attr]
    assert reporter.warnings == [] and result.sink_error is None and result.served is None


def test_the_same_request_twice_in_one_process_gives_the_same_recording(tmp_path: Path) -> None:
    first = replay(_request(tmp_path, "one"), Silent())
    second = replay(_request(tmp_path, "two"), Silent())
    assert first.report == second.report
    one, two = (entity_rows(tmp_path / f"{n}.rrd", "/world/robot") for n in ("one", "two"))
    assert len(one) == 59 and one == two


def test_a_replay_goes_into_a_recording_it_is_given(tmp_path: Path) -> None:
    """What a front end that keeps its recording open does (a viewer it streams to):
    two replays, one after the other, into recordings it opened itself."""
    request = _request(tmp_path, report=None)
    poses = []
    for name in ("a", "b"):
        opened = open_replay(request, Silent(), make_filter=None)
        info = viz.run_info(name, "a front end's own", {}, SAMPLE)
        with viz.open_run(info, viz.Sinks(save=tmp_path / f"{name}.rrd")) as logger:
            result = replay_into(opened, logger, Silent())
        poses.append(result.evaluation.pose)
        assert logger.recording.saved_to == tmp_path / f"{name}.rrd"
        assert len(entity_rows(tmp_path / f"{name}.rrd", "/world/robot")) == 59
    np.testing.assert_array_equal(poses[0], poses[1])


def test_a_log_stating_its_noise_tells_the_reporter_and_a_given_option_stays(
    tmp_path: Path,
) -> None:
    log = tmp_path / "stated.txt"
    log.write_text("# noise: sigma_x=0.5 sigma_range=0.2\n" + SAMPLE.read_text())
    reporter = Silent()
    result = replay(
        _request(tmp_path, data=log, truth=None, given=frozenset({"sigma_range"}),
                 filter=FilterSettings(sigmas=(0.25, 0.1, 0.1, 0.01, 0.3))),
        reporter,
    )  # fmt: skip
    assert reporter.notes == [f"{log}: the noise its header states: --sigma-x 0.5"]
    parameters = result.report["parameters"]
    assert isinstance(parameters, dict)
    assert (parameters["sigma_x"], parameters["sigma_range"]) == (0.5, 0.3)


def test_bad_input_is_an_input_error_naming_its_line_and_keeps_the_run_before_it(
    tmp_path: Path,
) -> None:
    log = tmp_path / "bad.txt"
    lines = SAMPLE.read_text().splitlines()
    log.write_text("\n".join([*lines[:10], "not numbers", *lines[10:]]) + "\n")
    with pytest.raises(RunStopped) as stopped:
        replay(_request(tmp_path, data=log, truth=None), Silent())
    assert stopped.value.exit_code == 2 and stopped.value.kept
    assert str(stopped.value).startswith(f"{log}:11: ")
    assert str(stopped.value).endswith(
        f"; the recording of everything before it is saved in {tmp_path / 'run.rrd'}"
    )
    with pytest.raises(InputError, match="no such file"):
        replay(_request(tmp_path, data=tmp_path / "missing.txt", truth=None), Silent())


@pytest.mark.parametrize(
    ("changes", "error", "words"),
    [
        ({"report": SAMPLE}, OutputError, "is the input"),
        ({"output": RecordingOutput(save=Path("/"))}, OutputError, "names a folder"),
        ({"output": RecordingOutput(bind="127.0.0.1")}, UsageError, "add --serve"),
        ({"odometry_scale": (0.0, 1.0)}, UsageError, "must be positive"),
        ({"filter_spec": "nowhere.py:Nothing"}, Exception, "no such file"),
    ],
)
def test_what_cannot_be_done_is_one_of_ekfvizs_errors_before_any_work(
    tmp_path: Path, changes: dict[str, object], error: type[Exception], words: str
) -> None:
    from ekfviz.core.errors import EkfvizError

    with pytest.raises(error, match=words) as raised:
        replay(_request(tmp_path, **changes), Silent())
    assert isinstance(raised.value, EkfvizError)
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written
