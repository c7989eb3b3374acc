"""Immutable per-event records: what the filter emits and every consumer reads.

A record carries the pose, its 3x3 covariance, every landmark mean with its 2x2
marginal covariance and, for an update, what was done with each observation. The full
(3+2N)^2 covariance is kept only when a consumer asks for it, because N can be large
and a run has many events.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, NamedTuple, TypeVar

import numpy as np

from ekfviz.core.correlation import Correlation
from ekfviz.core.health import CovarianceCheck
from ekfviz.core.types import BoolArray, FloatArray, Int8Array, IntArray

try:  # built by setup.py where a C compiler is (optional: numpy copies stand in)
    from ekfviz.core import _rows
except ImportError:  # pragma: no cover - an install without a C compiler
    _rows = None  # type: ignore[assignment]

HAVE_ROW_COPIES = _rows is not None


class EventKind(str, enum.Enum):
    """What produced a record."""

    INIT = "init"
    PREDICT = "predict"
    UPDATE = "update"


@dataclass(frozen=True, slots=True)
class Control:
    """A control read from a log: drive ``d`` metres, then turn ``alpha`` radians.

    ``time`` is the log's timestamp in seconds, when it has one: for a control that
    spans a known time, the time at its end (where the predict leaves the state).
    ``dt`` is the time in seconds the control spans, when known (velocity odometry held
    for ``dt``; the time since the previous timestamp of an extended log): the
    time-scaled motion noise needs it.
    """

    line: int
    d: float
    alpha: float
    time: float | None = None
    dt: float | None = None


@dataclass(frozen=True, slots=True)
class Sighting:
    """An observation line read from a log.

    ``ids`` (m,) are landmark ids, ``z`` (m, 2) their (bearing, range) in file order;
    ``time`` is the log's timestamp in seconds, when it has one.
    """

    line: int
    ids: IntArray
    z: FloatArray
    time: float | None = None


@dataclass(frozen=True, slots=True)
class Scan:
    """An observation line whose landmarks are unknown (``scan`` in the extended format).

    ``z`` (m, 2) is the (bearing, range) of each measurement in file order; the
    association decides which landmark, if any, each belongs to. ``diameters`` (m,) is
    what the sensor says of each object's size (Victoria Park's trunk diameters), when
    it says anything.
    """

    line: int
    z: FloatArray
    time: float | None = None
    diameters: FloatArray | None = None


@dataclass(frozen=True, slots=True)
class Drive:
    """A vehicle's raw controls held over time spans, ending at ``time``.

    ``segments`` (k, 3) holds (speed m/s, steering rad, duration s) per span, in order:
    the controls read from the log, each held until the next input or the next scan.
    The filter's vehicle model (:mod:`ekfviz.models.ackermann`) drives them in one predict.
    """

    line: int
    segments: FloatArray
    time: float | None = None


LogEvent = Control | Sighting  # the events of logs with landmark ids
AnyEvent = Control | Sighting | Scan | Drive  # and id-less scans, vehicle controls


class NeedsIds(ValueError):
    """An event without landmark ids (an id-less scan) or a vehicle's raw controls where
    only observations with ids and (d, alpha) controls will do.

    :param line: the event's line in the log
    """

    def __init__(self, line: int, what: str) -> None:
        self.line = line
        self.what = what
        super().__init__(f"line {line}: found {what}, expected landmark ids and d alpha controls")

    def __reduce__(self) -> tuple[type[NeedsIds], tuple[int, str]]:
        return type(self), (self.line, self.what)


def with_ids(events: Iterable[AnyEvent]) -> Iterator[LogEvent]:
    """The events of a log with landmark ids, refusing an id-less scan or vehicle control.

    :raises NeedsIds: at the first event without ids, naming its line
    """
    for event in events:
        if not isinstance(event, Control | Sighting):
            what = "an id-less scan" if isinstance(event, Scan) else "speed and steering controls"
            raise NeedsIds(event.line, what)
        yield event


@dataclass(frozen=True, slots=True)
class Observations:
    """What one update did with each landmark of its observation line, in file order.

    Landmarks seen for the first time are initialised, not used to correct the state:
    their ``initialised`` flag is set and their prediction, innovation, S and NIS are NaN.
    An observation the filter could not use is ``skipped`` (the record's warnings say
    why): its NIS is NaN, and so are its prediction, innovation and S where undefined.

    :param ids: (m,) landmark ids
    :param z: (m, 2) measured (bearing, range)
    :param z_pred: (m, 2) predicted (bearing, range) just before the landmark was folded in
    :param innovation: (m, 2) z - z_pred, bearing wrapped to (-pi, pi]
    :param S: (m, 2, 2) innovation covariance
    :param nis: (m,) normalised innovation squared nu^T S^-1 nu (2 dof each)
    :param initialised: (m,) True where the landmark was first seen here
    :param skipped: (m,) True where the observation was not used (see the warnings)
    """

    ids: IntArray
    z: FloatArray
    z_pred: FloatArray
    innovation: FloatArray
    S: FloatArray
    nis: FloatArray
    initialised: BoolArray
    skipped: BoolArray

    def __len__(self) -> int:
        return int(self.ids.shape[0])


class Fate(enum.IntEnum):
    """What the association made of one measurement of a scan."""

    MATCHED = 0  # paired with a landmark of the map (confirmed or tentative)
    NEW = 1  # explained by no landmark: starts a tentative landmark
    REJECTED = 2  # compatible with a landmark but left out of the best joint pairing: clutter


@dataclass(frozen=True, slots=True)
class ScanAssociation:
    """What the association decided at one scan (see :mod:`ekfviz.association`).

    :param method: "nn" or "jcbb"
    :param z: (m, 2) the scan's (bearing, range), in file order
    :param fate: (m,) a :class:`Fate` per measurement
    :param landmark: (m,) the id each measurement was paired with or started, -1 when rejected
    :param gate_ids: (g,) the landmarks whose gate some measurement fell in (the candidates)
    :param gate_z: (g, 2) their predicted (bearing, range)
    :param gate_S: (g, 2, 2) their innovation covariances
    :param gate_threshold: the chi-square quantile of the individual gate (2 dof)
    :param hypotheses: how many JCBB hypotheses (search nodes) were explored
    :param joint_nis: the joint Mahalanobis distance squared of the chosen pairing
    :param exhausted: the search ran out of its budget (hypotheses or work per scan)
    :param tentative: (t,) the landmarks still tentative after this scan
    :param confirmed: (c,) the landmarks confirmed at this scan
    :param removed: (r,) the tentative landmarks removed at this scan
    :param diameters: (m,) the sensor's size of each measured object, when known
    :param truth: (m,) the true landmark id of each measurement (-1 for clutter), when known
    :param fallback: when the search was cut short, what the pairing is instead: "best
        found" (the best jointly compatible pairing reached) or "nearest neighbour"; ""
        otherwise (see :mod:`ekfviz.association.jcbb`)
    """

    method: str
    z: FloatArray
    fate: Int8Array
    landmark: IntArray
    gate_ids: IntArray
    gate_z: FloatArray
    gate_S: FloatArray  # noqa: N815 (S, the textbook symbol)
    gate_threshold: float
    hypotheses: int
    joint_nis: float
    exhausted: bool
    tentative: IntArray
    confirmed: IntArray
    removed: IntArray
    diameters: FloatArray | None = None
    truth: IntArray | None = None
    fallback: str = ""

    def count(self, fate: Fate) -> int:
        return int(np.count_nonzero(self.fate == fate))


@dataclass(frozen=True, slots=True)
class EventRecord:
    """The filter state right after one event (initialisation, predict or update).

    :param event: event index: 0 for the initialisation, +1 for every predict and update
    :param step: 0 for the initialisation, then one per control/observation cycle
    :param kind: what produced this record
    :param line: 1-based line of the log that produced it (0 when none did)
    :param pose: (3,) x, y, theta with theta in (-pi, pi]
    :param pose_cov: (3, 3) pose covariance
    :param landmark_ids: (N,) ids in state order (the order of first sighting)
    :param landmarks_xy: (N, 2) landmark means
    :param landmark_covs: (N, 2, 2) landmark marginal covariances
    :param control: (2,) the (d, alpha) of a predict, else None
    :param observations: what an update or the initialisation did, else None
    :param full_cov: (3+2N, 3+2N) covariance, only when the consumer asked for it
    :param time: the log's timestamp of the event in seconds, when it has one
    :param warnings: what went wrong at this event without stopping the run, one
        sentence each (a skipped observation, a covariance that lost definiteness)
    :param covariance: the check of the whole covariance, at the events where it ran
    :param correlation: the correlation matrix of the whole covariance, at the events
        where the replay took it (see :mod:`ekfviz.core.correlation`)
    :param association: what the association decided, at the update of a scan
    :param path_xytheta: (K, 3) an offline filter's estimate of every pose of the run,
        the start's first, at its record after ``finish()`` (a smoother's whole path)
    """

    event: int
    step: int
    kind: EventKind
    line: int
    pose: FloatArray
    pose_cov: FloatArray
    landmark_ids: IntArray
    landmarks_xy: FloatArray
    landmark_covs: FloatArray
    control: FloatArray | None = None
    observations: Observations | None = None
    full_cov: FloatArray | None = None
    time: float | None = None
    warnings: tuple[str, ...] = ()
    covariance: CovarianceCheck | None = None
    correlation: Correlation | None = None
    association: ScanAssociation | None = None
    path_xytheta: FloatArray | None = None

    @property
    def n_landmarks(self) -> int:
        return int(self.landmark_ids.shape[0])


def landmark_marginals(P: FloatArray, n_landmarks: int) -> FloatArray:
    """Gather the 2x2 diagonal landmark blocks of a state covariance in O(N).

    :return: (N, 2, 2) array of marginal covariances
    """
    # P[3:, 3:] viewed as (N, 2, N, 2) blocks: its (i, :, i, :) diagonal, without a copy of P
    blocks = P[3 : 3 + 2 * n_landmarks, 3 : 3 + 2 * n_landmarks].reshape(
        n_landmarks, 2, n_landmarks, 2
    )
    covs: FloatArray = np.diagonal(blocks, axis1=0, axis2=2).transpose(2, 0, 1).copy()
    return covs


ArrayT = TypeVar("ArrayT", bound=np.ndarray)


def frozen(array: ArrayT) -> ArrayT:
    """Make an array read-only so that a record cannot be changed after the fact."""
    array.setflags(write=False)
    return array


def snapshot(
    x: FloatArray,
    P: FloatArray,
    *,
    event: int,
    step: int,
    kind: EventKind,
    line: int = 0,
    landmark_ids: IntArray | None = None,
    control: FloatArray | tuple[float, float] | None = None,
    observations: Observations | None = None,
    full_cov: bool = False,
    time: float | None = None,
    warnings: tuple[str, ...] = (),
    covariance: CovarianceCheck | None = None,
    association: ScanAssociation | None = None,
    landmark_covs: FloatArray | None = None,
) -> EventRecord:
    """Build a record from a state in the classic layout x = [x, y, theta, l1x, l1y, ...].

    The one way records are made, by the built-in filter and by a plugged one alike.
    Copies what it keeps: the caller may go on changing ``x`` and ``P``. A read-only
    int64 ``landmark_ids`` and ``landmark_covs`` are kept as they are, without a copy: a
    filter hands the same arrays to every record until its map changes (consumers
    then compare them by identity), which at a few landmarks halves a record's cost.

    :param x: (3+2N,) state mean
    :param P: (3+2N, 3+2N) state covariance (only the diagonal blocks are read unless
        ``full_cov``)
    :param landmark_ids: (N,) ids in state order; default 1..N
    :param landmark_covs: (N, 2, 2) the marginals of ``P``'s landmarks, read-only, when
        the caller has them already (see :func:`landmark_marginals`)
    """
    n_landmarks = (x.shape[0] - 3) // 2
    if x.shape[0] != 3 + 2 * n_landmarks or P.shape != (x.shape[0], x.shape[0]):
        raise ValueError(
            f"expected x of length 3+2N and P of shape (3+2N, 3+2N), got {x.shape} and {P.shape}"
        )
    if landmark_ids is None:
        landmark_ids = np.arange(1, n_landmarks + 1, dtype=np.int64)
    if not _kept(landmark_ids, np.int64):
        landmark_ids = frozen(np.array(landmark_ids, dtype=np.int64))
    if landmark_covs is None or not _kept(landmark_covs, np.float64):
        landmark_covs = frozen(landmark_marginals(P, n_landmarks))
    mean = frozen(x.astype(np.float64))  # pose and landmarks: views of one copy
    return kept_record(
        event, step, kind, line, mean[:3], frozen(P[:3, :3].astype(np.float64)),
        landmark_ids, mean[3:].reshape(n_landmarks, 2), landmark_covs,
        None if control is None else frozen(np.array(control, dtype=np.float64)),
        observations,
        frozen(np.array(P, dtype=np.float64)) if full_cov else None,
        time, warnings, covariance, association,
    )  # fmt: skip


# A frozen dataclass's __init__ sets each field through object.__setattr__ (a lookup by
# name each); its slots' own descriptors set them at under half the cost. A record is
# made per event, so kept_record uses them (the record stays as frozen as before).
_new = object.__new__
_SET = {name: EventRecord.__dict__[name].__set__ for name in EventRecord.__slots__}
(_set_event, _set_step, _set_kind, _set_line, _set_pose, _set_pose_cov, _set_ids, _set_xy,
 _set_covs, _set_control, _set_observations, _set_full_cov, _set_time, _set_warnings,
 _set_covariance, _set_correlation, _set_association, _set_path) = (
    _SET[name] for name in (
        "event", "step", "kind", "line", "pose", "pose_cov", "landmark_ids", "landmarks_xy",
        "landmark_covs", "control", "observations", "full_cov", "time", "warnings",
        "covariance", "correlation", "association", "path_xytheta",
    )
)  # fmt: skip


def kept_record(
    event: int,
    step: int,
    kind: EventKind,
    line: int,
    pose: FloatArray,
    pose_cov: FloatArray,
    landmark_ids: IntArray,
    landmarks_xy: FloatArray,
    landmark_covs: FloatArray,
    control: FloatArray | None = None,
    observations: Observations | None = None,
    full_cov: FloatArray | None = None,
    time: float | None = None,
    warnings: tuple[str, ...] = (),
    covariance: CovarianceCheck | None = None,
    association: ScanAssociation | None = None,
) -> EventRecord:
    """A record of parts that are the record's already: read-only float64 / int64 arrays
    of the shapes of :class:`EventRecord`, taken as they are, without a check or a copy.

    What :func:`snapshot` ends with, and what a filter that keeps its parts between
    records (:meth:`~ekfviz.filters.ekf.EkfSlam.record`) calls directly: it is made once
    per event, so it is the same record as ``EventRecord(...)`` at a third of the cost.
    """
    record: EventRecord = _new(EventRecord)
    _set_event(record, event)
    _set_step(record, step)
    _set_kind(record, kind)
    _set_line(record, line)
    _set_pose(record, pose)
    _set_pose_cov(record, pose_cov)
    _set_ids(record, landmark_ids)
    _set_xy(record, landmarks_xy)
    _set_covs(record, landmark_covs)
    _set_control(record, control)
    _set_observations(record, observations)
    _set_full_cov(record, full_cov)
    _set_time(record, time)
    _set_warnings(record, warnings)
    _set_covariance(record, covariance)
    _set_correlation(record, None)
    _set_association(record, association)
    _set_path(record, None)
    return record


_set_c_line, _set_c_d, _set_c_alpha, _set_c_time, _set_c_dt = (
    Control.__dict__[name].__set__ for name in ("line", "d", "alpha", "time", "dt")
)
_set_s_line, _set_s_ids, _set_s_z, _set_s_time = (
    Sighting.__dict__[name].__set__ for name in ("line", "ids", "z", "time")
)


def read_control(
    line: int, d: float, alpha: float, time: float | None = None, dt: float | None = None
) -> Control:
    """``Control(line, d, alpha, time, dt)`` put together as :func:`kept_record` puts a
    record, at half the cost: a reader makes one for every other line of a long log."""
    control: Control = _new(Control)
    _set_c_line(control, line)
    _set_c_d(control, d)
    _set_c_alpha(control, alpha)
    _set_c_time(control, time)
    _set_c_dt(control, dt)
    return control


def read_sighting(line: int, ids: IntArray, z: FloatArray, time: float | None = None) -> Sighting:
    """``Sighting(line, ids, z, time)`` as :func:`read_control` makes a control."""
    sighting: Sighting = _new(Sighting)
    _set_s_line(sighting, line)
    _set_s_ids(sighting, ids)
    _set_s_z(sighting, z)
    _set_s_time(sighting, time)
    return sighting


(_set_o_ids, _set_o_z, _set_o_z_pred, _set_o_innovation, _set_o_cov, _set_o_nis,
 _set_o_initialised, _set_o_skipped) = (
    Observations.__dict__[name].__set__
    for name in ("ids", "z", "z_pred", "innovation", "S", "nis", "initialised", "skipped")
)  # fmt: skip


def kept_observations(
    ids: IntArray,
    z: FloatArray,
    z_pred: FloatArray,
    innovation: FloatArray,
    S: FloatArray,
    nis: FloatArray,
    initialised: BoolArray,
    skipped: BoolArray,
) -> Observations:
    """``Observations(...)`` of parts that are its already (read-only arrays of its shapes),
    put together as :func:`kept_record` puts a record: an update makes one a line."""
    observations: Observations = _new(Observations)
    _set_o_ids(observations, ids)
    _set_o_z(observations, z)
    _set_o_z_pred(observations, z_pred)
    _set_o_innovation(observations, innovation)
    _set_o_cov(observations, S)
    _set_o_nis(observations, nis)
    _set_o_initialised(observations, initialised)
    _set_o_skipped(observations, skipped)
    return observations


def _kept(array: object, dtype: type[np.generic]) -> bool:
    """Whether an array can go into a record as it is: read-only, of the record's type."""
    return isinstance(array, np.ndarray) and array.dtype == dtype and not array.flags.writeable


