"""The EKF-SLAM filter: predict, update and landmark initialisation on a growing state.

State x = [x, y, theta, l1x, l1y, ...] (3+2N) and covariance P live in buffers with
spare capacity, so that adding a landmark does not copy P every time. Predict touches
only the robot rows and columns (O(N)); an update uses the 5 non-zero columns of the
sparse measurement Jacobian and a rank-2 change of P (O(N^2) per landmark).

Every operation is a named one of :mod:`ekfviz.models` (motion, G, W, Q and the
covariance prediction; h(x), H, the innovation, S and the correction; the landmark's
position, J_p, J_z, P_ll and P_lx): the math is written once, there.

Two regimes decide how the code runs. With a few landmarks, numpy's per-call overhead
is the cost: predict (at any size) and, below KERNEL_MAX_DIM, the sequential update run
in a small compiled kernel (``_kernel.c``, the same algebra in C loops over the same
buffers), whose one Python reference is this filter without it (``compiled=False``,
the tests compare the two); where it was not built (no C compiler at install) numpy runs
throughout. With thousands, the passes over P are the cost: the rank-2 changes of the
landmarks of one observation line are kept as a low-rank factor U (P_current = P - U^T
U) and applied to P in one blocked pass, which never builds an n x n temporary and keeps
P exactly symmetric (:mod:`ekfviz.filters.ekf_pending`).

U outlives the observation line: it is kept across predicts, new landmarks and removals
(each a linear change of P, which carries over to U exactly: see
:meth:`~ekfviz.filters.ekf_pending.PendingCovariance._fold`) and folded into P only once it
is full, or when a reader asks for the whole P (:attr:`P`, :attr:`buffers`, state parts with
the full covariance, the joint or compiled update). The readers of a few entries correct
what they read in O(rank n): the update's rows of P, the state parts' pose block and
marginals, and the association's gating (:meth:`EkfSlam.deferred_covariance`). A scan
of Victoria Park sees a handful of landmarks: one pass over P every few scans, not one
per scan. The updates of a line are in :mod:`ekfviz.filters.ekf_update`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from ekfviz.core.batch import MapParts, StateParts
from ekfviz.core.errors import FilterError
from ekfviz.core.memory import available_memory
from ekfviz.core.params import FilterParams, LandmarkInit, MotionNoise, UpdateMode, noise_scale
from ekfviz.core.records import TABLE_COLUMNS, Observations, frozen
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.filters.ekf_pending import DEFER_MIN_DIM, DEFER_ROWS
from ekfviz.filters.ekf_update import NAN_ROW, LineUpdates, nan_table, no_flags
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import (
    landmark_from_measurement,
    landmark_init_jacobians,
    motion,
    motion_jacobian,
    noise_jacobian,
)
from ekfviz.models.kalman import (
    measurement_noise,
    motion_noise,
    new_landmark_covariance,
    new_landmark_cross_covariance,
    predicted_cross_covariance,
    predicted_pose_covariance,
    prior_covariance,
)

try:
    from ekfviz.filters import _kernel
except ImportError:  # installed without a C compiler: numpy throughout
    _kernel = None  # type: ignore[assignment]

__all__ = ["DEFER_MIN_DIM", "DEFER_ROWS", "HAVE_KERNEL", "KERNEL_MAX_DIM", "EkfSlam", "room_for"]

# Is the compiled kernel of small maps here (see the module's docstring)?
HAVE_KERNEL = _kernel is not None
# Below this state dimension the sequential update runs in the compiled kernel: it does
# one pass over P per landmark, which from here on the deferred numpy update beats.
KERNEL_MAX_DIM = 128  # chosen with make bench-like timings on a 2-core machine


# A run holds the covariance about five times over at its peak (the copy checked beside
# the filter, the eigen-decomposition of the whole-P checks, the records' copies):
# 672 MB at N = 2000, whose P is 128 MB. A map whose P takes more than this share of the
# memory available is refused before P is made.
P_MEMORY_SHARE = 1 / 6


def room_for(size: int) -> None:
    """Refuse a state of ``size`` (3 + 2N) whose covariance would not fit in memory, in
    one line, before it is made: numpy's zeros are granted lazily, and filling them
    would swap the machine to a standstill (a first line of 20,000 landmarks, 320 KB of
    log, asks for a 12.8 GB P).

    :raises FilterError: saying how large P would be and what memory there is
    """
    need = 8 * size * size
    if need < 1 << 28:  # under 256 MB: no need to ask
        return
    available = available_memory()
    if available is None or need <= available * P_MEMORY_SHARE:
        return
    raise FilterError(
        f"{(size - 3) // 2} landmarks make the covariance {size} x {size} ({need / 1e9:.1f} GB);"
        f" a run needs about {round(1 / P_MEMORY_SHARE)} times that, more than the"
        f" {available / 1e9:.1f} GB of memory available"
    )


class EkfSlam(LineUpdates):
    """EKF-SLAM on a state that grows by landmark id."""

    def __init__(
        self, params: FilterParams | None = None, *, capacity: int = 0, compiled: bool = True
    ) -> None:
        """
        :param capacity: landmarks to make room for at once
        :param compiled: use the compiled kernel of small maps, where it was built
            (``False``: the numpy code throughout, as where it was not)
        """
        self.params = params if params is not None else FilterParams()
        p = self.params
        self._compiled = compiled and HAVE_KERNEL
        self._Q = motion_noise(p.sigma_x, p.sigma_y, p.sigma_alpha)
        self._q_diagonal = tuple(np.diag(self._Q).tolist())  # as floats, for the kernel
        self._R = measurement_noise(p.sigma_bearing, p.sigma_range)
        # R's diagonal as floats, for the compiled kernel
        self._r = (float(self._R[0, 0]), float(self._R[1, 1]))
        self._n = 3  # current state dimension, 3 + 2N
        if capacity:
            room_for(3 + 2 * capacity)
        self._x = np.zeros(3 + 2 * capacity)
        self._P = np.zeros((3 + 2 * capacity, 3 + 2 * capacity))
        self._x[:3] = p.init_pose
        self._x[2] = wrap_angle(self._x[2])
        self._P[:3, :3] = prior_covariance(p.init_pose_sigma)
        self._ids: list[int] = []
        self._warnings: list[str] = []  # of the last observe
        self._slot: dict[int, int] = {}  # landmark id -> index of its x in the state
        self._ids_array: IntArray | None = None  # self._ids as a frozen array, built lazily
        # the last observation line whose landmarks were all known: its ids as a list, as
        # the frozen array its records keep, and their slots (see observe); None once the
        # map changes
        self._known_line: tuple[list[int], IntArray, IntArray] | None = None
        self._rows: dict[int, IntArray] = {}  # slot j -> [0, 1, 2, j, j+1]
        # for records (and the gating), until P's map changes: the landmarks' marginals and
        # means (a predict changes neither)
        self._landmark_covs: FloatArray | None = None
        self._landmarks_xy: FloatArray | None = None
        # the view of the landmarks' marginals in P (see _marginals_view), for the buffer
        # P and dimension it was made for
        self._marginals: tuple[FloatArray, int, FloatArray] | None = None
        # the views of the pose and its block of P in the buffers they were made for, and
        # the map as batches keep it (see pose_block, map_parts)
        self._pose_views: tuple[FloatArray, FloatArray, tuple[FloatArray, FloatArray]] | None
        self._pose_views = None
        self._map_parts: MapParts | None = None
        self._status = np.zeros(0, dtype=np.int8)  # the kernel's per-observation status
        # the pending rank-2 changes of P: the current covariance is
        # P[:n, :n] - U[:rank, :n]^T U[:rank, :n] (see the module); U (DEFER_ROWS x the
        # buffers' capacity) is made by the first deferred update
        self._U: FloatArray | None = None
        self._rank = 0

    @classmethod
    def from_state(
        cls,
        params: FilterParams,
        x: FloatArray,
        P: FloatArray,
        landmark_ids: Sequence[int] | IntArray,
        *,
        compiled: bool = True,
    ) -> EkfSlam:
        """A filter that starts from a given state instead of the prior (``ekfviz check``
        starts the reference from the checked filter's own state before every event).

        :param x: (3+2N,) mean, ``P`` (3+2N, 3+2N) covariance, ``landmark_ids`` (N,)
        """
        ids = [int(i) for i in landmark_ids]
        n = 3 + 2 * len(ids)
        if x.shape != (n,) or P.shape != (n, n) or len(set(ids)) != len(ids):
            raise ValueError(f"expected x ({n},), P ({n}, {n}) and {len(ids)} distinct ids")
        ekf = cls(params, capacity=len(ids), compiled=compiled)
        ekf._x[:n] = x
        ekf._x[2] = wrap_angle(float(x[2]))
        ekf._P[:n, :n] = P
        ekf._n = n
        ekf._ids = ids
        ekf._slot = {landmark_id: 3 + 2 * k for k, landmark_id in enumerate(ids)}
        return ekf

    # -- views -------------------------------------------------------------------------

    @property
    def x(self) -> FloatArray:
        """Current state mean (3+2N,), a read-only view."""
        view = self._x[: self._n]
        view.flags.writeable = False
        return view

    @property
    def P(self) -> FloatArray:
        """Current state covariance (3+2N, 3+2N), a read-only view (the pending changes
        folded in first: see the module), valid until the filter next changes: a later
        update may leave its changes pending, so read P again rather than keep the view."""
        if self._rank:
            self._flush()
        view = self._P[: self._n, : self._n]
        view.flags.writeable = False
        return view

    @property
    def buffers(self) -> tuple[FloatArray, FloatArray]:
        """The state's own buffers x and P, the state in their leading 3+2N rows (and
        columns): for a reader that copies from them at once, without a view made per
        read; not to be written. The pending changes of P are folded in first."""
        if self._rank:
            self._flush()
        return self._x, self._P

    @property
    def dim(self) -> int:
        """Current state dimension 3 + 2N."""
        return self._n

    @property
    def landmark_ids(self) -> list[int]:
        """Landmark ids in state order (order of first sighting)."""
        return list(self._ids)

    def landmark_ids_array(self) -> IntArray:
        """:attr:`landmark_ids` as a read-only int64 array, kept until the map changes
        (the records' own): for a reader once per scan, without a list copied and
        converted each time."""
        if self._ids_array is None:
            self._ids_array = frozen(np.array(self._ids, dtype=np.int64))
        return self._ids_array

    def knows(self, landmark_id: int) -> bool:
        return landmark_id in self._slot

    @property
    def warnings(self) -> tuple[str, ...]:
        """Why observations of the last :meth:`observe` were skipped, one sentence each."""
        return tuple(self._warnings)

    def state_parts(self, full_cov: bool = False) -> StateParts:
        """The current state as a batch takes it (:class:`~ekfviz.core.batch.StateParts`):
        :meth:`pose_block`, :meth:`map_parts` and, where ``full_cov``, a copy of P."""
        if full_cov and self._rank:
            self._flush()
        pose, pose_cov = self.pose_block()
        n = self._n
        whole = self._P[:n, :n].copy() if full_cov else None
        return StateParts(pose, pose_cov, *self.map_parts(), whole)

    def pose_block(self) -> tuple[FloatArray, FloatArray]:
        """The pose (3,) and its covariance (3, 3) as a batch takes them: views of the
        buffers, valid until the filter next changes (a batch copies them at once), the
        pending changes of P taken off."""
        x, P = self._x, self._P
        views = self._pose_views
        if views is None or views[0] is not x or views[1] is not P:  # (a buffer grew)
            views = self._pose_views = (x, P, (x[:3], P[:3, :3]))
        if self._rank:
            pose, pose_cov = views[2]
            return pose, pose_cov - self._pending_pose_gram()
        return views[2]

    def map_parts(self) -> MapParts:
        """The map as a batch keeps it: landmark ids, means (N, 2) and marginals (N, 2, 2),
        read-only, in one tuple kept while the map does not change (a predict moves the
        pose alone), so that a batch stores it once."""
        kept = self._map_parts
        if (  # the arrays kept while the map is unchanged: still the same ones
            kept is not None
            and kept[0] is self._ids_array
            and kept[1] is self._landmarks_xy
            and kept[2] is self._landmark_covs
        ):
            return kept
        ids, xy = self.landmark_ids_array(), self._landmark_means()
        kept = self._map_parts = (ids, xy, self.landmark_marginals())
        return kept

    def _landmark_means(self) -> FloatArray:
        """The landmarks' means (N, 2) as batches keep them: read-only, one copy kept
        until the map changes (a predict moves the pose alone)."""
        if self._landmarks_xy is None:
            n = self._n
            self._landmarks_xy = frozen(self._x[3:n].copy()).reshape((n - 3) // 2, 2)
        return self._landmarks_xy

    def _marginals_view(self) -> FloatArray:
        """The view a record copies its marginals from, made again where the buffer or
        the dimension changed."""
        kept = self._marginals
        if kept is None or kept[0] is not self._P or kept[1] != self._n:
            kept = self._marginals = (self._P, self._n, _marginals_view(self._P, self._n))
        return kept[2]

    def landmark_marginals(self) -> FloatArray:
        """The landmarks' 2x2 marginal covariances (N, 2, 2) of the current P, read-only:
        one copy of P's diagonal blocks (a strided view), the pending changes taken off
        (O(rank n)), kept until the map changes (a predict leaves them as they are) for
        the records and the association's gating alike."""
        kept = self._landmark_covs
        if kept is not None:
            return kept
        covs: FloatArray = self._marginals_view().copy()
        rank = self._rank
        if rank:
            assert self._U is not None
            # each landmark's 2x2 block of U^T U: the squares of its columns summed, and
            # the products of its two columns, one array for both off-diagonal entries
            # (they stay the same float: P stays exactly symmetric)
            U_l = self._U[:rank, 3 : self._n]
            squares = np.einsum("ri,ri->i", U_l, U_l)
            products = np.einsum("ri,ri->i", U_l[:, 0::2], U_l[:, 1::2])
            covs[:, 0, 0] -= squares[0::2]
            covs[:, 1, 1] -= squares[1::2]
            covs[:, 0, 1] -= products
            covs[:, 1, 0] -= products
        self._landmark_covs = frozen(covs)
        return covs

    # -- predict -----------------------------------------------------------------------

    def predict(self, d: float, alpha: float, dt: float | None = None) -> None:
        """Drive ``d`` along the heading, then turn ``alpha``; O(N).

        P' = F P F^T + F_r^T W Q W^T F_r changes only the robot rows and columns:
        P_rr' = G P_rr G^T + W Q W^T and P_rm' = G P_rm (the named operations of
        :mod:`ekfviz.models`). With the time-scaled motion noise, Q = diag(sigma^2) * dt,
        none for a control that reads no motion (see :class:`MotionNoise`).

        :param dt: the time in seconds the control spans; needed by the time-scaled model
        :raises FilterError: a non-finite state, or a time-scaled Q without ``dt``
        """
        n = self._n
        x, P = self._x, self._P
        Q = self._Q
        if self.params.motion_noise is not MotionNoise.PER_STEP:
            Q = Q * noise_scale(self.params.motion_noise, dt, moving=d != 0.0 or alpha != 0.0)
        if self._compiled:  # the same algebra in C (O(n) either way)
            if self._rank:
                theta = float(x[2])
                self._predict_pending(-d * math.sin(theta), d * math.cos(theta))
            qx, qy, qa = self._q_diagonal if Q is self._Q else np.diag(Q).tolist()
            if not _kernel.predict(x, P, n, d, alpha, qx, qy, qa):
                raise FilterError("the state became non-finite in predict")
            return
        pose = x[:3].copy()
        G, W = motion_jacobian(pose, d), noise_jacobian(pose)
        x[:3] = motion(pose, d, alpha)
        if self._rank:
            self._predict_pending(float(G[0, 2]), float(G[1, 2]))
        if n > 3:
            P_rm = predicted_cross_covariance(G, P[:3, 3:n])
            P[:3, 3:n] = P_rm
            P[3:n, :3] = P_rm.T
        P[:3, :3] = predicted_pose_covariance(P[:3, :3], G, W, Q)
        if not math.isfinite(float(P[0, 0] + P[1, 1] + P[2, 2] + x[0] + x[1]) + d + alpha):
            raise FilterError("the state became non-finite in predict")

    # -- update ------------------------------------------------------------------------

    def observe(self, ids: Sequence[int] | IntArray, z: FloatArray) -> Observations:
        """Fold one observation line into the state.

        Known landmarks correct the state (sequentially in file order, or jointly, as the
        parameters say); landmarks seen for the first time are then initialised from the
        corrected pose, in file order.

        :param ids: (m,) landmark ids
        :param z: (m, 2) (bearing, range) per landmark
        :return: what was done with each observation, in file order; why any was
            skipped is in :attr:`warnings`
        :raises FilterError: a landmark named twice, or the state turned non-finite
        """
        self._landmark_covs = self._landmarks_xy = None
        self._warnings = []
        z = np.array(z, dtype=np.float64)  # copies: the record keeps it
        if z.ndim != 2 or z.shape[1] != 2:
            z = z.reshape(-1, 2)
        # A log observes the same landmarks line after line (a classic log all of them,
        # in one shared ids array): the line's ids, their copy and their slots are kept
        # from the last line while the map has not changed, and compared as a list. It is
        # kept only where the kernel updates it (compiled, sequential, below
        # KERNEL_MAX_DIM), and dropped when the map grows.
        line = self._known_line
        ids_list: list[int] = (
            ids.tolist() if type(ids) is np.ndarray and ids.dtype == np.int64 else []
        )
        skipped: list[bool] | BoolArray
        if line is not None and ids_list == line[0] and z.shape[0] == len(ids_list):
            ids_arr, m = line[1], len(ids_list)
            values, skipped = self._update_compiled(ids_list, z, line[2])
            new, any_new = [], False
        else:
            compiled = (
                self._compiled
                and self._n < KERNEL_MAX_DIM
                and self.params.update is UpdateMode.SEQUENTIAL
            )
            ids_arr = np.array(ids, dtype=np.int64)  # copies: the record keeps them
            ids_list = ids_arr.tolist()
            m = len(ids_list)
            if len(set(ids_list)) != m:
                raise FilterError("an observation names the same landmark twice")
            slot = self._slot
            new = [i not in slot for i in ids_list]
            any_new = True in new
            values, skipped = self._observe_line(ids_list, ids_arr, z, new, any_new, compiled)
        if any_new:
            self._reserve(sum(new))
            for k in range(m):
                if new[k]:
                    self._add_landmark(ids_list[k], z[k].tolist())
        if values.ndim != 2:  # the numpy code's table comes flat
            values = values.reshape(m, TABLE_COLUMNS)
        flags_none = no_flags(m)  # where nothing was skipped, shared
        return Observations(
            ids=ids_arr,
            z=frozen(z),
            table=frozen(values),
            initialised=frozen(np.array(new, dtype=bool)) if any_new else flags_none,
            skipped=skipped if skipped is flags_none else frozen(np.asarray(skipped, dtype=bool)),
        )

    def _observe_line(
        self,
        ids_list: list[int],
        ids_arr: IntArray,
        z: FloatArray,
        new: list[bool],
        any_new: bool,
        compiled: bool,
    ) -> tuple[FloatArray, list[bool] | BoolArray]:
        """The update of a line not met just before: per observation z_pred (2),
        innovation (2), S (2x2, row-major) and NIS, and the skipped flags. Freezes
        ``ids_arr`` (the record keeps it) and, where every landmark is known and the
        kernel updates, keeps the line for the next (see :meth:`observe`)."""
        m = len(ids_list)
        frozen(ids_arr)
        values: FloatArray
        skipped: list[bool] | BoolArray
        if any_new and all(new):
            values, skipped = nan_table(m), no_flags(m)
        elif compiled:
            slot = self._slot
            slots = np.array([slot.get(i, -1) for i in ids_list], dtype=np.int64)  # new: -1
            if not any_new:
                self._known_line = (ids_list, ids_arr, slots)
            values, skipped = self._update_compiled(ids_list, z, slots)
        else:
            known = [k for k, is_new in enumerate(new) if not is_new] if any_new else range(m)
            table: list[tuple[float, ...]] = [NAN_ROW] * m
            skipped = [False] * m
            if self.params.update is UpdateMode.JOINT:
                self._update_joint(ids_list, z, known, table, skipped)
            else:
                self._update_sequential(ids_list, z.tolist(), known, table, skipped)
            # one O(n) look at x (the buffer's: zero beyond the state), so that a NaN cannot
            # reach the next event: a non-finite S or H P reaches x through its update
            if not math.isfinite(float(self._x.sum())):
                raise FilterError("the state became non-finite in update")
            values = np.fromiter(itertools.chain.from_iterable(table), np.float64, 9 * m)
        return values, skipped

    def update(self, ids: Sequence[int] | IntArray, z: FloatArray) -> None:
        """:meth:`observe` as the :class:`~ekfviz.filters.protocol.SlamFilter` protocol has it."""
        self.observe(ids, z)

    # -- landmark removal ----------------------------------------------------------------

    def remove_landmarks(self, ids: Sequence[int]) -> None:
        """Drop landmarks from the state (a tentative landmark that was not confirmed).

        Marginalising a Gaussian is dropping its rows and columns: the rest of x and P is
        unchanged, and P stays exactly symmetric and positive semi-definite (a principal
        submatrix of one). The kept rows are moved up in place, O(n^2) at worst (the
        pending changes' columns likewise: see :meth:`_fold`).

        :raises FilterError: an id not in the state
        """
        doomed = set(int(i) for i in ids)
        if not doomed:
            return
        unknown = doomed - self._slot.keys()
        if unknown:
            raise FilterError(f"cannot remove landmarks {sorted(unknown)}: not in the state")
        n = self._n
        kept_ids = [i for i in self._ids if i not in doomed]
        keep = np.concatenate(
            ([0, 1, 2], *[(self._slot[i], self._slot[i] + 1) for i in kept_ids])
        ).astype(np.int64)
        m = keep.shape[0]
        if self._rank:  # marginalising drops the same columns of U
            assert self._U is not None
            U = self._U[: self._rank]
            U[:, :m] = U[:, keep]
        self._x[:m] = self._x[keep]
        self._x[m:n] = 0.0
        # the kept rows come in runs of consecutive ones (between the removed landmarks),
        # each moved up as one block of rows, then of columns: block copies instead of a
        # gather entry by entry (np.ix_, three times as long at n = 800). In order: a run
        # moves up over rows whose own run has already moved
        breaks = (np.flatnonzero(np.diff(keep) != 1) + 1).tolist()
        runs = [  # (from, to, length) of each run that moves
            (int(keep[start]), start, end - start)
            for start, end in zip([0, *breaks], [*breaks, m], strict=True)
            if keep[start] != start
        ]
        P = self._P
        for source, start, length in runs:
            P[start : start + length, :n] = P[source : source + length, :n]
        for source, start, length in runs:
            P[:m, start : start + length] = P[:m, source : source + length]
        P[m:n, :n] = 0.0
        P[:n, m:n] = 0.0
        self._n = m
        self._ids = kept_ids
        self._slot = {i: 3 + 2 * k for k, i in enumerate(kept_ids)}
        self._ids_array = None
        self._known_line = None
        self._rows = {}
        self._landmark_covs = self._landmarks_xy = None

    # -- landmark initialisation -------------------------------------------------------

    def _reserve(self, extra_landmarks: int) -> None:
        """Grow the buffers so that ``extra_landmarks`` more fit without a copy each.

        :raises FilterError: the covariance would not fit in memory (see :func:`room_for`)
        """
        needed = self._n + 2 * extra_landmarks
        if needed <= self._x.shape[0]:
            return
        room_for(needed)
        size = max(needed, 3 + (3 * (self._x.shape[0] - 3)) // 2)  # grow by half
        x = np.zeros(size)
        P = np.zeros((size, size))
        x[: self._n] = self._x[: self._n]
        P[: self._n, : self._n] = self._P[: self._n, : self._n]
        self._x, self._P = x, P
        if self._U is not None:
            U = np.zeros((DEFER_ROWS, size))
            U[: self._rank, : self._n] = self._U[: self._rank, : self._n]
            self._U = U

    def _initial_landmark(
        self, pose_xytheta: FloatArray, z: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Where a landmark first seen at ``z`` lies, and the Jacobians of that with respect
        to the pose and to ``z`` (the inverse measurement model; a filter with another
        sensor model overrides this alone)."""
        l_D_pose, l_D_z = landmark_init_jacobians(pose_xytheta, z)
        return landmark_from_measurement(pose_xytheta, z), l_D_pose, l_D_z

    def _add_landmark(self, landmark_id: int, z: Sequence[float]) -> None:
        """Append a landmark seen for the first time at ``z`` = (bearing, range).

        P_ll = J_p P_pp J_p^T + J_z R J_z^T and, unless the simplified variant is asked
        for, P_l,all = J_p P_p,all: the cross-covariances with the pose and with every
        landmark already mapped.
        """
        if not math.isfinite(z[0] + z[1]):
            raise FilterError("the state became non-finite in update")
        self._reserve(1)
        n = self._n
        x, P = self._x, self._P
        z_arr = np.asarray(z, dtype=np.float64)
        x[n : n + 2], l_D_pose, l_D_z = self._initial_landmark(x[:3], z_arr)
        correlated = self.params.landmark_init is LandmarkInit.CORRELATED
        P_pp = P[:3, :3]
        rank = self._rank
        if rank:
            # P_current = P - U^T U. Correlated, the new rows of P are J_p P[:3] as of the
            # current P, so the stored P gets J_p P_s[:3] and U the columns U[:, :3] J_p^T
            # (then P_s - U^T U is J_p P_current[:3] there): an exact carry-over. Independent,
            # the new rows are zero in both and U's columns too; P_ll reads the current
            # pose block.
            assert self._U is not None
            U = self._U[:rank]
            if correlated:
                U[:, n : n + 2] = U[:, :3] @ l_D_pose.T
            else:
                U[:, n : n + 2] = 0.0
                P_pp = P_pp - self._pending_pose_gram()
        if correlated:
            P_lx = new_landmark_cross_covariance(l_D_pose, P[:3, :n])
            P[n : n + 2, :n] = P_lx
            P[:n, n : n + 2] = P_lx.T
        else:
            P[n : n + 2, :n] = 0.0
            P[:n, n : n + 2] = 0.0
        P[n : n + 2, n : n + 2] = new_landmark_covariance(l_D_pose, P_pp, l_D_z, self._R)
        if not np.isfinite(P[n : n + 2, : n + 2]).all():  # a range so large it overflows
            raise FilterError(f"the covariance of new landmark {landmark_id} is not finite")
        self._slot[landmark_id] = n
        self._ids.append(landmark_id)
        self._ids_array = None
        self._known_line = None
        self._n = n + 2


def _marginals_view(P: FloatArray, n: int) -> FloatArray:
    """The N diagonal 2x2 blocks of the landmarks in the buffer ``P`` (C order) of
    dimension ``n``: P's rows and columns 3 + 2i and 4 + 2i, one strided view, a step of
    2 rows and 2 columns per landmark."""
    row, item = P.strides
    view: FloatArray = np.lib.stride_tricks.as_strided(
        P[3:, 3:], shape=((n - 3) // 2, 2, 2), strides=(2 * row + 2 * item, row, item),
        writeable=False,
    )  # fmt: skip
    return view
