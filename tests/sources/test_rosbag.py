"""The ROS 2 bag source: a bag written with ``rosbags`` from a simulated run replays to the
same final state as the extended log of that run; a bad bag gets one line and exit 2."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from commands import run_ekfviz, run_ekfviz_process
from conftest import entity_rows
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams, MotionNoise
from ekfviz.core.records import AnyEvent, Control, EventRecord, Scan, Sighting
from ekfviz.core.types import FloatArray
from ekfviz.io.extended import format_extended, read_extended
from ekfviz.io.truth import truth_json
from ekfviz.models.classic import motion
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import classic, loop
from ekfviz.sim.simulate import Detection, Simulation
from ekfviz.sources import SourceArgs, open_source
from ekfviz.sources.rosbag import RosbagSource

runner = CliRunner()
STORE = get_typestore(Stores.ROS2_HUMBLE)
T0 = 1_700_000_000.25  # seconds: a stamp of today's size, nanoseconds kept exactly
DT = 0.5  # seconds per step: the time-scaled noise differs from the per-step one


def timed(events: Sequence[AnyEvent], dt: float = DT) -> list[AnyEvent]:
    """The run's events with the stamps the bag gets: step k at T0 + k dt."""
    out: list[AnyEvent] = []
    step = 0
    for event in events:
        if isinstance(event, Control):
            step += 1
        time = T0 + step * dt
        if isinstance(event, Control):
            out.append(Control(event.line, event.d, event.alpha, time=time, dt=dt))
        elif isinstance(event, Scan):
            out.append(Scan(event.line, event.z, time=time))
        else:
            assert isinstance(event, Sighting)
            out.append(Sighting(event.line, event.ids, event.z, time=time))
    return out


def _header(time: float, frame: str) -> Any:
    sec = math.floor(time)
    stamp = STORE.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((time - sec) * 1e9))
    return STORE.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _pose(x: float, y: float, theta: float) -> Any:
    types = STORE.types
    return types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
        orientation=types["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2)
        ),
    )