class EventRows:
    """The plain predicts and updates of a replay as columns, written by the replay
    instead of a record each.

    A long log's events each cost more as a record, and on their way through the
    consumers, than in the filter, while the recorder reads them in columns. A replay
    given an ``EventRows`` (:func:`~ekfviz.runner.replay.replay`) writes here every plain
    predict of the built-in filter and, where :attr:`takes_updates` is set, every plain
    update (one by ids that changed no map and raised no warning, whose covariance is not
    checked and whose correlation is not due), and yields no record for them. The last
    event is always a record. The rows are in event order; the consumer reads them beside
    the records it gets (a row comes before the record after it) and :meth:`drop` s them
    once used. A row can be made the record the replay would have made
    (:meth:`records`, :meth:`latest`): a predict keeps the map of the event before it.

    A signal can raise anywhere (Ctrl-C in a replay is an exception): a row counts once
    all its columns are written, and the rows change as a whole where rows are forgotten
    (the columns and their count are one value, replaced at once).

    :ivar takes_updates: whether the replay may write updates here (the consumers of
        its records read none of theirs but what the rows hold)
    :ivar watch: called with the update rows that are forgotten (dropped or made
        records) or :meth:`settle` d, each row once, as :class:`UpdatesWatched` (the
        run's NIS and NEES counts)
    """

    def __init__(self, capacity: int = 4096) -> None:
        self._state = _Columns(
            0, np.empty((capacity, 3)), np.empty((capacity, 3, 3)), [], [], [], [], [], []
        )
        # the update rows' maps, row after row: a row holds read-only views of its part,
        # and a part is never written again (a full store is replaced, not reused)
        self._maps = _MapStore(16 * capacity)
        self.timed = False  # some row has a time
        self.takes_updates = False
        self.watch: Callable[[UpdatesWatched], object] | None = None
        # the newest row ever written, kept when dropped: where a stopped run stopped
        self._newest: tuple[_Row, FloatArray, FloatArray] | None = None
        # the newest update row ever written: the map of a predict row after it
        self._map: tuple[int, UpdateParts] | None = None
        self._seen = 0  # the first rows, handed to watch already (settle)

    # the columns, row after row (a row beyond len() is one left half written)
    @property
    def poses(self) -> FloatArray:
        return self._state.poses

    @property
    def pose_covs(self) -> FloatArray:
        return self._state.pose_covs

    @property
    def events(self) -> list[int]:
        return self._state.events

    @property
    def steps(self) -> list[int]:
        return self._state.steps

    @property
    def lines(self) -> list[int]:
        return self._state.lines

    @property
    def times(self) -> list[float | None]:
        return self._state.times

    @property
    def controls(self) -> list[tuple[float, float] | None]:
        """Each predict's (d, alpha); None at an update."""
        return self._state.controls

    @property
    def updates(self) -> list[UpdateParts | None]:
        """What each update did and its map (the filter's own arrays); None at a predict."""
        return self._state.updates

    def __len__(self) -> int:
        return self._state.complete

    def add(
        self,
        event: int,
        step: int,
        line: int,
        time: float | None,
        control: tuple[float, float],
        x: FloatArray,
        P: FloatArray,
    ) -> None:
        """A predict's row: its timelines and control, and the pose and pose covariance
        copied from the state ``x`` (3+2N,...) and ``P`` (classic layout, any capacity)."""
        self._copy(x, P, self._state)
        self._add(event, step, line, time, control, None)

    def add_update(
        self,
        event: int,
        step: int,
        line: int,
        time: float | None,
        observations: Observations,
        x: FloatArray,
        P: FloatArray,
        ids: IntArray,
    ) -> None:
        """An update's row: its timelines, what it did, the pose and pose covariance
        copied from ``x`` and ``P`` as :meth:`add` does, and its map: the landmarks
        ``ids`` (an array the row keeps) with their means and 2x2 marginals copied from
        ``x`` and ``P`` (landmark k at 3 + 2k, no changes of P pending) into read-only
        arrays the row keeps, as a record would."""
        n = len(ids)
        xy, covs, start = self._maps.room(n)
        self._copy(x, P, self._state, xy, covs, start, n)
        update = (observations, ids, *self._maps.taken(start, n))
        self._add(event, step, line, time, None, update)
        self._map = (event, update)

    @staticmethod
    def _copy(
        x: FloatArray,
        P: FloatArray,
        state: _Columns,
        xy: FloatArray | None = None,
        covs: FloatArray | None = None,
        start: int = 0,
        n: int = 0,
    ) -> None:
        """Copy the pose and pose covariance into the next row of ``state`` (grown if
        full) and the first ``n`` landmarks' means and marginals into ``xy`` and ``covs``
        from ``start`` on: one compiled call where ``P`` is the square buffer of ``x``'s
        capacity (a filter's own), numpy's copies otherwise."""
        row = state.complete
        if row == state.poses.shape[0]:
            state.grown()
        if _rows is not None and P.shape == (len(x), len(x)) and P.flags.c_contiguous:
            map_xy, map_covs = _NO_MAP if xy is None or covs is None else (xy, covs)
            _rows.copy_row(x, P, state.poses, state.pose_covs, row, map_xy, map_covs, start, n)
            return
        state.poses[row] = x[:3]
        state.pose_covs[row] = P[:3, :3]
        if n:
            assert xy is not None and covs is not None
            xy[start : start + n] = x[3 : 3 + 2 * n].reshape(n, 2)
            covs[start : start + n] = landmark_marginals(P, n)

    def _add(
        self,
        event: int,
        step: int,
        line: int,
        time: float | None,
        control: tuple[float, float] | None,
        update: UpdateParts | None,
    ) -> None:
        """The row's other columns, after its pose (:meth:`_copy`); then it counts."""
        state = self._state
        row = state.complete
        if len(state.events) != row:  # a row left half written (events come first)
            for column in state.lists():
                del column[row:]
        state.events.append(event)
        state.steps.append(step)
        state.lines.append(line)
        state.times.append(time)
        state.controls.append(control)
        state.updates.append(update)
        if time is not None:
            self.timed = True
        state.complete = row + 1  # the row counts: all of it written

    def drop(self, count: int) -> None:
        """Forget the first ``count`` rows (used); the newest is kept for :meth:`latest`."""
        state = self._state
        total = state.complete
        if count <= 0:
            return
        count = min(count, total)
        if count == total:
            self._newest = self._row(total - 1)
        self._watched(self._seen, count)
        self._state = state.rest(count)
        self._seen = max(self._seen - count, 0)
        self.timed = any(time is not None for time in self.times)

    def settle(self) -> None:
        """Hand every row written so far to :attr:`watch` (the rows are kept; a row is
        watched once): before the run is judged."""
        count = len(self)
        self._watched(self._seen, count)
        self._seen = count

    def _watched(self, start: int, stop: int) -> None:
        """Hand the update rows ``start:stop`` to :attr:`watch`."""
        if self.watch is None or start >= stop:
            return
        state = self._state
        at = [k for k in range(start, stop) if state.updates[k] is not None]
        if at:
            times = [state.times[k] for k in at]
            self.watch(
                UpdatesWatched(
                    [state.updates[k][0] for k in at],  # type: ignore[index]
                    np.array([state.steps[k] for k in at], dtype=np.int64),
                    np.array([math.nan if t is None else t for t in times], dtype=np.float64),
                    state.poses[at],
                    state.pose_covs[at],
                )
            )

    def _row(self, row: int) -> tuple[_Row, FloatArray, FloatArray]:
        """A row's columns, its pose and pose covariance (copies)."""
        state = self._state
        return (
            (
                state.events[row], state.steps[row], state.lines[row], state.times[row],
                state.controls[row], state.updates[row],
            ),
            state.poses[row].copy(),
            state.pose_covs[row].copy(),
        )  # fmt: skip

    def records(self, start: int, before: EventRecord) -> list[EventRecord]:
        """The rows from ``start`` on as the records the replay would have made (a
        predict with the map of the event before it, ``before`` the record before them);
        the rows are forgotten here."""
        made = []
        for row in range(start, len(self)):
            record = self._record(*self._row(row), before)
            made.append(record)
            before = record
        self._watched(max(start, self._seen), len(self))
        self._state = self._state.first(start)
        self._seen = min(self._seen, start)
        self.timed = any(time is not None for time in self.times)
        return made

    def update_record(self, row: int) -> EventRecord:
        """The record of the update at ``row`` (the rows are kept)."""
        assert self.updates[row] is not None
        return self._record(*self._row(row), None)

    def latest(self, record: EventRecord | None) -> EventRecord | None:
        """The newer of ``record`` and the newest row ever written (as a record): where
        a run that stopped got to."""
        newest = self._row(len(self) - 1) if len(self) else self._newest
        if newest is None or record is None or newest[0][0] <= record.event:
            return record
        before = record
        if newest[0][5] is None and self._map is not None and self._map[0] > record.event:
            # a predict after an update row: that update's map
            _, ids, xy, covs = self._map[1]
            before = kept_record(
                record.event, record.step, record.kind, record.line, record.pose,
                record.pose_cov, ids, xy, covs,
            )  # fmt: skip
        return self._record(*newest, before)

    @staticmethod
    def _record(
        row: _Row, pose: FloatArray, pose_cov: FloatArray, before: EventRecord | None
    ) -> EventRecord:
        event, step, line, time, control, update = row
        if update is None:
            assert before is not None  # a predict keeps the map of the event before it
            ids, xy, covs = before.landmark_ids, before.landmarks_xy, before.landmark_covs
            kind, observations = EventKind.PREDICT, None
            made_control = frozen(np.array(control, dtype=np.float64))
        else:
            observations, ids, xy, covs = update
            kind, made_control = EventKind.UPDATE, None
        return kept_record(
            event, step, kind, line, frozen(pose), frozen(pose_cov), ids, xy, covs,
            made_control, observations, time=time,
        )  # fmt: skip


