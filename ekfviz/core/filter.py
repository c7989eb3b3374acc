"""The EKF-SLAM filter: predict, update and landmark initialisation on a growing state.

State x = [x, y, theta, l1x, l1y, ...] (3+2N) and covariance P live in buffers with
spare capacity, so that adding a landmark does not copy P every time. Predict touches
only the robot rows and columns (O(N)); an update uses the 5 non-zero columns of the
sparse measurement Jacobian and a rank-2 change of P (O(N^2) per landmark).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from ekfviz.core.models import (
    landmark_from_measurement,
    landmark_init_jacobians,
    measure,
    measurement_jacobians,
    motion,
    motion_jacobians,
    wrap_angle,
)
from ekfviz.core.records import EventKind, EventRecord, Observations, frozen, snapshot
from ekfviz.core.types import FloatArray, IntArray


class LandmarkInit(str, enum.Enum):
    """How a new landmark's covariance is initialised."""

    CORRELATED = "correlated"  # with cross-covariances to the pose and the map (exact)
    INDEPENDENT = "independent"  # cross-covariances set to zero (the simplification)


class UpdateMode(str, enum.Enum):
    """How the landmarks of one observation line are folded in."""

    SEQUENTIAL = "sequential"  # one after another in file order, re-linearising between
    JOINT = "joint"  # all at once, linearised at the predicted state


@dataclass(frozen=True, slots=True)
class FilterParams:
    """Noise levels, prior and options of the filter; defaults are the classic ones."""

    sigma_x: float = 0.25
    sigma_y: float = 0.1
    sigma_alpha: float = 0.1
    sigma_bearing: float = 0.01
    sigma_range: float = 0.08
    init_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    init_pose_sigma: tuple[float, float, float] = (0.02, 0.02, 0.1)
    landmark_init: LandmarkInit = LandmarkInit.CORRELATED
    update: UpdateMode = UpdateMode.SEQUENTIAL

    @property
    def Q(self) -> FloatArray:
        """Motion noise covariance (3x3) in the robot frame."""
        return np.diag(np.square([self.sigma_x, self.sigma_y, self.sigma_alpha]))

    @property
    def R(self) -> FloatArray:
        """Measurement noise covariance (2x2) of (bearing, range)."""
        return np.diag(np.square([self.sigma_bearing, self.sigma_range]))

    def as_dict(self) -> dict[str, object]:
        """Every value as plain JSON-friendly Python objects."""
        values = asdict(self)
        values["init_pose"] = list(self.init_pose)
        values["init_pose_sigma"] = list(self.init_pose_sigma)
        values["landmark_init"] = self.landmark_init.value
        values["update"] = self.update.value
        return values


class FilterError(ValueError):
    """The filter cannot go on: a non-positive-definite S, a non-finite state, ..."""


