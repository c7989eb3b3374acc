"""The EKF-SLAM filter: predict, update and landmark initialisation on a growing state.

State x = [x, y, theta, l1x, l1y, ...] (3+2N) and covariance P live in buffers with
spare capacity, so that adding a landmark does not copy P every time. Predict touches
only the robot rows and columns (O(N)); an update uses the 5 non-zero columns of the
sparse measurement Jacobian and a rank-2 change of P (O(N^2) per landmark).

Two regimes decide how the code is written. With a few landmarks, numpy's per-call
overhead is the cost: predict (at any size) and, below KERNEL_MAX_DIM, the sequential
update run in a small compiled kernel (``_kernel.c``, the same algebra in C loops over
the same buffers); where it was not built (no C compiler at install) the small algebra
is done in Python floats and each landmark costs a dozen numpy calls. With thousands, the passes
over P are the cost: the rank-2 changes of the landmarks of one observation line are
kept as a low-rank factor U (P_current = P - U^T U) and applied to P in one blocked
pass, which never builds an n x n temporary and keeps P exactly symmetric.

U outlives the observation line: it is kept across predicts, new landmarks and removals
(each a linear change of P, which carries over to U exactly: see :meth:`EkfSlam._fold`)
and folded into P only once it is full, or when a reader asks for the whole P (:attr:`P`,
:attr:`buffers`, state parts with the full covariance, the joint or compiled update). The
readers of a few entries correct what they read in O(rank n): the update's rows of P,
the state parts' pose block and marginals, and the association's gating
(:meth:`EkfSlam.deferred_covariance`). A scan of Victoria Park sees a handful of
landmarks: one pass over P every few scans, not one per scan.
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
from ekfviz.core.records import Observations, frozen
from ekfviz.core.types import BoolArray, FloatArray, IntArray
from ekfviz.models.angles import wrap_angle, wrap_angles
from ekfviz.models.classic import landmark_from_measurement, landmark_init_jacobians

try:
    from ekfviz.filters import _kernel
except ImportError:  # installed without a C compiler: numpy throughout
    _kernel = None  # type: ignore[assignment]

# Is the compiled kernel of small maps here (see the module's docstring)?
HAVE_KERNEL = _kernel is not None
# Below this state dimension the sequential update runs in the compiled kernel: it does
# one pass over P per landmark, which from here on the deferred numpy update beats.
KERNEL_MAX_DIM = 128  # chosen with make bench-like timings on a 2-core machine
# From this state dimension on, the sequential update defers its rank-2 changes to one
# pass over P per DEFER_LANDMARKS landmarks (below it, one numpy call per change is
# cheaper than the bookkeeping). Both chosen with `make bench` on a 2-core machine.
DEFER_MIN_DIM = 64
DEFER_LANDMARKS = 32
# rows of the pending factor U: P -= U^T U is folded once DEFER_LANDMARKS observations
# (2 rows each) are pending, however many lines (scans) they span
DEFER_ROWS = 2 * DEFER_LANDMARKS
GRAM_STRIP_ROWS = 48  # rows of P per block of the blocked P -= U^T U (see _subtract_gram)
# A landmark predicted closer than this (metres) to the robot has no usable measurement
# Jacobian (it divides by the range): its observation is skipped with a warning.
MIN_PREDICTED_RANGE = 1e-6

_TWO_PI = 2.0 * math.pi
# z_pred (2), innovation (2), S (4) and NIS of a landmark seen for the first time
_NAN_ROW: tuple[float, ...] = (math.nan,) * 9


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


class EkfSlam:
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
        self._R = p.R
        # Q and R are diagonal: their entries as floats for the scalar algebra
        self._q = (p.sigma_x**2, p.sigma_y**2, p.sigma_alpha**2)
        self._r = (p.sigma_bearing**2, p.sigma_range**2)
        self._n = 3  # current state dimension, 3 + 2N
        if capacity:
            room_for(3 + 2 * capacity)
        self._x = np.zeros(3 + 2 * capacity)
        self._P = np.zeros((3 + 2 * capacity, 3 + 2 * capacity))
        self._x[:3] = p.init_pose
        self._x[2] = wrap_angle(self._x[2])
        self._P[:3, :3] = np.diag(np.square(p.init_pose_sigma))
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

    def deferred_covariance(self) -> tuple[FloatArray, FloatArray | None]:
        """The covariance as stored and its pending factor: (P_s, U) with the current
        covariance P_s - U^T U, read-only views (3+2N, 3+2N) and (r, 3+2N), U None where
        nothing is pending. For a reader of a few entries of P (the association's gating
        and joint covariance), which corrects them in O(r n) instead of folding U into P
        (a pass over all of P). Valid until the filter next changes."""
        n = self._n
        P = self._P[:n, :n]
        P.flags.writeable = False
        if not self._rank:
            return P, None
        assert self._U is not None  # made with the first pending change
        U = self._U[: self._rank, :n]
        U.flags.writeable = False
        return P, U

    def _flush(self) -> None:
        """Fold the pending changes into P: P -= U^T U (one pass over P)."""
        rank = self._rank
        if rank:
            assert self._U is not None
            self._rank = 0
            self._subtract_gram(self._U[:rank, : self._n])

    def _pending_pose_gram(self) -> FloatArray:
        """U[:, :3]^T U[:, :3] of the pending factor (its rows in use), exactly
        symmetric: what the pose block of P lacks."""
        assert self._U is not None
        U_p = self._U[: self._rank, :3]
        gram: FloatArray = U_p.T.dot(U_p)
        # the lower triangle, the upper's floats (by hand: triu_indices costs 10 times more)
        gram[1, 0], gram[2, 0], gram[2, 1] = gram[0, 1], gram[0, 2], gram[1, 2]
        return gram

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

    def pose_rows(self) -> FloatArray:
        """The pose's rows of the current P (3, 3+2N): a new array, the pending changes
        taken off (O(rank n)), without folding them into P."""
        n = self._n
        rows: FloatArray = self._P[:3, :n].copy()
        if self._rank:
            assert self._U is not None
            U = self._U[: self._rank, :n]
            rows -= U[:, :3].T.dot(U)
            rows[:, :3] = self._P[:3, :3] - self._pending_pose_gram()  # exactly symmetric
        return rows

    # -- predict -----------------------------------------------------------------------

    def predict(self, d: float, alpha: float, dt: float | None = None) -> None:
        """Drive ``d`` along the heading, then turn ``alpha``; O(N).

        P' = F P F^T + F_r^T W Q W^T F_r changes only the robot rows and columns:
        P_rr' = G P_rr G^T + W Q W^T and P_rm' = G P_rm. G is the identity but for
        G[0, 2] = -d sin(theta) and G[1, 2] = d cos(theta), and Q is diagonal, so the
        3x3 block is written out in floats (symmetric by construction). With the
        time-scaled motion noise, Q = diag(sigma^2) * dt, none for a control that reads no
        motion (see :class:`MotionNoise`).

        :param dt: the time in seconds the control spans; needed by the time-scaled model
        :raises FilterError: a non-finite state, or a time-scaled Q without ``dt``
        """
        n = self._n
        x, P = self._x, self._P
        q = self._q
        if self.params.motion_noise is not MotionNoise.PER_STEP:
            scale = noise_scale(self.params.motion_noise, dt, moving=d != 0.0 or alpha != 0.0)
            q = (q[0] * scale, q[1] * scale, q[2] * scale)
        if self._compiled:  # the same algebra in C (O(n) either way)
            if self._rank:
                theta = float(x[2])
                self._predict_pending(-d * math.sin(theta), d * math.cos(theta))
            if not _kernel.predict(x, P, n, d, alpha, *q):
                raise FilterError("the state became non-finite in predict")
            return
        px, py, theta = x[:3].tolist()
        c, s = math.cos(theta), math.sin(theta)
        x[:3] = (px + d * c, py + d * s, wrap_angle(theta + alpha))
        a, b = -d * s, d * c  # G[0, 2], G[1, 2]
        if self._rank:
            self._predict_pending(a, b)
        (p00, p01, p02), (_, p11, p12), (_, _, p22) = P[:3, :3].tolist()
        if n > 3:
            # rows 0, 1 of G P (its 3x3 block is overwritten below), and their mirror
            P_rm = np.array(((1.0, 0.0, a), (0.0, 1.0, b))).dot(P[:3, :n])
            P[:2, :n] = P_rm
            P[:n, :2] = P_rm.T
        qx, qy, qa = q
        r02 = p02 + a * p22
        r12 = p12 + b * p22
        m00 = p00 + a * p02 + a * r02 + c * c * qx + s * s * qy
        m01 = p01 + a * p12 + b * r02 + c * s * (qx - qy)
        m11 = p11 + b * p12 + b * r12 + s * s * qx + c * c * qy
        m22 = p22 + qa
        P[:3, :3] = ((m00, m01, r02), (m01, m11, r12), (r02, r12, m22))
        if not math.isfinite(m00 + m11 + m22 + px + py + d + alpha):
            raise FilterError("the state became non-finite in predict")

    def _predict_pending(self, a: float, b: float) -> None:
        """Carry the pending changes over a predict P' = F P F^T + Q, F = diag(G, I) with G
        the identity but for G[0, 2] = a and G[1, 2] = b: the stored P goes through the
        predict as the current one does, and F (P - U^T U) F^T + Q = (F P F^T + Q) -
        (U F^T)^T (U F^T), so U's pose columns become U[:, :3] G^T, O(rank)."""
        assert self._U is not None
        U = self._U[: self._rank]
        U[:, 0] += a * U[:, 2]
        U[:, 1] += b * U[:, 2]

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
            values = values.reshape(m, 9)
        frozen(values)  # its views below are read-only too
        flags_none = _NO_FLAGS.get(m)  # where nothing was skipped, shared
        return Observations(
            ids=ids_arr,
            z=frozen(z),
            z_pred=values[:, 0:2],
            innovation=values[:, 2:4],
            S=values[:, 4:8].reshape(m, 2, 2),
            nis=values[:, 8],
            initialised=frozen(np.array(new, dtype=bool)) if any_new else _no_flags(m),
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
            values, skipped = _nan_table(m), _no_flags(m)
        elif compiled:
            slot = self._slot
            slots = np.array([slot.get(i, -1) for i in ids_list], dtype=np.int64)  # new: -1
            if not any_new:
                self._known_line = (ids_list, ids_arr, slots)
            values, skipped = self._update_compiled(ids_list, z, slots)
        else:
            known = [k for k, is_new in enumerate(new) if not is_new] if any_new else range(m)
            table: list[tuple[float, ...]] = [_NAN_ROW] * m
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

    def _update_compiled(
        self, ids: list[int], z: FloatArray, slots: IntArray
    ) -> tuple[FloatArray, BoolArray]:
        """:meth:`_update_sequential` in the compiled kernel; its table and skipped flags.

        :param slots: (m,) each landmark's row in the state, -1 for a new one
        """
        if self._rank:  # the kernel reads and writes P itself (a map shrunk below
            self._flush()  # KERNEL_MAX_DIM by removals: else nothing is pending here)
        m = len(ids)
        table = _nan_table(m)
        status = self._status  # the kernel writes each of the line's first m
        if status.shape[0] < m:
            status = self._status = np.zeros(m, dtype=np.int8)
        r00, r11 = self._r
        code, k, n_skipped = _kernel.update_sequential(
            self._x, self._P, self._n, slots, z, table, status, r00, r11, MIN_PREDICTED_RANGE
        )
        if code == _S_NOT_FINITE:
            raise FilterError(f"the covariance became non-finite (S of landmark {ids[k]})")
        if code == _STATE_NOT_FINITE:
            raise FilterError("the state became non-finite in update")
        if n_skipped:  # the warnings, in file order
            status = status[:m]
            for k, why in enumerate(status.tolist()):
                if why == _ZERO_RANGE:
                    self._warnings.append(_skip_warning(ids[k], _zero_range(table[k, 1])))
                    table[k] = np.nan
                elif why == _NOT_DEFINITE:
                    s00, s01, _, s11 = table[k, 4:8].tolist()
                    self._warnings.append(_skip_warning(ids[k], _not_definite(s00, s01, s11)))
        return table, status >= _ZERO_RANGE if n_skipped else _no_flags(m)

    def _update_sequential(
        self,
        ids: list[int],
        z: list[list[float]],
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """EKF updates with the known landmarks one after another, in file order.

        For landmark i, H has 5 non-zero columns c = (0, 1, 2, j, j+1), so H P (= (P H^T)^T,
        P symmetric) needs only the rows c of P. With S = L L^T (Cholesky, in floats),
        A = L^-1 H P (2 x n) and w = L^-1 nu: x += A^T w and P -= A^T A (= K S K^T).
        S^-1 is never formed, and numpy computes A^T A as a symmetric rank-k update, so P
        stays exactly symmetric. Large states defer the P -= A^T A (see the module).
        """
        n = self._n
        x = self._x[:n]
        # take() gathers from the contiguous buffer: on a view it would copy all of P first
        P_buffer = self._P
        spare = P_buffer.shape[0] > n
        r00, r11 = self._r
        U, rank = self._pending()  # P_current = P - U[:rank, :n]^T U[:rank, :n]
        for k in known:
            landmark_id = ids[k]
            j = self._slot[landmark_id]
            rows = self._rows.get(j)
            if rows is None:
                rows = self._rows[j] = np.array((0, 1, 2, j, j + 1))
            px, py, theta, lx, ly = x.take(rows).tolist()
            dx, dy = lx - px, ly - py
            q = dx * dx + dy * dy
            rng = math.sqrt(q)
            if not rng > MIN_PREDICTED_RANGE:
                self._skip(k, landmark_id, skipped, _zero_range(rng))
                continue
            bearing = math.remainder(math.atan2(dy, dx) - theta, _TWO_PI)  # wrap_angle, inlined
            if bearing == -math.pi:
                bearing = math.pi
            e, f, g, h = dy / q, dx / q, dx / rng, dy / rng
            H = np.array(((e, -f, -1.0, -e, f), (-g, -h, 0.0, g, h)))  # its 5 columns
            # ndarray methods (take, dot) cost about half of indexing and @ at small n
            P_c = P_buffer.take(rows, 0)  # the rows c of P (5 x capacity)
            HP = H.dot(P_c[:, :n] if spare else P_c)
            if rank:
                U_r = U[:rank]  # contiguous rows of the buffer: take() copies no more
                HP -= H.dot(U_r.take(rows, 1).T).dot(U_r[:, :n])
            # S = H P_cc H^T + R from the 5 columns of H P, in floats: H is (e, -f, -1, -e, f)
            # over (-g, -h, 0, g, h)
            (a0, a1, a2, a3, a4), (b0, b1, _, b3, b4) = HP.take(rows, 1).tolist()
            s00 = e * (a0 - a3) - f * (a1 - a4) - a2 + r00
            s01 = g * (a3 - a0) + h * (a4 - a1)
            s11 = g * (b3 - b0) + h * (b4 - b1) + r11
            z_bearing, z_range = z[k]
            nu0 = math.remainder(z_bearing - bearing, _TWO_PI)  # no jump of 2 pi near +-pi
            nu1 = z_range - rng
            whitened = _whitened(HP, s00, s01, s11, nu0, nu1)
            if whitened is None:  # also NaN; an infinite S ends as NaN in x
                if not math.isfinite(s00 + s01 + s11):
                    raise FilterError(
                        f"the covariance became non-finite (S of landmark {landmark_id})"
                    )
                table[k] = (bearing, rng, nu0, nu1, s00, s01, s01, s11, math.nan)
                self._skip(k, landmark_id, skipped, _not_definite(s00, s01, s11))
                continue
            B, w0, w1 = whitened
            if not math.isfinite(w0 + w1):
                raise FilterError("the state became non-finite in update")
            np.add(x, B[2], out=x)
            rank = self._fold(B[:2], U, rank)
            table[k] = (bearing, rng, nu0, nu1, s00, s01, s01, s11, w0 * w0 + w1 * w1)
        self._rank = rank  # left pending: see the module
        x[2] = wrap_angle(float(x[2]))  # once per line: the bearings above are wrapped

    def _update_joint(
        self,
        ids: list[int],
        z: FloatArray,
        known: Sequence[int],
        table: list[tuple[float, ...]],
        skipped: list[bool],
    ) -> None:
        """EKF update with all known landmarks of a line at once (stacked H, one solve).

        H (2m x n) has its non-zero columns in (0, 1, 2) and the landmarks' own pairs;
        H P gathers those rows of P. With S = L L^T, A = L^-1 H P (2m x n) and
        w = L^-1 nu: x += A^T w, P -= A^T A (one blocked pass, exactly symmetric).
        """
        n = self._n
        x = self._x[:n]
        px, py, theta = x[:3].tolist()
        usable = []
        for k in known:
            j = self._slot[ids[k]]
            rng_k = math.hypot(float(x[j]) - px, float(x[j + 1]) - py)
            if rng_k > MIN_PREDICTED_RANGE:
                usable.append(k)
            else:
                self._skip(k, ids[k], skipped, _zero_range(rng_k))
        known = usable
        m = len(known)
        if not m:
            return
        if self._rank:  # H P below reads P's rows, and the gram below is P's
            self._flush()
        slots = np.array([self._slot[ids[k]] for k in known], dtype=np.int64)
        rows = np.concatenate(([0, 1, 2], np.column_stack([slots, slots + 1]).ravel()))
        dx, dy = x[slots] - px, x[slots + 1] - py
        q = dx * dx + dy * dy
        rng = np.sqrt(q)
        z_pred = np.column_stack([wrap_angles(np.arctan2(dy, dx) - theta), rng])
        nu = z[known] - z_pred
        nu[:, 0] = wrap_angles(nu[:, 0])
        e, f, g, h = dy / q, dx / q, dx / rng, dy / rng
        H = np.zeros((2 * m, 3 + 2 * m))
        H[0::2, :3] = np.column_stack([e, -f, -np.ones(m)])
        H[1::2, 0] = -g
        H[1::2, 1] = -h
        landmark_cols = 3 + 2 * np.arange(m)
        H[2 * np.arange(m), landmark_cols] = -e
        H[2 * np.arange(m), landmark_cols + 1] = f
        H[2 * np.arange(m) + 1, landmark_cols] = g
        H[2 * np.arange(m) + 1, landmark_cols + 1] = h
        HP = H @ self._P[rows, :n]
        S = HP[:, rows] @ H.T
        S[np.diag_indices(2 * m)] += np.tile(self._r, m)
        S = 0.5 * (S + S.T)
        if not np.isfinite(S).all():
            raise FilterError("the covariance became non-finite (joint S)")
        blocks = S.reshape(m, 2, m, 2)[np.arange(m), :, np.arange(m), :]  # (m, 2, 2)
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            # not one landmark's fault alone: the whole line is skipped
            for row, k in enumerate(known):
                (s00, s01), (_, s11) = blocks[row].tolist()
                table[k] = (*z_pred[row].tolist(), *nu[row].tolist(), s00, s01, s01, s11,
                            math.nan)  # fmt: skip
                skipped[k] = True
            self._warnings.append(
                f"the joint innovation covariance S of landmarks {[ids[k] for k in known]}"
                " is not positive definite: their observations were skipped"
            )
            return
        A = np.asarray(np.linalg.solve(L, HP), dtype=np.float64)
        w = np.linalg.solve(L, nu.ravel())
        if not np.isfinite(w).all():
            raise FilterError("the state became non-finite in update")
        x += w @ A
        x[2] = wrap_angle(float(x[2]))
        self._subtract_gram(A)
        nis = np.einsum("ki,ki->k", nu, np.linalg.solve(blocks, nu[:, :, None])[:, :, 0])
        for row, k in enumerate(known):
            table[k] = (*z_pred[row].tolist(), *nu[row].tolist(), *blocks[row].ravel().tolist(),
                        float(nis[row]))  # fmt: skip

    def _skip(self, k: int, landmark_id: int, skipped: list[bool], why: str) -> None:
        skipped[k] = True
        self._warnings.append(_skip_warning(landmark_id, why))

    def _pending(self) -> tuple[FloatArray, int]:
        """The pending factor U (the buffer: DEFER_ROWS x capacity) and its rows in use,
        for a sequential update; no rows at all (and 0) where the state is too small to
        defer (below DEFER_MIN_DIM), with what was pending folded in."""
        if self._n < DEFER_MIN_DIM:
            if self._rank:  # a map shrunk by removals
                self._flush()
            return _NO_ROWS, 0
        if self._U is None:
            self._U = np.zeros((DEFER_ROWS, self._P.shape[0]))
        return self._U, self._rank

    def _fold(self, A: FloatArray, U: FloatArray, rank: int) -> int:
        """P -= A^T A for an observation's A = L^-1 H P (2 x n): with a factor ``U`` (see
        :meth:`_pending`), kept as its rows ``rank``, ``rank + 1`` and applied in one pass
        over P once U is full (see :meth:`_subtract_gram`); without rows, applied now (A
        C-contiguous: np.dot takes A^T A as a symmetric rank-k update). Returns the rows
        of U in use after it.

        Pending rows stay valid across the other changes of P, each linear: a predict
        (:meth:`_predict_pending`), a new landmark (its columns of U, J_pose U[:, :3]^T:
        see :meth:`_add_landmark`) and a removal (the same columns of U dropped).
        """
        n = A.shape[1]
        if not U.shape[0]:
            self._P[:n, :n] -= A.T.dot(A)
            return rank
        U[rank : rank + 2, :n] = A
        rank += 2
        if rank == U.shape[0]:
            self._subtract_gram(U[:, :n])
            rank = 0
        self._rank = rank  # at once: an error later in the line leaves P as it is
        return rank

    def _subtract_gram(self, U: FloatArray) -> None:
        """P -= U^T U for U (r x n), in place, in one pass over P, exactly symmetric.

        A plain ``P -= U.T @ U`` builds an n x n temporary and reads P twice. Here P goes by
        strips of rows: the diagonal block gets numpy's symmetric rank-k product, the
        block right of it a plain product, and the block below it is then copied as the
        transpose of the one to its right, so that P[i, j] and P[j, i] are the same float
        whatever the BLAS does.
        """
        n = U.shape[1]
        P = self._P
        if n <= GRAM_STRIP_ROWS:
            P[:n, :n] -= U.T @ U
            return
        for i0 in range(0, n, GRAM_STRIP_ROWS):
            i1 = min(i0 + GRAM_STRIP_ROWS, n)
            U_i = U[:, i0:i1]
            P[i0:i1, i0:i1] -= U_i.T @ U_i
            if i1 < n:
                right = P[i0:i1, i1:n]
                right -= U_i.T @ U[:, i1:]
                P[i1:n, i0:i1] = right.T

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
        P_ll = l_D_pose @ P_pp @ l_D_pose.T + l_D_z @ self._R @ l_D_z.T
        if correlated:
            P_lx = l_D_pose @ P[:3, :n]
            P[n : n + 2, :n] = P_lx
            P[:n, n : n + 2] = P_lx.T
        else:
            P[n : n + 2, :n] = 0.0
            P[:n, n : n + 2] = 0.0
        P[n : n + 2, n : n + 2] = 0.5 * (P_ll + P_ll.T)
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


def _whitened(
    HP: FloatArray, s00: float, s01: float, s11: float, nu0: float, nu1: float
) -> tuple[FloatArray, float, float] | None:
    """An observation's update through the Cholesky factor L of its 2x2 S, in floats:
    B = [A; w^T A] (3 x n) with A = L^-1 H P and w = L^-1 nu (so the change of x is
    B[2] and that of P is -A^T A), and w; None where S is not positive definite ("not >"
    also catches NaN).

    :param HP: (2, n) H P, the rows c of P through H
    """
    l00 = math.sqrt(s00) if s00 > 0.0 else 0.0
    l10 = s01 / l00 if l00 > 0.0 else 0.0
    d11 = s11 - l10 * l10
    if not (l00 > 0.0 and d11 > 0.0):
        return None
    l11 = math.sqrt(d11)
    w0 = nu0 / l00
    w1 = (nu1 - l10 * w0) / l11
    i00, i11 = 1.0 / l00, 1.0 / l11
    i10 = -l10 * i00 * i11
    B: FloatArray = np.array(((i00, 0.0), (i10, i11), (w0 * i00 + w1 * i10, w1 * i11))).dot(HP)
    return B, w0, w1


# the pending factor of a state too small to defer (see EkfSlam._pending): no rows
_NO_ROWS: FloatArray = np.zeros((0, 0))
_NO_ROWS.flags.writeable = False

_NAN_TABLES: dict[int, FloatArray] = {}


def _nan_table(m: int) -> FloatArray:
    """(m, 9) NaN, a new array (a copy of a kept one: np.full costs more at small m)."""
    table = _NAN_TABLES.get(m)
    if table is None:
        table = _NAN_TABLES.setdefault(m, np.full((m, 9), np.nan))
    copy: FloatArray = table.copy()
    return copy


_NO_FLAGS: dict[int, BoolArray] = {}


def _no_flags(m: int) -> BoolArray:
    """(m,) False, read-only: shared by every observation line of m landmarks that
    initialised (or skipped) none, instead of a new array per line."""
    flags = _NO_FLAGS.get(m)
    if flags is None:
        flags = _NO_FLAGS.setdefault(m, frozen(np.zeros(m, dtype=bool)))
    return flags


# what the compiled update says of an observation, and of the whole line (see _kernel.c)
_ZERO_RANGE, _NOT_DEFINITE = 2, 3
_S_NOT_FINITE, _STATE_NOT_FINITE = 1, 2


def _skip_warning(landmark_id: int, why: str) -> str:
    return f"landmark {landmark_id}: {why}: observation skipped"


def _zero_range(rng: float) -> str:
    return (
        f"predicted {rng:.3g} m from the robot, where the measurement Jacobian"
        " (which divides by the range) is undefined"
    )


def _not_definite(s00: float, s01: float, s11: float) -> str:
    return (
        f"innovation covariance S = [[{s00:.3g}, {s01:.3g}], [{s01:.3g}, {s11:.3g}]]"
        " is not positive definite"
    )