class UpdatesWatched(NamedTuple):
    """Update rows handed to :attr:`EventRows.watch`: what each did, its step and time
    (NaN where none), its pose (k, 3) and pose covariance (k, 3, 3)."""

    observations: list[Observations]
    steps: IntArray
    times: FloatArray
    poses: FloatArray
    pose_covs: FloatArray


class _Columns:
    """The rows of :class:`EventRows`: how many are complete, and their columns."""

    __slots__ = (
        "complete",
        "controls",
        "events",
        "lines",
        "pose_covs",
        "poses",
        "steps",
        "times",
        "updates",
    )  # fmt: skip

    def __init__(
        self,
        complete: int,
        poses: FloatArray,
        pose_covs: FloatArray,
        events: list[int],
        steps: list[int],
        lines: list[int],
        times: list[float | None],
        controls: list[tuple[float, float] | None],
        updates: list[UpdateParts | None],
    ) -> None:
        self.complete = complete
        self.poses, self.pose_covs = poses, pose_covs
        self.events, self.steps, self.lines, self.times = events, steps, lines, times
        self.controls, self.updates = controls, updates

    def lists(self) -> tuple[list[Any], ...]:
        return self.events, self.steps, self.lines, self.times, self.controls, self.updates

    def grown(self) -> None:
        """Twice the room in the arrays, the rows so far copied."""
        self.poses = np.concatenate([self.poses, np.empty_like(self.poses)])
        self.pose_covs = np.concatenate([self.pose_covs, np.empty_like(self.pose_covs)])

    def rest(self, count: int) -> _Columns:
        """The rows after the first ``count``, in columns of their own."""
        total = self.complete
        poses, pose_covs = np.empty_like(self.poses), np.empty_like(self.pose_covs)
        poses[: total - count] = self.poses[count:total]
        pose_covs[: total - count] = self.pose_covs[count:total]
        return _Columns(
            total - count, poses, pose_covs,
            *(column[count:total] for column in self.lists()),
        )  # fmt: skip

    def first(self, count: int) -> _Columns:
        """The first ``count`` rows (the arrays shared: rows beyond are not read)."""
        return _Columns(
            count, self.poses, self.pose_covs, *(column[:count] for column in self.lists())
        )


