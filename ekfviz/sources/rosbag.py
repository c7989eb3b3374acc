"""A ROS 2 bag (sqlite3 or MCAP storage), read through the ``rosbags`` library.

``ekfviz replay BAG --odom /odom --landmarks /landmarks [--truth-topic /ground_truth]``
takes three topics of the bag directory (the one holding ``metadata.yaml``):

- odometry, ``nav_msgs/msg/Odometry``: the first message is where the robot starts;
  the motion from each pose to the next is one control of the filter's model, drive
  ``d`` along the previous heading then turn ``alpha``: ``d`` the length of the step,
  negative when it goes backwards, ``alpha`` the change of heading. The control spans
  the time between the two stamps, so the motion noise is time-scaled by default, as
  for MRCLAM's velocity odometry. Odometry integrated from drive-then-turn controls
  (a simulated run's) gives those controls back, to rounding (1e-12);
- landmark detections, ``visualization_msgs/msg/MarkerArray``: one observation per
  array, each marker a landmark seen at its position (x ahead, y left) in the robot's
  frame, as (bearing, range); the marker's id is the landmark's. An array whose ids
  are all negative is an id-less scan: the association decides which landmark each is
  (an empty array is a scan too when the bag's first detections are id-less).
  ``DELETE`` and ``DELETEALL`` markers are not detections and are skipped;
- truth (optional), ``nav_msgs/msg/Odometry`` or ``geometry_msgs/msg/PoseStamped``:
  the true track by time (the bag knows no true landmarks: ``--truth FILE`` gives them).

Times are the messages' header stamps (a MarkerArray's: its first marker's); an empty
array's, or a stamp left at zero, is the time the bag recorded the message. At equal
times the motion comes before the detections. An event's "line" is its message's number
among the topics read, in the bag's order; an error names a topic's message by its
number on that topic. ``rosbags`` is an optional dependency
(``pip install 'ekfviz[rosbag]'``), imported only when a bag is opened.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from ekfviz.core.errors import InputError
from ekfviz.core.params import MotionNoise
from ekfviz.core.records import AnyEvent, Control, Scan, Sighting
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.io.text import (
    MAX_MAGNITUDE,
    RANGE_TEXT,
    ProgressCallback,
    WarningCallback,
    open_input,
)
from ekfviz.models.angles import wrap_angle
from ekfviz.sources.base import OwnTruth, Source, SourceArgs, SourceOption, register

PANEL = "ROS 2 bag"
METADATA = "metadata.yaml"
ODOMETRY = "nav_msgs/msg/Odometry"
MARKERS = "visualization_msgs/msg/MarkerArray"
POSE = "geometry_msgs/msg/PoseStamped"
DELETE, DELETEALL = 2, 3  # visualization_msgs/msg/Marker actions that detect nothing
Pose = tuple[float, float, float]  # x, y, heading
EXTRA = "reading a ROS 2 bag needs the rosbags library: pip install 'ekfviz[rosbag]'"

ODOM = SourceOption(
    "odom", str, f"The bag's odometry topic ({ODOMETRY}).", default="/odom",
    show_default=True, panel=PANEL, metavar="<topic>",
)  # fmt: skip
LANDMARKS = SourceOption(
    "landmarks", str, f"The bag's landmark detections topic ({MARKERS}).",
    default="/landmarks", show_default=True, panel=PANEL, metavar="<topic>",
)  # fmt: skip
TRUTH_TOPIC = SourceOption(
    "truth_topic", str,
    f"The bag's true poses topic ({ODOMETRY} or {POSE}) \\[default: none].",
    panel=PANEL, metavar="<topic>",
)  # fmt: skip


@register
@dataclass(frozen=True, slots=True)
class RosbagSource(Source):
    """A ROS 2 bag directory and the topics to read."""

    kind = "rosbag"
    description = f"a ROS 2 bag directory ({METADATA})"
    marker = METADATA
    options = (ODOM, LANDMARKS, TRUTH_TOPIC)
    motion_noise = MotionNoise.PER_SQRT_SECOND

    path: Path
    odom: str = "/odom"
    landmarks: str = "/landmarks"
    truth_topic: str | None = None
    storage: tuple[Path, ...] = ()  # the storage files metadata.yaml lists

    @classmethod
    def detect(cls, path: Path) -> bool:
        return path.is_dir() and (path / METADATA).is_file()

    @classmethod
    def open(cls, path: Path, args: SourceArgs) -> RosbagSource:
        """The bag, its topics checked: there, of the right type, not empty."""
        odom, landmarks, truth = (args.value(o) for o in (ODOM, LANDMARKS, TRUTH_TOPIC))
        source = cls(
            path, str(odom), str(landmarks), None if truth is None else str(truth),
            _storage_files(path),
        )  # fmt: skip
        with _Bag(source) as reader:
            source._topics(reader)
        return source

    @property
    def files(self) -> list[Path]:
        """The metadata and the storage files it lists (not every file of the folder:
        an old recording beside them is none of the bag's)."""
        return [self.path / METADATA, *self.storage]

    @property
    def progress_paths(self) -> list[Path]:
        return self.files[1:]

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        """The controls and observations in time order (read whole, then merged)."""
        odometry: list[tuple[float, int, Pose]] = []
        detections: list[tuple[float, int, IntArray, FloatArray]] = []
        with _Bag(self) as reader:
            topics = self._topics(reader)
            wanted = [topics[self.odom], topics[self.landmarks]]
            total = sum(p.stat().st_size for p in self.progress_paths)
            count = max(1, sum(c.msgcount for c in wanted))
            messages = _messages(self.path, reader, wanted)
            for number, (connection, recorded, message) in enumerate(messages):
                # kept as numbers, not messages: a long bag's messages would not fit
                time, line = _stamp(message, recorded), number + 1
                if connection.topic == self.odom:
                    nth = len(odometry) + 1  # errors count a topic's messages
                    odometry.append((time, line, self._pose(message, self.odom, nth)))
                else:
                    nth = len(detections) + 1
                    detections.append((time, line, *self._detected(message, nth)))
                if progress is not None and number % 256 == 0:
                    progress(total * number // count)
        if progress is not None:
            progress(total)
        yield from self._merged(odometry, detections)

    def _merged(
        self,
        odometry: list[tuple[float, int, Pose]],
        detections: list[tuple[float, int, IntArray, FloatArray]],
    ) -> Iterator[AnyEvent]:
        """Controls between consecutive poses and observations, by stamp (motion first)."""
        self._check_order(self.odom, [t for t, _, _ in odometry])
        self._check_order(self.landmarks, [t for t, _, _, _ in detections])
        # an empty array (nothing in view) is a scan in a bag of id-less detections
        idless = self._idless(detections)
        k, j = 1, 0
        while k < len(odometry) or j < len(detections):
            if k < len(odometry) and (j == len(detections) or odometry[k][0] <= detections[j][0]):
                (before, _, start), (time, line, pose) = odometry[k - 1], odometry[k]
                d, alpha = _control(start, pose)
                yield Control(line=line, d=d, alpha=alpha, time=time, dt=time - before)
                k += 1
            else:
                time, line, ids, z = detections[j]
                if (ids < 0).all() and (ids.size or idless):
                    yield Scan(line=line, z=z, time=time)
                else:
                    yield Sighting(line=line, ids=ids, z=z, time=time)
                j += 1

    def _idless(self, detections: list[tuple[float, int, IntArray, FloatArray]]) -> bool:
        """Whether the bag's landmark arrays leave their markers unnamed (negative ids),
        as its first array with markers does: all of them must be of its kind. The
        association numbers the landmarks it finds 1, 2, ..., which would be the ids of
        others that the bag names.

        :raises InputError: naming the first message of the other kind
        """
        named = [(nth, bool((ids >= 0).all())) for nth, (_, _, ids, _) in
                 enumerate(detections, start=1) if ids.size]  # fmt: skip
        if not named:
            return False
        first, by_ids = named[0]
        other = next((nth for nth, kind in named if kind != by_ids), None)
        if other is not None:
            found, before = (
                ("id-less markers (negative ids)", "named ones")
                if by_ids
                else ("markers with ids", "id-less ones")
            )
            raise InputError(
                self.path, 0, f"{self.landmarks} message {other}: found {found} after {before}"
                f" (message {first}), expected all landmarks named or none in a bag",
            )  # fmt: skip
        return not by_ids

    def _pose(self, message: Any, topic: str, nth: int) -> Pose:
        """The pose of the topic's ``nth`` message, its numbers checked as every reader
        checks its own: finite, within +-1e18, a quaternion that is a rotation (of any
        norm but 0: its heading does not depend on the norm).

        :raises InputError: naming the topic's message and what was found
        """
        pose = message.pose.pose if hasattr(message.pose, "pose") else message.pose
        where = f"{topic} message {nth}"
        position, q = pose.position, pose.orientation
        for name, value in (("x", position.x), ("y", position.y)):
            _checked(self.path, where, f"position {name}", value)
        quaternion = [_checked(self.path, where, f"orientation {name}", getattr(q, name))
                      for name in ("x", "y", "z", "w")]  # fmt: skip
        norm = math.hypot(*quaternion)
        if norm < 1e-9:
            raise InputError(
                self.path, 0, f"{where}: found an orientation quaternion of norm {norm:.3g},"
                " expected a unit quaternion",
            )  # fmt: skip
        return _heading(pose)

    def _detected(self, message: Any, nth: int) -> tuple[IntArray, FloatArray]:
        """The ids (negative: none) and (bearing, range) of the topic's ``nth`` array's
        markers, checked."""
        markers = [m for m in message.markers if m.action not in (DELETE, DELETEALL)]
        z = np.array(
            [
                (math.atan2(m.pose.position.y, m.pose.position.x),
                 math.hypot(m.pose.position.x, m.pose.position.y))
                for m in markers
            ],
            dtype=np.float64,
        ).reshape(-1, 2)  # fmt: skip
        ids = np.array([m.id for m in markers], dtype=np.int64)
        where = f"{self.landmarks} message {nth}"
        if not np.isfinite(z).all():
            raise InputError(self.path, 0, f"{where}: found a position that is not finite")
        for marker in markers:
            for name in ("x", "y"):
                _checked(self.path, where, f"marker {marker.id}'s {name}",
                         getattr(marker.pose.position, name))  # fmt: skip
        if len(z) and not (z[:, 1] > 0.0).all():
            k = int(np.flatnonzero(~(z[:, 1] > 0.0))[0])
            raise InputError(
                self.path, 0, f"{where}: found marker id {int(ids[k])} at range 0 (the"
                " sensor's origin), expected a positive range",
            )  # fmt: skip
        if (ids < 0).any() and not (ids < 0).all():
            raise InputError(
                self.path, 0, f"{where}: found markers with and without ids (negative),"
                " expected all landmarks named or none",
            )  # fmt: skip
        unique, counts = np.unique(ids[ids >= 0], return_counts=True)
        if (counts > 1).any():
            raise InputError(
                self.path, 0, f"{where}: found marker id {int(unique[counts > 1][0])} twice,"
                " expected each landmark once an array",
            )  # fmt: skip
        return ids, z

    def _check_order(self, topic: str, times: list[float]) -> None:
        for nth, (before, time) in enumerate(itertools.pairwise(times), start=2):
            if time < before:
                raise InputError(
                    self.path, 0, f"{topic} message {nth}: found stamp {time:.9f} s after"
                    f" {before:.9f} s, expected stamps that never decrease",
                )  # fmt: skip

    def own_truth(self, warn: WarningCallback) -> OwnTruth | None:
        """The truth topic's track, by stamp (no landmarks: a bag names none)."""
        if self.truth_topic is None:
            return None
        with _Bag(self) as reader:
            connection = self._topics(reader)[self.truth_topic]
            rows = [
                (_stamp(message, recorded), self._pose(message, self.truth_topic, number + 1))
                for number, (_, recorded, message) in enumerate(
                    _messages(self.path, reader, [connection])
                )
            ]
        self._check_order(self.truth_topic, [t for t, _ in rows])
        truth = GroundTruth(
            ids=np.zeros(0, dtype=np.int64),
            landmarks_xy=np.zeros((0, 2)),
            track_times=np.array([t for t, _ in rows]),
            track_xytheta=np.array([p for _, p in rows]).reshape(-1, 3),
        )
        return OwnTruth(truth, [self.path / METADATA])

    def _topics(self, reader: Any) -> dict[str, Any]:
        """The connections of the topics read, checked.

        :raises InputError: a topic missing, of another type or without messages
        """
        found = {c.topic: c for c in reader.connections}
        wanted: list[tuple[str, SourceOption, tuple[str, ...]]] = [
            (self.odom, ODOM, (ODOMETRY,)),
            (self.landmarks, LANDMARKS, (MARKERS,)),
        ]
        if self.truth_topic is not None:
            wanted.append((self.truth_topic, TRUTH_TOPIC, (ODOMETRY, POSE)))
        for topic, option, types in wanted:
            expected = " or ".join(types)
            connection = found.get(topic)
            if connection is None:
                have = ", ".join(f"{c.topic} ({c.msgtype})" for c in found.values()) or "none"
                raise InputError(
                    self.path, 0, f"has no topic {topic} ({option.flag}), expected {expected}"
                    f" messages there (topics: {have})",
                )  # fmt: skip
            if connection.msgtype not in types:
                raise InputError(
                    self.path, 0, f"topic {topic} ({option.flag}) holds {connection.msgtype},"
                    f" expected {expected}",
                )  # fmt: skip
            if sum(c.msgcount for c in reader.connections if c.topic == topic) == 0:
                raise InputError(
                    self.path, 0, f"topic {topic} ({option.flag}) has no messages, expected"
                    f" {expected} messages",
                )  # fmt: skip
        return found


class _Bag:
    """A source's bag opened with ``rosbags`` (imported here), its errors one line each."""

    def __init__(self, source: RosbagSource) -> None:
        self.path = source.path
        self.storage = source.storage  # (read from metadata.yaml once, when it opened)
        self.reader: Any = None

    def __enter__(self) -> Any:
        try:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise InputError(self.path, 0, EXTRA) from None
        for stored in self.storage:  # each a regular file that opens
            open_input(stored, "a storage file of the bag (metadata.yaml lists it)").close()
        # bags that do not carry their message definitions are read with Humble's
        reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        try:
            reader.open()
        except Exception as error:  # rosbags' reader errors, a bad metadata.yaml
            raise InputError(self.path, 0, f"cannot read the bag: {_said(error)}") from None
        self.reader = reader
        return reader

    def __exit__(self, *exc: object) -> None:
        self.reader.close()


def _messages(path: Path, reader: Any, connections: list[Any]) -> Iterator[tuple[Any, int, Any]]:
    """(connection, time recorded in ns, message) of the connections, in the bag's order."""
    try:
        for connection, recorded, raw in reader.messages(connections=connections):
            yield connection, recorded, reader.deserialize(raw, connection.msgtype)
    except InputError:
        raise
    except Exception as error:  # a storage or serialisation error of rosbags
        raise InputError(path, 0, f"cannot read the bag: {_said(error)}") from None


def _said(error: Exception) -> str:
    """What ``rosbags`` said, in one line (its first: a YAML error goes on for eight)."""
    lines = str(error).strip().splitlines()
    return lines[0].strip() if lines else type(error).__name__


def _stamp(message: Any, recorded: int) -> float:
    """The message's stamp in seconds: its header's (a MarkerArray's: its first
    marker's); the time the bag recorded it for an empty array or a header left at 0."""
    if hasattr(message, "markers"):
        if not message.markers:
            return recorded * 1e-9
        message = message.markers[0]
    stamp = message.header.stamp
    if stamp.sec == 0 and stamp.nanosec == 0:  # never filled in: 1970 is no robot's time
        return recorded * 1e-9
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _heading(pose: Any) -> Pose:
    """(x, y, heading) of a pose, the heading the yaw of its quaternion. The yaw's two
    terms both scale with the square of the norm, so a quaternion of another norm than 1
    (float32 rounding, a scaled one) gives the heading of its rotation."""
    q = pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), q.w * q.w + q.x * q.x - q.y * q.y - q.z * q.z)
    return float(pose.position.x), float(pose.position.y), yaw


