"""A log's events, and the per-event view of what a replay made of them.

The events a source reads (:class:`Control`, :class:`Sighting`, :class:`Scan`,
:class:`Drive`) go into a replay; what comes out are columnar batches
(:class:`~ekfviz.core.batch.EventBatch`), whose events a consumer may view one at a
time as an :class:`EventRecord`: the pose, its 3x3 covariance, every landmark mean with
its 2x2 marginal covariance and, for an update, what was done with each observation
(:class:`Observations`, and for a scan what the association decided,
:class:`ScanAssociation`).

The records made once per line of a log or per update (the events, and
:class:`Observations`) are named tuples: as immutable and typed as the frozen
dataclasses of the rest, made in a third of the time (a long log makes hundreds of
thousands of them). A named tuple's ``len()`` is its number of fields: an update's
number of observations is ``len(observations.ids)``.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import NamedTuple, TypeVar

import numpy as np

from ekfviz.core.correlation import Correlation
from ekfviz.core.health import CovarianceCheck
from ekfviz.core.types import BoolArray, FloatArray, Int8Array, IntArray


class EventKind(str, enum.Enum):
    """What produced a record."""

    INIT = "init"
    PREDICT = "predict"
    UPDATE = "update"


class Control(NamedTuple):
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


class Sighting(NamedTuple):
    """An observation line read from a log.

    ``ids`` (m,) are landmark ids, ``z`` (m, 2) their (bearing, range) in file order;
    ``time`` is the log's timestamp in seconds, when it has one.
    """

    line: int
    ids: IntArray
    z: FloatArray
    time: float | None = None


class Scan(NamedTuple):
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


class Drive(NamedTuple):
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


# the columns of what a filter computed of each observation (:attr:`Observations.table`)
Z_PRED, INNOVATION, S_ROWS, NIS = slice(0, 2), slice(2, 4), slice(4, 8), 8
TABLE_COLUMNS = 9


class Observations(NamedTuple):
    """What one update did with each landmark of its observation line, in file order.

    Landmarks seen for the first time are initialised, not used to correct the state:
    their ``initialised`` flag is set and their prediction, innovation, S and NIS are NaN.
    An observation the filter could not use is ``skipped`` (the record's warnings say
    why): its NIS is NaN, and so are its prediction, innovation and S where undefined.
    What the filter computed of each is one table, as its update writes it; ``z_pred``,
    ``innovation``, ``S`` and ``nis`` are views of its columns.

    :param ids: (m,) landmark ids
    :param z: (m, 2) measured (bearing, range)
    :param table: (m, 9) per observation: z_pred (2), innovation (2), S row by row (4), NIS
    :param initialised: (m,) True where the landmark was first seen here
    :param skipped: (m,) True where the observation was not used (see the warnings)
    """

    ids: IntArray
    z: FloatArray
    table: FloatArray
    initialised: BoolArray
    skipped: BoolArray

    @classmethod
    def of(
        cls,
        *,
        ids: IntArray,
        z: FloatArray,
        z_pred: FloatArray,
        innovation: FloatArray,
        S: FloatArray,
        nis: FloatArray,
        initialised: BoolArray,
        skipped: BoolArray,
    ) -> Observations:
        """Observations of their columns, the computed ones copied into one table."""
        table = np.empty((len(ids), TABLE_COLUMNS))
        table[:, Z_PRED], table[:, INNOVATION] = z_pred, innovation
        table[:, S_ROWS], table[:, NIS] = np.reshape(S, (-1, 4)), nis
        return cls(ids, z, frozen(table), initialised, skipped)

    @property
    def z_pred(self) -> FloatArray:
        """(m, 2) predicted (bearing, range) just before the landmark was folded in."""
        return self.table[:, Z_PRED]

    @property
    def innovation(self) -> FloatArray:
        """(m, 2) z - z_pred, bearing wrapped to (-pi, pi]."""
        return self.table[:, INNOVATION]

    @property
    def S(self) -> FloatArray:
        """(m, 2, 2) innovation covariance."""
        return self.table[:, S_ROWS].reshape(-1, 2, 2)

    @property
    def nis(self) -> FloatArray:
        """(m,) normalised innovation squared nu^T S^-1 nu (2 dof each)."""
        return self.table[:, NIS]


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
    """The filter state right after one event (initialisation, predict or update): one
    event of a batch, viewed on its own (:meth:`~ekfviz.core.batch.EventBatch.event`).

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