def odometry(time: float, pose: FloatArray) -> Any:
    types = STORE.types
    twist = types["geometry_msgs/msg/Twist"](
        linear=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
        angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
    )
    return types["nav_msgs/msg/Odometry"](
        header=_header(time, "odom"),
        child_frame_id="base_link",
        pose=types["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(*pose), covariance=np.zeros(36)
        ),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def markers(time: float, event: Sighting | Scan) -> Any:
    """One marker per measurement at its place in the robot's frame (id -1: id-less)."""
    types = STORE.types
    ids = event.ids if isinstance(event, Sighting) else [-1] * len(event.z)
    array = []
    for landmark, (bearing, rng) in zip(ids, event.z, strict=True):
        array.append(
            types["visualization_msgs/msg/Marker"](
                header=_header(time, "base_link"),
                ns="landmarks",
                id=int(landmark),
                type=2,
                action=0,
                pose=_pose(rng * math.cos(bearing), rng * math.sin(bearing), 0.0),
                scale=types["geometry_msgs/msg/Vector3"](x=0.3, y=0.3, z=0.3),
                color=types["std_msgs/msg/ColorRGBA"](r=1.0, g=0.0, b=0.0, a=1.0),
                lifetime=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
                frame_locked=False,
                points=[],
                colors=[],
                texture_resource="",
                texture=types["sensor_msgs/msg/CompressedImage"](
                    header=_header(time, ""), format="", data=np.zeros(0, dtype=np.uint8)
                ),
                uv_coordinates=[],
                text="",
                mesh_resource="",
                mesh_file=types["visualization_msgs/msg/MeshFile"](
                    filename="", data=np.zeros(0, dtype=np.uint8)
                ),
                mesh_use_embedded_materials=False,
            )
        )
    return types["visualization_msgs/msg/MarkerArray"](markers=array)


def write_bag(
    path: Path,
    run: Simulation,
    storage: StoragePlugin = StoragePlugin.SQLITE3,
    *,
    truth: bool = True,
    skip: Sequence[str] = (),
    stamped: bool = True,
) -> Path:
    """The run as a bag: /odom integrated from its commanded controls from (0, 0, 0),
    /landmarks one MarkerArray per observation, /ground_truth its true poses. At each
    stamp the detections are written before the odometry: the source puts motion first.
    Not ``stamped``: every header stamp left at zero (the bag's times only).
    """

    def stamp(time: float) -> float:
        return time if stamped else 0.0

    events = timed(run.scan_events if run.scan_events is not None else run.events)
    with Writer(path, version=9, storage_plugin=storage) as writer:
        topics = {
            "/odom": "nav_msgs/msg/Odometry",
            "/landmarks": "visualization_msgs/msg/MarkerArray",
            **({"/ground_truth": "geometry_msgs/msg/PoseStamped"} if truth else {}),
        }
        connections = {
            topic: writer.add_connection(topic, kind, typestore=STORE)
            for topic, kind in topics.items()
            if topic not in skip
        }

        def write(topic: str, time: float, message: Any) -> None:
            if topic in connections:
                data = STORE.serialize_cdr(message, topics[topic])
                writer.write(connections[topic], round(time * 1e9), data)

        pose = np.zeros(3)
        write("/odom", T0, odometry(stamp(T0), pose))
        step = 0
        for event in events:
            assert event.time is not None
            if isinstance(event, Control):
                pose = motion(pose, event.d, event.alpha)
                step += 1
                write("/odom", event.time, odometry(stamp(event.time), pose))
            else:
                assert isinstance(event, Sighting | Scan)
                write("/landmarks", event.time, markers(stamp(event.time), event))
            if not isinstance(event, Control):
                true = run.poses_xytheta[step]
                write("/ground_truth", event.time, STORE.types["geometry_msgs/msg/PoseStamped"](
                    header=_header(stamp(event.time), "map"), pose=_pose(*true)
                ))  # fmt: skip
    return path


def write_log(path: Path, run: Simulation) -> Path:
    """The extended log of the run, timestamped as the bag, every digit kept."""
    events = timed(run.scan_events if run.scan_events is not None else run.events)
    path.write_text(format_extended(events, precision=None))
    return path


def final(events: Iterator[AnyEvent], params: FilterParams) -> EventRecord:
    return every_event(replay(events, params))[-1]


@pytest.fixture(scope="module")
def run() -> Simulation:
    return classic().run(seed=4)


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_a_bag_replays_to_the_final_state_of_the_extended_log(
    tmp_path: Path, run: Simulation, storage: StoragePlugin
) -> None:
    bag = write_bag(tmp_path / "run_bag", run, storage)
    log = write_log(tmp_path / "run.txt", run)
    source = open_source(bag)
    assert isinstance(source, RosbagSource) and source.kind == "rosbag"
    assert source.motion_noise is MotionNoise.PER_SQRT_SECOND
    params = FilterParams(motion_noise=MotionNoise.PER_SQRT_SECOND)
    from_bag = final(source.events(), params)
    from_log = final(read_extended(log), params)
    assert from_bag.event == from_log.event == len(run.events) - 1
    assert from_bag.step == from_log.step == len(run.events) // 2
    np.testing.assert_allclose(from_bag.pose, from_log.pose, rtol=0, atol=1e-9)
    np.testing.assert_allclose(from_bag.landmarks_xy, from_log.landmarks_xy, rtol=0, atol=1e-9)
    np.testing.assert_allclose(from_bag.pose_cov, from_log.pose_cov, rtol=0, atol=1e-9)
    assert from_bag.landmark_ids.tolist() == from_log.landmark_ids.tolist()
    # the odometry gives the commanded controls back, the stamps their times
    controls = [e for e in source.events() if isinstance(e, Control)]
    assert [c.dt for c in controls] == pytest.approx([DT] * len(run.events[1::2]), abs=1e-6)
    commanded = np.array([(e.d, e.alpha) for e in run.events if isinstance(e, Control)])
    np.testing.assert_allclose([(c.d, c.alpha) for c in controls], commanded, atol=1e-12)


def test_stamps_left_at_zero_are_the_times_the_bag_recorded(
    tmp_path: Path, run: Simulation
) -> None:
    stamped = list(open_source(write_bag(tmp_path / "stamped", run)).events())
    unstamped = list(open_source(write_bag(tmp_path / "zero", run, stamped=False)).events())
    assert [type(e) for e in unstamped] == [type(e) for e in stamped]
    assert [e.time for e in unstamped] == pytest.approx([e.time for e in stamped], abs=1e-6)
    assert all(e.dt == pytest.approx(DT) for e in unstamped if isinstance(e, Control))


def test_replay_of_a_bag_matches_the_log_end_to_end(tmp_path: Path, run: Simulation) -> None:
    """``ekfviz replay BAG`` against ``ekfviz replay LOG --motion-noise per-sqrt-second``:
    the same evaluation to 1e-9, a recording with every step, the truth topic read."""
    bag = write_bag(tmp_path / "run_bag", run, StoragePlugin.MCAP)
    log = write_log(tmp_path / "run.txt", run)
    truth = tmp_path / "truth.json"
    truth.write_text(_truth_file(run))
    reports = {}
    for name, args in {
        "bag": [str(bag), "--odom", "/odom", "--landmarks", "/landmarks"],
        "log": [str(log), "--motion-noise", "per-sqrt-second"],
    }.items():
        result = runner.invoke(
            app, ["replay", *args, "--truth", str(truth), "--save", str(tmp_path / f"{name}.rrd"),
                  "--report", str(tmp_path / f"{name}.json")],
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        reports[name] = json.loads((tmp_path / f"{name}.json").read_text())
    _close(reports["bag"], reports["log"], skip={"input"})
    robot = entity_rows(tmp_path / "bag.rrd", "/world/robot")
    assert len(robot) == len(entity_rows(tmp_path / "log.rrd", "/world/robot")) == len(run.events)
    # the truth topic: the filter starts at the true start (the truth's frame)
    result = runner.invoke(
        app, ["replay", str(bag), "--truth-topic", "/ground_truth", "--save",
              str(tmp_path / "t.rrd"), "--report", str(tmp_path / "t.json")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "starts at the true pose of the first event" in result.output
    start = run.poses_xytheta[0]
    assert f"x {start[0]:.4f}, y {start[1]:.4f}" in result.output
    report = json.loads((tmp_path / "t.json").read_text())
    assert report["parameters"]["motion_noise"] == "per-sqrt-second"


def _truth_file(run: Simulation) -> str:
    from ekfviz.core.truth import GroundTruth

    return truth_json(GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta))


def _close(a: object, b: object, skip: set[str], where: str = "") -> None:
    """JSON documents equal, numbers within 1e-9."""
    if isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            if key not in skip:
                _close(a[key], b[key], skip, f"{where}/{key}")
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, skip, f"{where}/{k}")
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, rel=0, abs=1e-9), where
    else:
        assert a == b, where


def test_id_less_markers_are_scans_that_the_association_pairs(tmp_path: Path) -> None:
    run = loop(seed=1, steps=60, landmarks=12).run(seed=1, detection=Detection(unknown_ids=True))
    bag = write_bag(tmp_path / "scans_bag", run)
    log = write_log(tmp_path / "scans.txt", run)
    events = list(open_source(bag).events())
    assert any(isinstance(e, Scan) for e in events)
    assert not any(isinstance(e, Sighting) for e in events)
    reports = {}
    for name, args in {
        "bag": [str(bag)],
        "log": [str(log), "--motion-noise", "per-sqrt-second"],
    }.items():
        result = runner.invoke(
            app, ["replay", *args, "--save", str(tmp_path / f"{name}.rrd"),
                  "--report", str(tmp_path / f"{name}.json")],
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        assert "Association:" in result.output
        reports[name] = json.loads((tmp_path / f"{name}.json").read_text())
    _close(reports["bag"], reports["log"], skip={"input"})


def _failure(tmp_path: Path, bag: Path, *options: str, apart: bool = False) -> str:
    """The one line of a refused bag, through the command line (exit 2, no traceback);
    ``apart``: in a process of its own, which a replay that hangs fails at a time-out."""
    run = run_ekfviz_process if apart else run_ekfviz
    result = run("replay", bag, *options, "--save", tmp_path / "x.rrd")
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert not (tmp_path / "x.rrd").exists()
    return lines[0]


def test_a_missing_topic_a_wrong_type_or_an_empty_bag_is_one_line(
    tmp_path: Path, run: Simulation
) -> None:
    short = run.events[:5]
    small = Simulation(short, run.poses_xytheta[:3], run.landmark_ids, run.landmarks_xy)
    bag = write_bag(tmp_path / "no_landmarks", small, skip=["/landmarks"])
    line = _failure(tmp_path, bag)
    assert f"{bag}: has no topic /landmarks (--landmarks)" in line
    assert "/odom (nav_msgs/msg/Odometry)" in line  # what the bag does have

    bag = write_bag(tmp_path / "typed", small)
    line = _failure(tmp_path, bag, "--odom", "/ground_truth")
    assert line.endswith(
        "topic /ground_truth (--odom) holds geometry_msgs/msg/PoseStamped, expected"
        " nav_msgs/msg/Odometry"
    )
    line = _failure(tmp_path, bag, "--truth-topic", "/landmarks")
    assert "expected nav_msgs/msg/Odometry or geometry_msgs/msg/PoseStamped" in line

    empty = tmp_path / "empty"
    with Writer(empty, version=9) as writer:
        writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=STORE)
        writer.add_connection("/landmarks", "visualization_msgs/msg/MarkerArray", typestore=STORE)
    line = _failure(tmp_path, empty)
    assert line.endswith(
        "topic /odom (--odom) has no messages, expected nav_msgs/msg/Odometry messages"
    )

    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: [not, a, bag\n")
    assert "cannot read the bag" in _failure(tmp_path, broken)

    # an option of the bag for a log file, and the other way round
    log = write_log(tmp_path / "run.txt", small)
    line = _failure(tmp_path, log, "--odom", "/odom")
    assert "--odom is for a ROS 2 bag directory (metadata.yaml), not an extended log file" in line
    assert "--robot is for an MRCLAM dataset directory" in _failure(tmp_path, bag, "--robot", "2")


def test_markers_with_and_without_ids_a_repeated_id_or_nan_are_refused(tmp_path: Path) -> None:
    both = Sighting(1, np.array([3, -1]), np.array([[0.1, 2.0], [0.2, 3.0]]))
    twice = Sighting(1, np.array([3, 3]), np.array([[0.1, 2.0], [0.2, 3.0]]))
    nowhere = Sighting(1, np.array([3]), np.array([[0.1, np.nan]]))
    for name, sighting, expected in [
        ("both", both, "message 1: found markers with and without ids"),
        ("twice", twice, "message 1: found marker id 3 twice"),
        ("nowhere", nowhere, "/landmarks message 1: found a position that is not finite"),
    ]:
        run = Simulation((sighting,), np.zeros((1, 3)), np.array([3]), np.zeros((1, 2)))
        bag = write_bag(tmp_path / name, run, truth=False)
        with pytest.raises(InputError, match=expected):
            list(open_source(bag).events())


@pytest.mark.parametrize("named_first", [True, False])
def test_named_and_id_less_arrays_in_one_bag_are_refused(tmp_path: Path, named_first: bool) -> None:
    """The association numbers the landmarks it finds 1, 2, ...: in a bag that names
    some arrays' markers and not others, they would take the named landmarks' ids."""
    z = np.array([[0.1, 2.0], [0.2, 3.0]])
    named = Sighting(1, np.array([1, 2]), z)
    idless = Sighting(2, np.array([-1, -1]), z)
    empty = Sighting(3, np.zeros(0, dtype=np.int64), np.zeros((0, 2)))  # of neither kind
    first, second = (named, idless) if named_first else (idless, named)
    run = Simulation((first, empty, second), np.zeros((1, 3)), np.array([1, 2]), z)
    bag = write_bag(tmp_path / "both", run, truth=False)
    found = "id-less markers (negative ids) after named ones" if named_first else (
        "markers with ids after id-less ones")  # fmt: skip
    with pytest.raises(InputError, match=rf"message 3: found {re.escape(found)} \(message 1\)"):
        list(open_source(bag).events())


def test_without_rosbags_the_bag_names_the_extra(tmp_path: Path, run: Simulation) -> None:
    bag = write_bag(tmp_path / "run_bag", run)
    code = (
        "import sys\n"
        "class NoRosbags:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] == 'rosbags':\n"
        "            raise ImportError('not installed')\n"
        "sys.meta_path.insert(0, NoRosbags())\n"
        "from pathlib import Path\n"
        "from ekfviz.core.errors import InputError\n"
        "from ekfviz.sources import open_source\n"
        "try:\n"
        "    open_source(Path(sys.argv[1]))\n"
        "except InputError as error:\n"
        "    print(error)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code, str(bag)], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == (
        f"{bag}: reading a ROS 2 bag needs the rosbags library: pip install 'ekfviz[rosbag]'"
    )


def test_source_args_reach_the_source(tmp_path: Path, run: Simulation) -> None:
    bag = write_bag(tmp_path / "run_bag", run)
    args = SourceArgs({"truth_topic": "/ground_truth"}, frozenset({"truth_topic"}))
    source = open_source(bag, args)
    own = source.own_truth(print)
    assert own is not None and own.truth.track_xytheta is not None
    np.testing.assert_allclose(own.truth.track_xytheta[0], run.poses_xytheta[0], atol=1e-12)
    assert source.command_options(args) == ["--truth-topic", "/ground_truth"]


def test_rosbags_is_imported_only_when_a_bag_is_opened(tmp_path: Path, run: Simulation) -> None:
    bag = write_bag(tmp_path / "run_bag", run)
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "import ekfviz.cli\n"
        "from ekfviz.sources import open_source\n"
        "before = 'rosbags' in sys.modules\n"
        "open_source(Path(sys.argv[1]))\n"
        "print(before, 'rosbags' in sys.modules)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code, str(bag)], capture_output=True, text=True, check=True
    )
    assert result.stdout.split() == ["False", "True"]


def _tiny_bag(
    path: Path,
    *,
    quaternion: tuple[float, float, float, float] | None = None,
    x: float = 1.0,
    marker_xy: tuple[float, float] = (2.0, 1.0),
    truth_times: Sequence[float] = (),
) -> Path:
    """Three odometry poses (the second's position ``x`` and orientation ``quaternion``
    if given), a detection of landmark 1 at ``marker_xy`` after each, and a truth topic
    /gt with a pose at each of ``truth_times`` (after T0)."""
    landmark = Sighting(1, np.array([1]), np.array([[math.atan2(marker_xy[1], marker_xy[0]),
                                                     math.hypot(*marker_xy)]]))  # fmt: skip
    quaternion_type = STORE.types["geometry_msgs/msg/Quaternion"]
    with Writer(path, version=9) as writer:
        odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=STORE)
        marks = writer.add_connection("/landmarks", MARKER_ARRAY, typestore=STORE)
        gt = writer.add_connection("/gt", "geometry_msgs/msg/PoseStamped", typestore=STORE)
        for k, pose in enumerate([(0.0, 0.0, 0.0), (x, 0.0, 0.1), (2.0, 0.1, 0.2)]):
            time = T0 + k * DT
            message = odometry(time, np.array(pose))
            if k == 1 and quaternion is not None:
                message.pose.pose.orientation = quaternion_type(*quaternion)
            writer.write(odom, round(time * 1e9), STORE.serialize_cdr(message, ODOMETRY_TYPE))
            array = markers(time, landmark)
            writer.write(marks, round(time * 1e9), STORE.serialize_cdr(array, MARKER_ARRAY))
        for k, time in enumerate(truth_times):  # recorded in turn, stamped ``time``
            stamped = STORE.types["geometry_msgs/msg/PoseStamped"](
                header=_header(T0 + time, "map"), pose=_pose(0.0, 0.0, 0.0)
            )
            data = STORE.serialize_cdr(stamped, "geometry_msgs/msg/PoseStamped")
            writer.write(gt, round((T0 + k * 0.1) * 1e9), data)
    return path


ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"


