"""The source layer: detection by registry, each format's own options, a new format as one
module and one registration, a simulated run in memory."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams, MotionNoise
from ekfviz.core.records import AnyEvent, Control, Sighting
from ekfviz.io.extended import format_extended, read_extended
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import classic
from ekfviz.sources import SimulatedSource, SourceArgs, formats, open_source, read_log, register
from ekfviz.sources import base as registry

runner = CliRunner()
DATA = Path(__file__).resolve().parents[2] / "data"


def test_every_format_is_registered_once_in_detection_order() -> None:
    kinds = [f.kind for f in formats()]
    assert kinds == ["mrclam", "victoria", "rosbag", "extended", "classic"]
    assert open_source(DATA / "classic.txt").kind == "classic"
    assert open_source(DATA / "scans.txt").kind == "extended"
    assert open_source(DATA / "classic.txt").names_every_landmark
    assert not open_source(DATA / "scans.txt").ids_only


def test_a_directory_of_no_format_lists_what_is_expected(tmp_path: Path) -> None:
    with pytest.raises(InputError) as caught:
        open_source(tmp_path)
    assert str(caught.value) == (
        f"{tmp_path}: is a directory without Barcodes.dat, inputs.dat and measurements.dat"
        " or metadata.yaml, expected a log file, an MRCLAM dataset directory, a Victoria Park"
        " directory (inputs.dat, measurements.dat, gps.dat) or a ROS 2 bag directory"
        " (metadata.yaml)"
    )


def test_an_option_of_another_format_names_its_owner() -> None:
    args = SourceArgs({"sigma_speed": 0.3}, frozenset({"sigma_speed"}))
    with pytest.raises(InputError, match="--sigma-speed is for a Victoria Park directory"):
        open_source(DATA / "classic.txt", args)
    # an option left at its default is no option given
    assert open_source(DATA / "classic.txt", SourceArgs({"sigma_speed": 0.5})).kind == "classic"


def test_the_cli_refuses_an_option_of_another_format_in_one_line() -> None:
    result = runner.invoke(app, ["replay", str(DATA / "classic.txt"), "--odom", "/odom"])
    assert result.exit_code == 2
    assert "--odom is for a ROS 2 bag directory (metadata.yaml), not a classic log file" in (
        result.output
    )


def test_a_simulated_run_replays_as_its_extended_log(tmp_path: Path) -> None:
    run = classic().run(seed=7)
    log = tmp_path / "run.txt"
    log.write_text(format_extended(run.events, precision=None))
    source = SimulatedSource(run)
    own = source.own_truth(print)
    assert own is not None and own.truth.poses_xytheta is not None
    assert source.files == [] and source.motion_noise is MotionNoise.PER_STEP
    last = every_event(replay(source.events(), FilterParams()))[-1]
    expected = every_event(replay(read_extended(log), FilterParams()))[-1]
    np.testing.assert_array_equal(last.pose, expected.pose)
    np.testing.assert_array_equal(last.landmarks_xy, expected.landmarks_xy)


@dataclass(frozen=True, slots=True)
class _Pairs(registry.Source):
    """A format of a test: ``*.pairs`` files of ``d alpha`` lines, a landmark at 5 0 seen
    after each (one module and one registration: nothing else is edited)."""

    kind = "pairs"
    description = "a pairs file"

    path: Path

    @classmethod
    def detect(cls, path: Path) -> bool:
        return path.suffix == ".pairs"

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        yield Sighting(1, np.array([1]), np.array([[0.0, 5.0]]))
        for line, text in enumerate(self.path.read_text().splitlines(), start=2):
            d, alpha = map(float, text.split())
            yield Control(line, d, alpha)
            yield Sighting(line, np.array([1]), np.array([[0.0, 5.0 - d * (line - 1)]]))


@pytest.fixture
def pairs_registered() -> Iterator[None]:
    registry._FORMATS.insert(0, _Pairs)  # asked first, as a new import line would put it
    try:
        yield
    finally:
        registry._FORMATS.remove(_Pairs)


@pytest.mark.usefixtures("pairs_registered")
def test_a_new_format_is_one_module_and_one_registration(tmp_path: Path) -> None:
    data = tmp_path / "run.pairs"
    data.write_text("1 0\n1 0\n")
    assert [type(e).__name__ for e in read_log(data)] == ["Sighting"] + ["Control", "Sighting"] * 2
    result = runner.invoke(
        app,
        ["replay", str(data), "--save", str(tmp_path / "run.rrd"), "--report",
         str(tmp_path / "run.json")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (tmp_path / "run.rrd").stat().st_size > 0
    assert register is registry.register  # what a format module calls
