"""One scan through the association: gate, pair, fold into the filter, confirm, remove.

The :class:`Associator` is what the runner calls once per :class:`~ekfviz.core.records.Scan`.
It reads the filter's x and P, predicts every landmark's measurement with ekfviz's own
sensor model, pairs the scan's measurements with landmarks (``nn`` or ``jcbb``), then
hands the filter the pairing as an ordinary observation (ids and measurements in file
order, the new landmarks last: see :meth:`EkfSlam.observe`), and finally asks it to
remove the tentative landmarks whose window ended unconfirmed.

A landmark whose gate is wide (its area in the plane, bearings scaled by the predicted
range, over ``single_gate_area``) is paired by JCBB only together with other wide ones,
``wide_pairs`` (3) in all.
One measurement alone cannot tell a landmark from clutter or from a new landmark that
fell in a wide gate (the pose is uncertain before a loop closes: a gate of tens of
square metres holds a false alarm as often as not), and pairs with landmarks mapped
just before (narrow gates, correlated with the pose) add no evidence; two wide pairs
must also agree in their geometry, and the joint gate of the second given the first is
small. So a loop closes at a scan that sees two or more of the old landmarks.

A measurement paired with no landmark is *new* when no landmark's gate at
``new_probability`` (wider than the pairing gate) holds it, and otherwise *rejected*:
it is near a landmark but left out of the best pairing, so it is taken for clutter
rather than start a duplicate of that landmark.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from ekfviz.association.gating import ScanGate, gate_scan, gate_threshold, marginals_of
from ekfviz.association.jcbb import jcbb
from ekfviz.association.nn import nearest_neighbour
from ekfviz.association.params import AssociationError, AssociationParams, Method
from ekfviz.association.tentative import TentativeBook
from ekfviz.core.records import Fate, Observations, Scan, ScanAssociation, frozen
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.models.range_bearing import RangeBearing


class ScanFilter(Protocol):
    """What the associator needs of a filter: its state, an update with ids, and removal."""

    @property
    def x(self) -> FloatArray: ...

    @property
    def P(self) -> FloatArray: ...

    @property
    def landmark_ids(self) -> list[int]: ...

    def observe(self, ids: Sequence[int] | IntArray, z: FloatArray) -> Observations: ...

    def remove_landmarks(self, ids: Sequence[int]) -> None: ...


_EMPTY_IDS = frozen(np.zeros(0, dtype=np.int64))
_NO_Z = frozen(np.zeros((0, 2)))
_NO_S = frozen(np.zeros((0, 2, 2)))
# the fates as plain ints: an IntEnum's member costs a class attribute lookup each time
_MATCHED, _NEW, _REJECTED = int(Fate.MATCHED), int(Fate.NEW), int(Fate.REJECTED)


class _Pairing:
    """What gating and pairing made of one scan: per measurement its candidate (a column
    of the gate) in the pairing (-1: none) and whether it lies in some landmark's gate at
    ``new_probability``; the gate's landmarks, predicted measurements and S; what JCBB
    said of its search. Python lists, a scan being a few measurements: a loop over them
    costs less than the numpy calls it replaces."""

    __slots__ = ("S", "columns", "exhausted", "fallback", "gate_ids", "hypotheses",
                 "joint_d2", "near", "z_pred")  # fmt: skip

    def __init__(
        self,
        m: int,
        gate_ids: IntArray = _EMPTY_IDS,
        z_pred: FloatArray = _NO_Z,
        S: FloatArray = _NO_S,
    ) -> None:
        self.columns: list[int] = [-1] * m
        self.near: list[bool] = [False] * m
        self.gate_ids, self.z_pred, self.S = gate_ids, z_pred, S
        self.hypotheses, self.joint_d2, self.exhausted, self.fallback = 0, 0.0, False, ""


class Associator:
    """Associates the scans of one run, keeping the tentative landmarks between them.

    :param sensor: the measurement model the filter uses
    :param R: (2, 2) measurement noise covariance
    :param scan_truth: per scan in file order, the true landmark id of each measurement
        (-1 or None for clutter), to keep in the records for the evaluation
    """

    def __init__(
        self,
        params: AssociationParams,
        sensor: RangeBearing,
        R: FloatArray,
        scan_truth: Sequence[Sequence[int | None]] | None = None,
    ) -> None:
        if params.method is Method.KNOWN:
            raise AssociationError("--association known reads the ids of the log: no associator")
        self.params = params
        self._sensor = sensor
        self._R = np.asarray(R, dtype=np.float64)
        self._gate = gate_threshold(params.gate_probability)
        self._new_gate = max(self._gate, gate_threshold(params.new_probability))
        self._book = TentativeBook(params.confirm, params.confirm_window)
        self._next_id = 1
        self._scan_truth = scan_truth
        self._scans = 0
        self._method, self._method_name = params.method, params.method.value

    @staticmethod
    def check_filter(slam: object, params: AssociationParams) -> None:
        """Refuse a filter that cannot drop tentative landmarks, unless none will be
        (``--confirm 1``)."""
        removes = getattr(slam, "removes_landmarks", None)  # a Plugged filter says so itself
        if not isinstance(removes, bool):
            removes = callable(getattr(slam, "remove_landmarks", None))
        if params.confirm > 1 and not removes:
            name = "it" if isinstance(getattr(slam, "name", None), str) else type(slam).__name__
            raise AssociationError(
                f"{name} has no remove_landmarks(ids), which tentative landmarks"
                " need: use --confirm 1 (every new landmark kept) with this filter"
            )

    @property
    def tentative(self) -> list[int]:
        return self._book.tentative

    def process(self, slam: ScanFilter, scan: Scan) -> tuple[Observations, ScanAssociation]:
        """Associate one scan and fold it into ``slam``.

        :return: what the filter did with the measurements it was given, and what the
            association decided of every measurement of the scan
        """
        self._book.next_scan()
        self._scans += 1
        z = np.asarray(scan.z, dtype=np.float64).reshape(-1, 2)
        m = z.shape[0]
        state_ids = (
            slam.landmark_ids_array()  # kept by the filter while its map is the same
            if isinstance(slam, EkfSlam)
            else np.asarray(slam.landmark_ids, dtype=np.int64)
        )
        pairing = _Pairing(m)
        if m and state_ids.shape[0]:
            pairing = self._paired(slam, state_ids, z)
        fates, landmarks, new_ids, matched_ids = self._fates(pairing)
        fate = np.array(fates, dtype=np.int8)
        landmark = np.array(landmarks, dtype=np.int64)
        if _REJECTED in fates:
            used = fate != _REJECTED
            observations = slam.observe(landmark[used], z[used])
        else:
            observations = slam.observe(landmark.copy(), z.copy())
        confirmed, removed = self._book.settle(matched_ids, new_ids)
        if removed:
            slam.remove_landmarks(removed)
        truth = self._truth_of_scan()
        association = ScanAssociation(
            method=self._method_name,
            z=frozen(z.copy()),
            fate=frozen(fate),
            landmark=frozen(landmark),
            gate_ids=frozen(pairing.gate_ids),
            gate_z=frozen(np.array(pairing.z_pred)),
            gate_S=frozen(np.array(pairing.S)),
            gate_threshold=self._gate,
            hypotheses=pairing.hypotheses,
            joint_nis=pairing.joint_d2,
            exhausted=pairing.exhausted,
            tentative=frozen(np.array(self._book.tentative, dtype=np.int64)),
            confirmed=frozen(np.array(confirmed, dtype=np.int64)),
            removed=frozen(np.array(removed, dtype=np.int64)),
            diameters=None if scan.diameters is None else frozen(np.array(scan.diameters)),
            truth=truth if truth is not None and truth.shape[0] == m else None,
            fallback=pairing.fallback,
        )
        return observations, association

    def _paired(self, slam: ScanFilter, state_ids: IntArray, z: FloatArray) -> _Pairing:
        """The scan ``z`` gated against the landmarks of ``slam`` and paired (nearest
        neighbour or JCBB)."""
        x = np.asarray(slam.x)
        U: FloatArray | None
        if isinstance(slam, EkfSlam):
            # the built-in filter's covariance with its pending low-rank changes: the
            # gating reads the pose's rows and the marginals (the records' own) without
            # folding them into P (a pass over all of it) once per scan
            P, U = slam.deferred_covariance()
            pose_rows, covs = slam.pose_rows(), slam.landmark_marginals()
        else:
            P, U = np.asarray(slam.P), None
            pose_rows, covs = P[:3], marginals_of(P)
        gate = gate_scan(x, pose_rows, covs, self._sensor, self._R, z, self._gate,
                         self._new_gate)  # fmt: skip
        pairing = _Pairing(z.shape[0], state_ids[gate.rows], gate.z_pred, gate.S)
        pairing.near = gate.near.tolist()
        if not gate.rows.size:
            return pairing
        if self._method is Method.NN:
            pairing.columns = nearest_neighbour(gate.d2, gate.compatible).tolist()
            return pairing
        result = jcbb(
            gate.nu,
            gate.d2,
            gate.compatible,
            _joint_covariance(P, gate.H, state_rows(gate.rows), U),
            self._R,
            self.params.gate_probability,
            self.params.budget,
            self.params.work_budget,
        )
        pairing.hypotheses, pairing.joint_d2 = result.hypotheses, result.joint_d2
        pairing.exhausted, pairing.fallback = result.exhausted, result.fallback
        pairing.columns = self._without_a_lone_wide_pair(result.pairing.tolist(), gate)
        return pairing

    def _fates(self, pairing: _Pairing) -> tuple[list[int], list[int], list[int], list[int]]:
        """Each measurement's fate and landmark (the id paired or started, -1 where
        rejected), new ids given in order; and the ids started and those matched."""
        candidate_ids: list[int] = pairing.gate_ids.tolist()
        fates: list[int] = []
        landmarks: list[int] = []
        new_ids: list[int] = []
        matched_ids: list[int] = []
        for column, is_near in zip(pairing.columns, pairing.near, strict=True):
            if column >= 0:
                landmark_id = candidate_ids[column]
                fates.append(_MATCHED)
                matched_ids.append(landmark_id)
            elif is_near:  # in a gate, but left out of the best pairing: clutter
                landmark_id = -1
                fates.append(_REJECTED)
            else:
                landmark_id = self._next_id
                self._next_id += 1
                fates.append(_NEW)
                new_ids.append(landmark_id)
            landmarks.append(landmark_id)
        return fates, landmarks, new_ids, matched_ids

    def _truth_of_scan(self) -> IntArray | None:
        """The true landmark id of each measurement of the scan just counted (-1 for
        clutter), where the run has them."""
        if self._scan_truth is None or self._scans > len(self._scan_truth):
            return None
        ids = [-1 if t is None else int(t) for t in self._scan_truth[self._scans - 1]]
        return frozen(np.array(ids, dtype=np.int64))

    def _without_a_lone_wide_pair(self, columns: list[int], gate: ScanGate) -> list[int]:
        """The pairing without its pairs with a wide gate, when it has fewer than
        ``wide_pairs`` of them.

        :param columns: each measurement's candidate (of ``gate``), -1 where none
        """
        if not any(column >= 0 for column in columns):
            return columns
        # gate_areas() of the pairs, in floats: the same operations
        S = gate.S.reshape(-1, 4).tolist()
        ranges = gate.z_pred[:, 1].tolist()
        scale = math.pi * self._gate
        limit = self.params.single_gate_area
        wide = []
        for i, column in enumerate(columns):
            if column < 0:
                continue
            s00, s01, s10, s11 = S[column]
            area = scale * math.sqrt(max(s00 * s11 - s01 * s10, 0.0)) * max(ranges[column], 0.0)
            if area > limit:
                wide.append(i)
        if not wide or len(wide) >= self.params.wide_pairs:
            return columns
        kept = list(columns)
        for i in wide:
            kept[i] = -1
        return kept

    def finish(self, slam: ScanFilter) -> list[int]:
        """The end of the run: remove the landmarks still tentative; their ids."""
        removed = self._book.drop_all()
        if removed:
            slam.remove_landmarks(removed)
        return removed


def gate_area(S: FloatArray, range_m: float, threshold: float) -> float:
    """The area (m^2) in the plane of a landmark's gate: the ellipse d^2 <= threshold of
    its (bearing, range) innovation covariance ``S``, bearings scaled by the range."""
    det = float(np.linalg.det(S))
    return math.pi * threshold * math.sqrt(max(det, 0.0)) * max(range_m, 0.0)


def gate_areas(S: FloatArray, range_m: FloatArray, threshold: float) -> FloatArray:
    """:func:`gate_area` of many gates at once (the 2x2 determinants written out).

    :param S: (k, 2, 2); :param range_m: (k,)
    """
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    areas: FloatArray = (
        math.pi * threshold * np.sqrt(np.maximum(det, 0.0)) * np.maximum(range_m, 0.0)
    )
    return areas


def state_rows(rows: IntArray) -> IntArray:
    """The state indices of the pose and of the landmarks at ``rows`` (of the map)."""
    rows = np.asarray(rows, dtype=np.int64)
    indices = np.empty(3 + 2 * len(rows), dtype=np.int64)
    indices[:3] = (0, 1, 2)
    indices[3::2] = 3 + 2 * rows
    indices[4::2] = 4 + 2 * rows
    return indices


def _joint_covariance(
    P: FloatArray, H: FloatArray, rows: IntArray, U: FloatArray | None = None
) -> FloatArray:
    """H P H^T of the candidates stacked (2K x 2K), without R.

    :param H: (K, 2, 5) each candidate's Jacobian over the pose and its own rows
    :param rows: the state rows of the pose then of each candidate (3 + 2K)
    :param U: (r, 3+2N) pending changes of the covariance: it is P - U^T U
    """
    k = H.shape[0]
    H_stacked = np.zeros((2 * k, 3 + 2 * k))
    H_stacked[:, :3] = H[:, :, :3].reshape(2 * k, 3)
    # each candidate's own 2x2 block on the diagonal of the landmarks' columns, at once
    blocks = H_stacked[:, 3:].reshape(k, 2, k, 2)  # a view: (row pair, row, column pair, column)
    at = np.arange(k)
    blocks[at, :, at, :] = H[:, :, 3:]
    # P[np.ix_(rows, rows)] in two gathers, the rows first: P may be a view of the
    # filter's buffer, which take() would copy whole before gathering
    P_rows = P[rows].take(rows, 1)
    if U is not None:
        U_rows = U[:, rows]
        P_rows -= U_rows.T @ U_rows
    C = H_stacked @ P_rows @ H_stacked.T
    return np.asarray(0.5 * (C + C.T), dtype=np.float64)
