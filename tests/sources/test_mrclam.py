"""MRCLAM datasets: the reader on a simulated dataset and on malformed variants, barcode
mapping, interpolated truth, the time timeline, calibration, the gate."""

from __future__ import annotations

import json
import math
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.calibrate.fit import calibrate
from ekfviz.cli import app
from ekfviz.core.batch import EventBatch
from ekfviz.core.errors import InputError
from ekfviz.core.params import MotionNoise
from ekfviz.core.records import Control, EventKind, Sighting
from ekfviz.core.truth import GroundTruth
from ekfviz.io.mrclam import open_dataset, read_mrclam, read_truth
from ekfviz.sim.mrclam import MrclamNoise, MrclamWorld, simulate_mrclam
from ekfviz.sources import open_source
from ekfviz.viz.thinning import PredictThinning

runner = CliRunner()


def write_dataset(directory: Path, files: dict[str, str]) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (directory / name).write_text(text)
    return directory


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated dataset of one minute, written by ``ekfviz simulate --layout mrclam``."""
    directory = tmp_path_factory.mktemp("sim") / "MRCLAM_Sim"
    result = runner.invoke(
        app, ["simulate", "--layout", "mrclam", "-o", str(directory), "--seed", "5",
              "--duration", "60"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return directory


# A hand-made dataset: subjects 1 (robot, barcode 5), 2 (robot, 14), 6 (landmark, 63),
# 7 (landmark, 81); odometry at t = 10, 11, 12; measurements at 11.5 (landmark 6, the
# other robot, an unknown barcode) and at 12 (landmark 7, twice: the second is skipped).
HAND = {
    "Barcodes.dat": "# Subject #    Barcode #\n1 5\n2 14\n6 63\n7 81\n",
    "Landmark_Groundtruth.dat": "# Subject # x y sx sy\n6 1.0 2.0 0.001 0.001\n7 3.0 -1.0 0 0\n",
    "Robot1_Odometry.dat": "# Time [s] v w\n10.0 0.5 0.0\n11.0 1.0 0.2\n12.0 0.0 0.0\n",
    "Robot1_Measurement.dat": "# Time [s] Subject # range bearing\n"
    "11.5 63 2.0 0.1\n11.5 14 1.0 0.0\n11.5 77 3.0 0.0\n12.0 81 4.0 -0.2\n12.0 81 4.1 -0.2\n",
    "Robot1_Groundtruth.dat": "# Time x y theta\n9.0 0 0 3.0\n11.0 1 0 -3.0\n13.0 2 0 -2.0\n",
}


def test_hand_made_dataset_events_barcodes_and_skips(tmp_path: Path) -> None:
    warnings: list[str] = []
    events = list(read_mrclam(open_dataset(write_dataset(tmp_path, HAND), 1), warn=warnings.append))
    kinds = [type(e).__name__ for e in events]
    assert kinds == ["Control", "Control", "Sighting", "Control", "Sighting"]
    first, second, sighting, third, last = events
    assert isinstance(first, Control) and isinstance(second, Control)
    assert isinstance(third, Control)
    # the sample at 10 s holds for 1 s; the one at 11 s is cut by the measurement at 11.5
    assert (first.d, first.alpha, first.dt, first.time) == pytest.approx((0.5, 0.0, 1.0, 11.0))
    assert (second.d, second.alpha, second.dt, second.time) == pytest.approx((0.5, 0.1, 0.5, 11.5))
    assert (third.d, third.alpha, third.dt, third.time) == pytest.approx((0.5, 0.1, 0.5, 12.0))
    assert first.line == 2 and second.line == 3  # odometry lines
    assert isinstance(sighting, Sighting) and isinstance(last, Sighting)
    assert sighting.ids.tolist() == [6] and sighting.time == 11.5
    np.testing.assert_allclose(sighting.z, [[0.1, 2.0]])  # (bearing, range) from range, bearing
    assert last.ids.tolist() == [7] and last.line == 5
    assert len(warnings) == 1
    assert "1 of robots, subjects 2 (1)" in warnings[0]
    assert "unknown barcodes 77 (1)" in warnings[0]
    assert "1 repeating a landmark" in warnings[0]


@pytest.mark.parametrize("bad", ["11.5 0.0 0.0", "1e12 0.0 0.0"])
def test_the_samples_before_a_bad_odometry_time_are_read_first(tmp_path: Path, bad: str) -> None:
    """A time going back (or past a recording's timeline) on line 5 of the odometry: the
    events of the samples before it come first, as a run stopped there keeps them; the
    block they share with it was refused whole."""
    files = dict(HAND, **{"Robot1_Odometry.dat": f"# Time [s] v w\n10.0 0.5 0.0\n11.0 1.0"
                          f" 0.2\n12.0 0.0 0.0\n{bad}\n"})  # fmt: skip
    events: list[object] = []
    with pytest.raises(InputError) as raised:
        for event in read_mrclam(open_dataset(write_dataset(tmp_path, files), 1)):
            events.append(event)
    assert raised.value.line == 5 and raised.value.path.name == "Robot1_Odometry.dat"
    # every event of the samples before it, as without the bad line (see the test above)
    kinds = [type(e).__name__ for e in events]
    assert kinds == ["Control", "Control", "Sighting", "Control", "Sighting"]
    assert isinstance(events[3], Control) and events[3].time == pytest.approx(12.0)


def test_truth_interpolates_on_the_circle_and_not_outside_the_track(tmp_path: Path) -> None:
    truth = read_truth(open_dataset(write_dataset(tmp_path, HAND), 1))
    assert truth.ids.tolist() == [6, 7]
    np.testing.assert_allclose(truth.lookup(np.array([7])), [[3.0, -1.0]])
    # from 3.0 to -3.0 rad the short way is across pi: halfway is pi, not 0
    pose = truth.pose_at(10.0)
    assert pose is not None
    np.testing.assert_allclose(pose[:2], [0.5, 0.0])
    assert abs(abs(pose[2]) - math.pi) < 1e-12
    later = truth.pose_at(12.0)
    assert later is not None
    np.testing.assert_allclose(later, np.array([1.5, 0.0, -2.5]))
    assert truth.pose_at(8.9) is None and truth.pose_at(13.1) is None
    assert truth.pose_of(0, None) is None  # a timestamped truth needs the event's time


def test_simulated_dataset_reads_back_with_its_truth(dataset: Path) -> None:
    source = open_source(dataset)
    assert source.kind == "mrclam" and source.motion_noise is MotionNoise.PER_SQRT_SECOND
    warnings: list[str] = []
    events = list(source.events(warn=warnings.append))
    times = [e.time for e in events]
    assert all(t is not None for t in times) and times == sorted(times)  # type: ignore[type-var]
    controls = [e for e in events if isinstance(e, Control)]
    sightings = [e for e in events if isinstance(e, Sighting)]
    assert controls and sightings
    assert all(c.dt is not None and c.dt > 0 for c in controls)
    span = sum(c.dt for c in controls if c.dt is not None)
    assert span == pytest.approx(events[-1].time - (controls[0].time - controls[0].dt), abs=1e-6)  # type: ignore[operator]
    # landmark ids are subjects 6.. (robots and the unknown barcode 99 skipped)
    ids = np.concatenate([s.ids for s in sightings])
    assert ids.min() >= 6 and ids.max() <= 20
    assert len(warnings) == 1 and "of robots" in warnings[0]
    own = source.own_truth(warnings.append)
    assert own is not None and own.files == [
        dataset / "Landmark_Groundtruth.dat",
        dataset / "Robot1_Groundtruth.dat",
    ]
    assert own.truth.track_times is not None and len(own.truth.ids) == 15
    assert len(warnings) == 1  # nothing said of a truth that is there


def test_simulation_is_deterministic_in_the_seed() -> None:
    world = MrclamWorld(duration_s=5.0)
    assert simulate_mrclam(seed=2, world=world) == simulate_mrclam(seed=2, world=world)
    assert simulate_mrclam(seed=2, world=world) != simulate_mrclam(seed=3, world=world)


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("Robot1_Odometry.dat", "10.0 0.5\n", "Robot1_Odometry.dat:1: found 2 numbers, expected 3"),
        ("Robot1_Odometry.dat", "10.0 0.5 x\n", "Robot1_Odometry.dat:1: found 'x'"),
        ("Robot1_Odometry.dat", "10.0 0.5 nan\n", "Robot1_Odometry.dat:1: found 'nan'"),
        ("Robot1_Odometry.dat", "10 0 0\n9 0 0\n", "Robot1_Odometry.dat:2: found time 9.000 after"),
        ("Robot1_Measurement.dat", "11 63 -1 0\n", "Robot1_Measurement.dat:1: found range -1"),
        ("Robot1_Measurement.dat", "11 6.5 1 0\n", "Robot1_Measurement.dat:1: found barcode 6.5"),
        ("Robot1_Measurement.dat", "11 63 1\n", "Robot1_Measurement.dat:1: found 3 numbers"),
        ("Robot1_Measurement.dat", "12 63 1 0\n11 63 1 0\n", "Measurement.dat:2: found time 11"),
        ("Barcodes.dat", "1 5\n2 5\n", "Barcodes.dat:2: found barcode 5 twice"),
        ("Barcodes.dat", "1 5.5\n", "Barcodes.dat:1: found '1 5.5', expected two integers"),
        ("Robot1_Groundtruth.dat", "9 0 0\n", "Robot1_Groundtruth.dat:1: found 3 numbers"),
        ("Landmark_Groundtruth.dat", "6 1 2\n", "Landmark_Groundtruth.dat:1: found '6 1 2'"),
    ],
)
def test_malformed_dataset_is_one_line_exit_2_and_no_recording(
    tmp_path: Path, name: str, text: str, message: str
) -> None:
    directory = write_dataset(tmp_path / "data", {**HAND, name: text})
    rrd = tmp_path / "run.rrd"
    result = runner.invoke(app, ["replay", str(directory), "--save", str(rrd)])
    assert result.exit_code == 2, result.output
    assert message in result.output, result.output
    assert "Traceback" not in result.output
    assert not rrd.exists() or rrd.stat().st_size > 0  # never half-written


def test_a_long_malformed_file_names_its_line(tmp_path: Path) -> None:
    """Big files are read in blocks; a bad line deep inside is still named exactly."""
    lines = [f"{10 + k * 0.01:.2f} 0.1 0.0" for k in range(30000)]
    lines[25000] = "260.00 0.1 oops"
    directory = write_dataset(tmp_path, {**HAND, "Robot1_Odometry.dat": "\n".join(lines)})
    with pytest.raises(InputError, match=r"Robot1_Odometry.dat:25001: found 'oops'"):
        list(read_mrclam(open_dataset(directory, 1)))


@pytest.mark.parametrize(
    ("name", "lines", "message"),
    [  # a line short, the next long: the block's count is right, its lines' are not
        ("Robot1_Odometry.dat", ["10.0 0.1", "0.0 10.01 0.1 0.0"], "Odometry.dat:2001: found 2 "),
        ("Robot1_Measurement.dat", ["11 63 1 0 12", "63 1 0"], "Measurement.dat:2001: found 5 "),
    ],
)
def test_a_line_of_another_length_is_refused_though_the_next_makes_up_for_it(
    tmp_path: Path, name: str, lines: list[str], message: str
) -> None:
    """A long file is converted a block at a time: every line's count is still checked."""
    good = {
        "Robot1_Odometry.dat": [f"{k * 0.001:.3f} 0.1 0.0" for k in range(2000)],
        "Robot1_Measurement.dat": [f"{k * 0.001:.3f} 63 1.0 0.0" for k in range(2000)],
    }[name]
    directory = write_dataset(tmp_path, {**HAND, name: "\n".join([*good, *lines]) + "\n"})
    with pytest.raises(InputError, match=message):
        list(read_mrclam(open_dataset(directory, 1)))


@pytest.mark.parametrize("blank", ["\u00a0", "\u2003 \t", "\x1c", "\u00a0# a note"])
def test_a_line_of_unicode_white_space_is_blank_as_in_the_other_readers(
    tmp_path: Path, blank: str
) -> None:
    odometry = HAND["Robot1_Odometry.dat"].replace("11.0 1.0 0.2\n", f"11.0 1.0 0.2\n{blank}\n")
    plain = list(read_mrclam(open_dataset(write_dataset(tmp_path / "a", HAND), 1)))
    spaced = {**HAND, "Robot1_Odometry.dat": odometry}
    read = list(read_mrclam(open_dataset(write_dataset(tmp_path / "b", spaced), 1)))
    assert [repr(event._replace(line=0)) for event in read] == [
        repr(event._replace(line=0)) for event in plain
    ]  # the same events (the lines after the blank one one further down)


@pytest.mark.parametrize("name", ["Robot1_Groundtruth.dat", "Landmark_Groundtruth.dat"])
def test_a_truth_file_that_is_a_folder_is_refused(tmp_path: Path, name: str) -> None:
    directory = write_dataset(tmp_path / "data", {k: v for k, v in HAND.items() if k != name})
    (directory / name).mkdir()
    result = runner.invoke(app, ["replay", str(directory), "--save", str(tmp_path / "x.rrd")])
    assert result.exit_code == 2
    assert f"{name}: is a directory, expected a text file" in result.output
    assert "warning" not in result.output


def test_missing_robot_and_not_a_dataset(tmp_path: Path) -> None:
    directory = write_dataset(tmp_path / "data", HAND)
    result = runner.invoke(app, ["replay", str(directory), "--robot", "4", "--save", "x.rrd"])
    assert result.exit_code == 2
    assert "Robot4_Odometry.dat: no such file, expected robot 4's files (robots here: 1)" in (
        result.output
    )
    (tmp_path / "empty").mkdir()
    result = runner.invoke(app, ["replay", str(tmp_path / "empty"), "--save", "x.rrd"])
    assert result.exit_code == 2 and "is a directory without Barcodes.dat" in result.output


def time_column(path: Path, entity: str, kind: str = "timestamp[ns]") -> list[float]:
    """The ``time`` index of an entity's rows, in seconds (``kind``: its Arrow type)."""
    from rerun.chunk import RrdReader

    seconds: list[float] = []
    for chunk in RrdReader(path).stream().filter(content=entity, is_static=False):
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        column = batch.column(batch.schema.names.index("time"))
        assert str(column.type) == kind  # MRCLAM's Unix times: a timestamp
        seconds += [v / 1e9 for v in column.cast("int64").to_pylist()]
    return sorted(seconds)


def test_replay_records_a_time_timeline_and_thins_its_predicts(
    dataset: Path, tmp_path: Path
) -> None:
    rrd = tmp_path / "run.rrd"
    result = runner.invoke(app, ["replay", str(dataset), "--save", str(rrd)])
    assert result.exit_code == 0, result.output
    assert "starts at the true pose of the first event" in result.output
    events = list(open_source(dataset).events())
    first = events[0]
    assert first.time is not None
    start = first.time - (first.dt or 0.0) if isinstance(first, Control) else first.time
    times = time_column(rrd, "/world/robot")
    assert times[0] == pytest.approx(start, abs=1e-6)
    end = events[-1].time
    assert end is not None and times[-1] == pytest.approx(end, abs=1e-6)
    # thinned: far fewer robot rows than events, never more than 0.5 s of log time apart
    # (plus the odometry period of 20 ms: a predict is logged once 0.5 s have passed)
    assert len(times) < len(events) / 3
    assert max(np.diff(times)) <= 0.5 + 0.02 + 1e-6
    # every update, and the predict right before it, is in the recording
    robot = entity_rows(rrd, "/world/robot")
    logged = {int(str(row["event"])) for row in robot}
    updates = [k + 1 for k, e in enumerate(events) if isinstance(e, Sighting)]
    assert all(k in logged and k - 1 in logged for k in updates if k > 1)
    # the layout follows the time timeline; the report names the model
    info = runner.invoke(app, ["info", str(rrd)])
    assert info.exit_code == 0
    assert re.search(r"time span\s+2009-07-24", info.output), info.output
    assert '"per-sqrt-second"' in info.output


def test_the_detail_option_logs_every_predict(dataset: Path, tmp_path: Path) -> None:
    rrd = tmp_path / "run.rrd"
    result = runner.invoke(app, ["replay", str(dataset), "--detail", "--save", str(rrd)])
    assert result.exit_code == 0, result.output
    assert len(entity_rows(rrd, "/world/robot")) == len(list(open_source(dataset).events())) + 1


@pytest.mark.slow
def test_calibrate_recovers_the_simulated_noise_within_ten_percent(tmp_path: Path) -> None:
    noise = MrclamNoise()
    directory = write_dataset(
        tmp_path / "sim", simulate_mrclam(seed=11, world=MrclamWorld(duration_s=600.0))
    )
    result = runner.invoke(app, ["calibrate", str(directory)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    # the printed contract: a line of its own that starts with "ekfviz replay"
    line = next(x for x in result.output.splitlines() if x.startswith("ekfviz replay "))
    words = shlex.split(line)
    found = {words[k][2:]: words[k + 1] for k in range(len(words) - 1) if words[k][:2] == "--"}
    assert found["motion-noise"] == "per-sqrt-second"
    assert "gate" not in found  # no outliers in a Gaussian simulation
    for name, true in (
        ("sigma-x", noise.sigma_x), ("sigma-y", noise.sigma_y),
        ("sigma-alpha", noise.sigma_alpha), ("sigma-bearing", noise.sigma_bearing),
        ("sigma-range", noise.sigma_range),
    ):  # fmt: skip
        assert float(found[name]) == pytest.approx(true, rel=0.10), name
    assert "is consistent with the truth" in result.output
    # and the printed line runs
    replayed = runner.invoke(app, [*words[1:], "--save", str(tmp_path / "r.rrd")])
    assert replayed.exit_code == 0, replayed.output


def test_calibrate_per_step_on_an_untimed_simulation() -> None:
    from ekfviz.sim import scenarios
    from ekfviz.sim.simulate import Noise

    world = scenarios.loop(seed=1, steps=3000, landmarks=60)
    run = world.run(Noise(0.05, 0.02, 0.01, 0.01, 0.05), seed=1, init_pose_sigma=(0, 0, 0))
    truth = GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta)
    result = calibrate(run.events, truth)
    assert result.motion is not None and result.motion.window_s is None
    np.testing.assert_allclose(result.motion.sigmas, (0.05, 0.02, 0.01), rtol=0.1)
    assert result.bearing.sigma == pytest.approx(0.01, rel=0.1)
    assert result.range.sigma == pytest.approx(0.05, rel=0.1)


def test_calibrate_needs_true_poses(tmp_path: Path) -> None:
    truth = tmp_path / "t.txt"
    truth.write_text("1 2\n")
    log = tmp_path / "log.txt"
    log.write_text("0.1 5\n1 0\n0.1 5\n")
    result = runner.invoke(app, ["calibrate", str(log), "--truth", str(truth)])
    assert result.exit_code == 2 and "calibrate needs true poses" in result.output


def test_the_gate_rejects_an_outlier_with_a_warning(tmp_path: Path) -> None:
    from ekfviz.core.params import FilterParams
    from ekfviz.runner.replay import replay
    from ekfviz.runner.run import every_event

    near = Sighting(line=1, ids=np.array([1]), z=np.array([[0.0, 5.0]]))
    events: list[Control | Sighting] = [near, Control(line=2, d=0.0, alpha=0.0), Sighting(
        line=3, ids=np.array([1]), z=np.array([[1.5, 5.0]])
    )]  # fmt: skip
    gated = every_event(replay(events, FilterParams(gate=13.8)))[-1]
    assert gated.warnings and "NIS" in gated.warnings[0] and "rejected" in gated.warnings[0]
    assert gated.observations is not None and len(gated.observations.ids) == 0
    used = every_event(replay(events, FilterParams()))[-1]
    assert used.observations is not None and len(used.observations.ids) == 1


def record(kind: EventKind, event: int, time: float | None) -> EventBatch:
    """One event with the prior's state, of ``kind`` at ``time``."""
    from ekfviz.core.batch import KIND_CODES, BatchBuilder

    builder = BatchBuilder()
    builder.add_state(
        np.zeros(3), np.eye(3), event=event, step=event, kind=KIND_CODES[kind], time=time
    )
    return builder.build()


def test_thinning_keeps_updates_the_predict_before_them_and_the_last() -> None:
    thinning = PredictThinning(0.5)
    logged: list[int] = []
    kinds = [EventKind.INIT] + [EventKind.PREDICT] * 20 + [EventKind.UPDATE] + [
        EventKind.PREDICT
    ] * 5  # fmt: skip
    for k, kind in enumerate(kinds):
        logged += thinning.admit(record(kind, k, 0.1 * k)).events.tolist()
    held = thinning.drain()
    logged += [] if held is None else held.events.tolist()
    # init; predicts 5, 10, 15, 20 (0.5 s apart); 20 is also right before the update 21;
    # 26 the last
    assert logged == [0, 5, 10, 15, 20, 21, 26]
    untimed = PredictThinning(0.5)
    assert untimed.admit(record(EventKind.PREDICT, 1, None)).events.tolist() == [1]
    # in batches of any size: the same events logged
    for size in (2, 3, 7, 27):
        thinning = PredictThinning(0.5)
        events = [record(kind, k, 0.1 * k) for k, kind in enumerate(kinds)]
        joined = EventBatch.joined(
            [EventBatch.joined(events[k : k + size]) for k in range(0, len(events), size)]
        )
        again = [joined[k : k + size] for k in range(0, len(joined), size)]
        logged_now = [thinning.admit(part).events.tolist() for part in again]
        held = thinning.drain()
        flat = [e for part in logged_now for e in part] + ([] if held is None else [26])
        assert flat == [0, 5, 10, 15, 20, 21, 26], size


def test_an_extended_log_with_times_gets_a_duration_timeline(tmp_path: Path) -> None:
    """Times below 10^9 s are no Unix times: a duration, in the log's own seconds; an
    untimed line takes the time before it."""
    log = tmp_path / "log.txt"
    log.write_text(
        "0.5 observe 1 0.1 5\n1.0 control 1 0\n1.0 observe 1 0.1 4\ncontrol 1 0\n"
        "2.25 observe 1 0.1 3\n"
    )
    rrd = tmp_path / "run.rrd"
    result = runner.invoke(app, ["replay", str(log), "--save", str(rrd)])
    assert result.exit_code == 0, result.output
    assert time_column(rrd, "/world/robot", "duration[ns]") == [0.5, 1.0, 1.0, 1.0, 2.25]
    info = runner.invoke(app, ["info", str(rrd)])
    assert "0.500 s to 2.250 s (1.750 s)" in info.output, info.output


@pytest.mark.parametrize(
    "command",
    [
        pytest.param(["sweep", "--vary", "sigma_range=x1,x2", "--workers", "1"],
                     marks=pytest.mark.slow),
        ["compare", "--filter", "ekf", "--filter", "ekf", "--label", "a", "--label", "b",
         "--workers", "1"],
        pytest.param(["check", "--filter", "ekf"], marks=pytest.mark.slow),
    ],
)  # fmt: skip
def test_the_studies_and_check_take_a_dataset_s_robot(
    dataset: Path, tmp_path: Path, command: list[str]
) -> None:
    """``--robot`` as replay takes it (sweep and compare could not read a dataset at all:
    the run's information hashed the directory as one file)."""
    name, *rest = command
    save = ["--save", str(tmp_path / "x.rrd")]
    result = runner.invoke(app, [name, str(dataset), "--robot", "1", *rest, *save])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, [name, str(dataset), "--robot", "9", *rest, *save])
    assert result.exit_code == 2
    assert "Robot9_Odometry.dat: no such file, expected robot 9's files" in result.output


def test_a_sweep_of_a_dataset_runs_the_filter_a_replay_of_it_runs(
    dataset: Path, tmp_path: Path
) -> None:
    """Its odometry's noise per square-root second (as replay's --motion-noise auto), not
    per control: the same baseline, the same NIS as the replay's."""
    report = tmp_path / "sweep.json"
    result = runner.invoke(
        app,
        ["sweep", str(dataset), "--robot", "1", "--vary", "sigma_range=x1", "--workers", "1",
         "--save", str(tmp_path / "s.rrd"), "--report", str(report)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    baseline = json.loads(report.read_text())["baseline"]
    assert baseline["motion_noise"] == "per-sqrt-second"


@pytest.mark.slow
@pytest.mark.parametrize(
    "command",
    [
        ["compare", "--filter", "ekf", "--workers", "1"],
        ["sweep", "--vary", "sigma_range=x1", "--workers", "1"],
    ],
)
def test_a_study_of_a_dataset_is_judged_against_the_dataset_s_own_truth(
    dataset: Path, tmp_path: Path, command: list[str]
) -> None:
    """As a replay of it: from the true pose of the first event, against the Vicon track
    and the surveyed landmarks (a study read only ``--truth``: no errors, no NEES, and its
    filter started at 0 0 0). ``--no-truth`` drops the truth, as replay's does."""
    replayed = tmp_path / "replay.json"
    result = runner.invoke(
        app, ["replay", str(dataset), "--save", str(tmp_path / "r.rrd"), "--report", str(replayed)]
    )
    assert result.exit_code == 0, result.output
    replay = json.loads(replayed.read_text())
    studied = tmp_path / "study.json"
    rrd = tmp_path / "s.rrd"
    name, *rest = command
    result = runner.invoke(app, [name, str(dataset), *rest, "--save", str(rrd), "--report",
                                 str(studied)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "The filter starts at the true pose of the first event" in result.output
    assert "--init-pose" not in result.output  # a study has no such option
    study = json.loads(studied.read_text())
    first = (study["filters"] if name == "compare" else study["variants"])[0]
    assert first["summary"] == replay["summary"]  # the same errors, in the truth's frame
    assert first["consistency"] == replay["consistency"]  # NEES by the track's times
    assert first["consistency"]["nees"]["count"] > 0
    info = runner.invoke(app, ["info", str(rrd)])
    assert "Landmark_Groundtruth.dat" in info.output, info.output

    result = runner.invoke(app, [name, str(dataset), *rest, "--no-truth", "--save", str(rrd),
                                 "--report", str(studied)])  # fmt: skip
    assert result.exit_code == 0, result.output
    first = json.loads(studied.read_text())["filters" if name == "compare" else "variants"][0]
    assert "summary" not in first
    assert first["consistency"]["nees"]["count"] == 0


@pytest.mark.parametrize(
    "command",
    [
        ["compare", "--filter", "ekf", "--workers", "1"],
        ["sweep", "--vary", "sigma_range=x1", "--workers", "1"],
        ["check", "--filter", "ekf"],
    ],
)
def test_a_study_or_check_refuses_a_dataset_s_malformed_truth(
    tmp_path: Path, command: list[str]
) -> None:
    """Where replay refuses it (they ran without a word before: they never read it)."""
    directory = write_dataset(tmp_path / "data", {**HAND, "Robot1_Groundtruth.dat": "9 0 0\n"})
    rrd = tmp_path / "x.rrd"
    name, *rest = command
    result = runner.invoke(app, [name, str(directory), *rest, "--save", str(rrd)])
    assert result.exit_code == 2, result.output
    assert "Robot1_Groundtruth.dat:1: found 3 numbers" in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    assert not rrd.exists()


def test_a_filter_warning_names_the_file_of_its_line(tmp_path: Path) -> None:
    """A dataset directory is two files of lines: a warning named ``DIR:LINE``, a line of
    neither file. An update's line is the measurement file's (a predict's the odometry's)."""
    measured = "# Time [s] Subject # range bearing\n11.5 63 2.0 0.1\n12.0 63 2.9 -0.4\n"
    directory = write_dataset(tmp_path / "data", {**HAND, "Robot1_Measurement.dat": measured})
    result = runner.invoke(app, ["replay", str(directory), "--gate", "1e-6", "--save",
                                 str(tmp_path / "x.rrd")])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert f"warning: {directory / 'Robot1_Measurement.dat'}:3: " in result.output, result.output


@pytest.mark.parametrize(
    ("command", "option"),
    [
        (["calibrate"], "--report"),
        (["check", "--filter", "ekf"], "--report"),
        (["sweep", "--vary", "sigma_x=x2", "--workers", "1"], "--save"),
        (["compare", "--filter", "ekf", "--workers", "1"], "--report"),
    ],
)
def test_no_command_writes_over_a_file_of_the_dataset_it_reads(
    dataset: Path, command: list[str], option: str
) -> None:
    """``replay`` refused it; ``calibrate --report DIR/Robot1_Odometry.dat`` replaced the
    odometry with its report, and the dataset no longer read."""
    name, *rest = command
    target = dataset / "Robot1_Odometry.dat"
    before = target.read_bytes()
    result = runner.invoke(app, [name, str(dataset), *rest, option, str(target)])
    assert result.exit_code == 2, result.output
    assert result.output.strip() == (
        f"error: {option} {target}: is the input {target}, which writing it would replace:"
        " give another file"
    )
    assert target.read_bytes() == before