class EkfSlam:
    """EKF-SLAM on a state that grows by landmark id."""

    def __init__(self, params: FilterParams | None = None, *, capacity: int = 0) -> None:
        self.params = params if params is not None else FilterParams()
        self._Q = self.params.Q
        self._R = self.params.R
        self._n = 3  # current state dimension, 3 + 2N
        self._x = np.zeros(3 + 2 * capacity)
        self._P = np.zeros((3 + 2 * capacity, 3 + 2 * capacity))
        self._x[:3] = self.params.init_pose
        self._x[2] = wrap_angle(self._x[2])
        self._P[:3, :3] = np.diag(np.square(self.params.init_pose_sigma))
        self._ids: list[int] = []
        self._slot: dict[int, int] = {}  # landmark id -> index of its x in the state

    # -- views -------------------------------------------------------------------------

    @property
    def x(self) -> FloatArray:
        """Current state mean (3+2N,), a read-only view."""
        view = self._x[: self._n]
        view.flags.writeable = False
        return view

    @property
    def P(self) -> FloatArray:
        """Current state covariance (3+2N, 3+2N), a read-only view."""
        view = self._P[: self._n, : self._n]
        view.flags.writeable = False
        return view

    @property
    def landmark_ids(self) -> list[int]:
        """Landmark ids in state order (order of first sighting)."""
        return list(self._ids)

    def knows(self, landmark_id: int) -> bool:
        return landmark_id in self._slot

    def record(
        self,
        *,
        event: int,
        step: int,
        kind: EventKind,
        line: int = 0,
        control: FloatArray | None = None,
        observations: Observations | None = None,
        full_cov: bool = False,
        time: float | None = None,
    ) -> EventRecord:
        """Snapshot the current state as an immutable record."""
        return snapshot(
            self._x[: self._n],
            self._P[: self._n, : self._n],
            event=event,
            step=step,
            kind=kind,
            line=line,
            landmark_ids=np.array(self._ids, dtype=np.int64),
            control=control,
            observations=observations,
            full_cov=full_cov,
            time=time,
        )

    # -- predict -----------------------------------------------------------------------

    def predict(self, d: float, alpha: float) -> None:
        """Drive ``d`` along the heading, then turn ``alpha``; O(N).

        P' = F P F^T + F_r^T W Q W^T F_r changes only the robot rows and columns:
        P_rr' = G P_rr G^T + W Q W^T and P_rm' = G P_rm.
        """
        n = self._n
        x, P = self._x, self._P
        G, W = motion_jacobians(x[:3], d)
        x[:3] = motion(x[:3], d, alpha)
        P_rr = G @ P[:3, :3] @ G.T + W @ self._Q @ W.T
        P[:3, :3] = 0.5 * (P_rr + P_rr.T)
        if n > 3:
            P_rm = G @ P[:3, 3:n]
            P[:3, 3:n] = P_rm
            P[3:n, :3] = P_rm.T
        self._check_finite("predict")

    # -- update ------------------------------------------------------------------------

    def observe(self, ids: Sequence[int] | IntArray, z: FloatArray) -> Observations:
        """Fold one observation line into the state.

        Known landmarks correct the state (sequentially in file order, or jointly, as the
        parameters say); landmarks seen for the first time are then initialised from the
        corrected pose, in file order.

        :param ids: (m,) landmark ids
        :param z: (m, 2) (bearing, range) per landmark
        :return: what was done with each observation, in file order
        """
        ids_arr = np.asarray(ids, dtype=np.int64)
        z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
        m = ids_arr.shape[0]
        if len(set(ids_arr.tolist())) != m:
            raise FilterError("an observation names the same landmark twice")
        z_pred = np.full((m, 2), np.nan)
        innovation = np.full((m, 2), np.nan)
        S = np.full((m, 2, 2), np.nan)
        nis = np.full(m, np.nan)
        new = np.array([not self.knows(int(i)) for i in ids_arr], dtype=bool)
        known = np.flatnonzero(~new)
        if known.size:
            if self.params.update is UpdateMode.JOINT:
                self._update_joint(ids_arr, z, known, z_pred, innovation, S, nis)
            else:
                for k in known:
                    z_pred[k], innovation[k], S[k], nis[k] = self._update_one(int(ids_arr[k]), z[k])
        new_at = np.flatnonzero(new)
        self._reserve(new_at.size)
        for k in new_at:
            self._add_landmark(int(ids_arr[k]), z[k])
        self._check_finite("update")
        return Observations(
            ids=frozen(ids_arr.copy()),
            z=frozen(z.copy()),
            z_pred=frozen(z_pred),
            innovation=frozen(innovation),
            S=frozen(S),
            nis=frozen(nis),
            initialised=frozen(new),
        )

    def _update_one(
        self, landmark_id: int, z: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """EKF update with one landmark through the 5 non-zero columns of H; O(N^2)."""
        n = self._n
        x, P = self._x[:n], self._P[:n, :n]
        j = self._slot[landmark_id]
        cols = [0, 1, 2, j, j + 1]
        z_pred = measure(x[:3], x[j : j + 2])
        self._require_range(landmark_id, z_pred)
        z_D_pose, z_D_landmark = measurement_jacobians(x[:3], x[j : j + 2])
        H = np.hstack([z_D_pose, z_D_landmark])  # the 5 non-zero columns, 2x5
        PHt = P[:, cols] @ H.T  # n x 2: a gather of 5 columns instead of P @ H_full^T
        S = H @ PHt[cols] + self._R
        nu = z - z_pred
        nu[0] = wrap_angle(nu[0])  # bearings near +-pi must not jump by 2 pi
        nis = self._correct(PHt, S, nu)
        return z_pred, nu, S, nis

    def _update_joint(
        self,
        ids: IntArray,
        z: FloatArray,
        known: IntArray,
        z_pred: FloatArray,
        innovation: FloatArray,
        S_out: FloatArray,
        nis_out: FloatArray,
    ) -> None:
        """EKF update with all known landmarks of a line at once (stacked H, one solve)."""
        n = self._n
        x, P = self._x[:n], self._P[:n, :n]
        m = known.size
        cols = [0, 1, 2]
        H = np.zeros((2 * m, 3 + 2 * m))
        nu = np.empty(2 * m)
        for row, k in enumerate(known):
            j = self._slot[int(ids[k])]
            cols += [j, j + 1]
            z_pred[k] = measure(x[:3], x[j : j + 2])
            self._require_range(int(ids[k]), z_pred[k])
            z_D_pose, z_D_landmark = measurement_jacobians(x[:3], x[j : j + 2])
            H[2 * row : 2 * row + 2, :3] = z_D_pose
            H[2 * row : 2 * row + 2, 3 + 2 * row : 5 + 2 * row] = z_D_landmark
            innovation[k] = z[k] - z_pred[k]
            innovation[k, 0] = wrap_angle(innovation[k, 0])
            nu[2 * row : 2 * row + 2] = innovation[k]
        PHt = P[:, cols] @ H.T  # n x 2m
        S = H @ PHt[cols] + np.kron(np.eye(m), self._R)
        for row, k in enumerate(known):
            S_k = S[2 * row : 2 * row + 2, 2 * row : 2 * row + 2]
            S_out[k] = S_k
            nis_out[k] = float(innovation[k] @ np.linalg.solve(S_k, innovation[k]))
        self._correct(PHt, S, nu)

    def _correct(self, PHt: FloatArray, S: FloatArray, nu: FloatArray) -> float:
        """Apply x += K nu and P -= K S K^T given P H^T (n x k), S (k x k) and nu; O(N^2).

        With S = L L^T (Cholesky) and A = L^-1 (P H^T)^T, K nu = A^T L^-1 nu and
        K S K^T = A^T A. S^-1 is never formed, and A^T A is exactly symmetric (numpy
        computes a product with its own transpose as a symmetric rank-k update), so P
        stays exactly symmetric. The 2x2 case of a single landmark is written out in
        scalars: at small N the filter's time goes to numpy call overhead, not flops.

        :return: the NIS nu^T S^-1 nu
        """
        n = self._n
        if S.shape == (2, 2):
            A, w = _whiten_2x2(PHt, S, nu)
        else:
            S = 0.5 * (S + S.T)
            try:
                L = np.linalg.cholesky(S)
            except np.linalg.LinAlgError as error:
                raise FilterError("innovation covariance S is not positive definite") from error
            A = np.linalg.solve(L, PHt.T)
            w = np.linalg.solve(L, nu)
        self._x[:n] += w @ A
        self._x[2] = wrap_angle(self._x[2])
        self._P[:n, :n] -= A.T @ A
        return float(w @ w)

    # -- landmark initialisation -------------------------------------------------------

    def _reserve(self, extra_landmarks: int) -> None:
        """Grow the buffers so that ``extra_landmarks`` more fit without a copy each."""
        needed = self._n + 2 * extra_landmarks
        if needed <= self._x.shape[0]:
            return
        size = max(needed, 3 + (3 * (self._x.shape[0] - 3)) // 2)  # grow by half
        x = np.zeros(size)
        P = np.zeros((size, size))
        x[: self._n] = self._x[: self._n]
        P[: self._n, : self._n] = self._P[: self._n, : self._n]
        self._x, self._P = x, P

    def _add_landmark(self, landmark_id: int, z: FloatArray) -> None:
        """Append a landmark seen for the first time at ``z`` = (bearing, range).

        P_ll = J_p P_pp J_p^T + J_z R J_z^T and, unless the simplified variant is asked
        for, P_l,all = J_p P_p,all: the cross-covariances with the pose and with every
        landmark already mapped.
        """
        self._reserve(1)
        n = self._n
        x, P = self._x, self._P
        l_D_pose, l_D_z = landmark_init_jacobians(x[:3], z)
        x[n : n + 2] = landmark_from_measurement(x[:3], z)
        P_ll = l_D_pose @ P[:3, :3] @ l_D_pose.T + l_D_z @ self._R @ l_D_z.T
        if self.params.landmark_init is LandmarkInit.CORRELATED:
            P_lx = l_D_pose @ P[:3, :n]
        else:
            P_lx = np.zeros((2, n))
        P[n : n + 2, :n] = P_lx
        P[:n, n : n + 2] = P_lx.T
        P[n : n + 2, n : n + 2] = 0.5 * (P_ll + P_ll.T)
        self._slot[landmark_id] = n
        self._ids.append(landmark_id)
        self._n = n + 2

    @staticmethod
    def _require_range(landmark_id: int, z_pred: FloatArray) -> None:
        # The measurement Jacobian divides by the range: undefined at the landmark itself.
        if not z_pred[1] > 1e-9:
            raise FilterError(f"landmark {landmark_id} is predicted at zero range")

    def _check_finite(self, where: str) -> None:
        n = self._n
        if not (np.isfinite(self._x[:n]).all() and math.isfinite(float(self._P[:3, :3].sum()))):
            raise FilterError(f"the state became non-finite in {where}")


def _whiten_2x2(PHt: FloatArray, S: FloatArray, nu: FloatArray) -> tuple[FloatArray, FloatArray]:
    """L^-1 (P H^T)^T (2 x n) and L^-1 nu (2,) for S = L L^T, with the Cholesky in scalars."""
    (s00, s01), (s10, s11) = S.tolist()
    s01 = 0.5 * (s01 + s10)
    l00 = math.sqrt(s00) if s00 > 0.0 else math.nan
    l10 = s01 / l00
    d = s11 - l10 * l10
    if not (s00 > 0.0 and d > 0.0):  # also catches NaN
        raise FilterError("innovation covariance S is not positive definite")
    l11 = math.sqrt(d)
    A = PHt.T.copy()
    A[0] /= l00
    A[1] -= l10 * A[0]
    A[1] /= l11
    nu0, nu1 = nu.tolist()
    w0 = nu0 / l00
    return A, np.array([w0, (nu1 - l10 * w0) / l11])