def _last_pose(bag: Path) -> FloatArray:
    params = FilterParams(motion_noise=MotionNoise.PER_SQRT_SECOND)
    return final(open_source(bag).events(), params).pose


def test_a_quaternion_of_any_norm_gives_its_rotation_s_heading(tmp_path: Path) -> None:
    """The heading of a quaternion scaled by 2 is its rotation's (the yaw formula read
    it as 93.5 degrees at 45); a zero or non-finite one is refused, naming the message."""
    theta = 0.1
    unit = (0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2))
    plain = _last_pose(_tiny_bag(tmp_path / "unit", quaternion=unit))
    doubled = (2 * unit[0], 2 * unit[1], 2 * unit[2], 2 * unit[3])
    scaled = _last_pose(_tiny_bag(tmp_path / "scaled", quaternion=doubled))
    np.testing.assert_allclose(scaled, plain, rtol=0, atol=1e-12)
    for name, quaternion, expected in [
        ("zero", (0.0, 0.0, 0.0, 0.0), "/odom message 2: found an orientation quaternion of"
         " norm 0, expected a unit quaternion"),
        ("inf", (0.0, 0.0, math.inf, 1.0), "/odom message 2: found orientation z inf,"
         " expected a finite number"),
    ]:  # fmt: skip
        line = _failure(tmp_path, _tiny_bag(tmp_path / name, quaternion=quaternion))
        assert line.endswith(expected), line