def _checked(path: Path, where: str, name: str, value: float) -> float:
    """A number of a message: finite and within +-1e18, as every reader's.

    :raises InputError: naming the message and the field
    """
    value = float(value)
    if not math.isfinite(value) or abs(value) > MAX_MAGNITUDE:
        finite = math.isfinite(value)
        expected = f"a number within {RANGE_TEXT}" if finite else "a finite number"
        raise InputError(path, 0, f"{where}: found {name} {value:g}, expected {expected}")
    return value


def _storage_files(path: Path) -> tuple[Path, ...]:
    """The storage files a bag's ``metadata.yaml`` lists (``relative_file_paths``), as
    ``rosbags`` finds them; none where it does not read (``rosbags`` then says why).

    :raises InputError: the metadata that is no regular file (a FIFO would block)
    """
    with open_input(path / METADATA, "the bag's metadata (YAML)") as handle:
        text = handle.read(1 << 20)
    try:
        from ruamel.yaml import YAML  # rosbags' own YAML reader

        document = YAML(typ="safe").load(text)
        names = document["rosbag2_bagfile_information"]["relative_file_paths"]
        return tuple(path / PurePath(str(name)).name for name in names)
    except Exception:  # not a bag's metadata: rosbags' open says what is wrong
        return ()


def _control(before: Pose, after: Pose) -> tuple[float, float]:
    """The drive-then-turn (d, alpha) from one pose to the next.

    ``d`` is the length of the step, negative when it goes against the heading; a
    sideways slip (which drive-then-turn cannot make) is in neither.
    """
    dx, dy = after[0] - before[0], after[1] - before[1]
    ahead = dx * math.cos(before[2]) + dy * math.sin(before[2])
    d = math.copysign(math.hypot(dx, dy), ahead)
    return d, wrap_angle(after[2] - before[2])