class _MapStore:
    """The update rows' maps: landmark means and marginals, update after update, in
    buffers of their own that are filled once and never written again (a full one is
    replaced): a row's read-only views of its part stay what they were for as long as
    anything holds them."""

    __slots__ = ("_covs", "_read_covs", "_read_xy", "_room", "_used", "_xy")

    def __init__(self, room: int) -> None:
        self._room = room
        self._fresh(room)

    def _fresh(self, room: int) -> None:
        self._xy, self._covs = np.empty((room, 2)), np.empty((room, 2, 2))
        self._read_xy, self._read_covs = self._xy.view(), self._covs.view()
        self._read_xy.flags.writeable = self._read_covs.flags.writeable = False
        self._used = 0

    def room(self, n: int) -> tuple[FloatArray, FloatArray, int]:
        """The buffers to write ``n`` landmarks into and where (:meth:`taken` after)."""
        if self._used + n > len(self._xy):
            self._fresh(max(self._room, n))
        return self._xy, self._covs, self._used

    def taken(self, start: int, n: int) -> tuple[FloatArray, FloatArray]:
        """The ``n`` landmarks written from ``start`` on, as read-only views (means
        (n, 2), marginals (n, 2, 2)); the buffers' room after them is the next part's."""
        self._used = start + n
        return self._read_xy[start : start + n], self._read_covs[start : start + n]


# room for no landmark, where a row copies a pose alone
_NO_MAP = (np.empty((0, 2)), np.empty((0, 2, 2)))

# an update row's observations and map: landmark ids, means (N, 2), marginals (N, 2, 2)
UpdateParts = tuple[Observations, IntArray, FloatArray, FloatArray]
# event step line time control update
_Row = tuple[int, int, int, float | None, tuple[float, float] | None, UpdateParts | None]