def test_a_bag_s_numbers_are_checked_as_every_reader_s(tmp_path: Path) -> None:
    """Beyond +-1e18 (the filter's arithmetic would overflow: it was a filter fault at
    "line 21"), a marker at the sensor's origin (a landmark at the robot), a truth topic
    whose stamps go back (it was sorted without a word, moving the start)."""
    line = _failure(tmp_path, _tiny_bag(tmp_path / "far", x=1e300))
    assert line.endswith("/odom message 2: found position x 1e+300, expected a number within"
                         " +-1e18"), line  # fmt: skip
    line = _failure(tmp_path, _tiny_bag(tmp_path / "origin", marker_xy=(0.0, 0.0)))
    assert line.endswith("/landmarks message 1: found marker id 1 at range 0 (the sensor's"
                         " origin), expected a positive range"), line  # fmt: skip
    back = _tiny_bag(tmp_path / "back", truth_times=(0.0, 0.5, 0.25, 1.0))
    line = _failure(tmp_path, back, "--truth-topic", "/gt")
    assert "/gt message 3: found stamp" in line and "expected stamps that never decrease" in line


@pytest.mark.parametrize(
    "kind",
    [
        "fifo",
        *(
            pytest.param(k, marks=pytest.mark.slow)
            for k in ("folder", "dangling link", "link loop")
        ),
    ],
)
def test_only_the_storage_files_the_metadata_lists_are_read(tmp_path: Path, kind: str) -> None:
    """A file of the folder beside the bag's own is none of the bag's: a stray FIFO hung
    the replay for ever (SIGTERM too: a FIFO's open waits for a writer), a dangling link
    was a traceback, a folder refused a good bag. The bag's own storage file as a FIFO is
    one line."""
    bag = _tiny_bag(tmp_path / "bag")
    stray = bag / "old.db3"
    if kind == "fifo":
        os.mkfifo(stray)
    elif kind == "folder":
        stray.mkdir()
    elif kind == "dangling link":
        stray.symlink_to(tmp_path / "nowhere.db3")
    else:
        stray.symlink_to(stray)
    # a FIFO's open waits for a writer: in a process of its own, a hang fails at a time-out
    run = run_ekfviz_process if kind == "fifo" else run_ekfviz
    result = run("replay", bag, "--save", tmp_path / "ok.rrd")
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    if kind == "fifo":
        (storage,) = bag.glob("bag*.db3")
        storage.unlink()
        os.mkfifo(storage)
        line = _failure(tmp_path, bag, apart=True)
        assert line.endswith(
            f"{storage}: is a FIFO (named pipe), not a regular file; expected a storage file"
            " of the bag (metadata.yaml lists it)"
        ), line
