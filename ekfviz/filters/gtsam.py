"""Factor-graph smoothers from GTSAM as ekfviz filters: incremental (iSAM2) and batch.

Both build the same factor graph from the log, with the EKF's own noise (see the
reference, ``docs/ekf-slam.md``):

- a ``Pose2`` per step, ``X(k)``, and a ``Point2`` per landmark, ``L(j)`` (j: the order of
  first sighting, so that any landmark id fits a key);
- a ``PriorFactorPose2`` on ``X(0)`` with the initial pose sigmas;
- a ``BetweenFactorPose2`` per control (d, alpha), measured ``Pose2(d, 0, alpha)``: the
  EKF's noise e = (e_x, e_y, e_a) acts in the robot frame before the turn, so the
  between-pose error ``Log(measured^-1 (X_k^-1 X_k+1))`` is, to first order,
  ``J e`` with ``J = blockdiag(R(-alpha), 1)`` (:func:`between_jacobian`), and the factor's
  covariance is ``J Q J^T``;
- a ``BearingRangeFactor2D`` per observed landmark with the EKF's R; a landmark is
  initialised from its first sighting (the inverse measurement model).

GTSAM's covariances are in the tangent space of each variable: for a ``Pose2`` the
position part is in the robot's own frame. ekfviz's state is in world coordinates, so
the pose rows and columns are rotated by R(theta) (:func:`tangent_to_world`).

:class:`Isam2Slam` (``--filter isam2``) updates ``gtsam.ISAM2`` at every event and shows
the current pose and every landmark with their joint marginal covariance (pose-landmark
and landmark-landmark cross-covariances included, so that the runner's S and NIS are
the smoother's own). :class:`BatchSlam` (``--filter batch``) collects the whole graph and
solves it once in :meth:`BatchSlam.finish` with Levenberg-Marquardt and
``gtsam.Marginals``: until then it shows the graph's initial guess (see the class).

GTSAM is an optional dependency (``pip install 'ekfviz[gtsam]'``), imported with this
module, which only ``--filter isam2|batch`` loads.
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import (
    landmark_from_measurement,
    landmark_init_jacobians,
    motion,
    motion_jacobians,
)

if TYPE_CHECKING:
    import gtsam

INSTALL_HINT = "the gtsam extra (pip install -e '.[gtsam]' in a clone of ekfviz)"


PRIOR_SIGMA_FLOOR = 1e-6  # m and rad: the prior of a start known exactly


def reason(error: BaseException) -> str:
    """GTSAM's message in one line: its first sentence, up to the first blank line (its
    messages run on for paragraphs, with links)."""
    text = " ".join(str(error).strip().split("\n\n")[0].split())
    return text or type(error).__name__


class GtsamMissing(ModuleNotFoundError):
    """GTSAM is not installed; the message says how to install it."""


def import_gtsam() -> ModuleType:
    """GTSAM, imported on first use.

    :raises GtsamMissing: it is not installed (one line, with the install command)
    """
    try:
        import gtsam
    except ImportError as error:
        raise GtsamMissing(
            f"the GTSAM filters (isam2, batch) need the gtsam package: {INSTALL_HINT}",
            name="gtsam",
        ) from error
    return gtsam


# Imported with this module, which ``--filter isam2|batch`` alone loads: without GTSAM the
# registry (ekfviz.filters) turns this into one line with the install command.
import_gtsam()


def between_jacobian(alpha: float) -> FloatArray:
    """d(between-pose error)/d(e_x, e_y, e_a) of a control with turn ``alpha``, at e = 0.

    The relative pose of a control is (d + e_x, e_y, alpha + e_a) in the frame of the pose
    it starts from; ``Pose2(d, 0, alpha)^-1`` composed with it is ``(R(-alpha) (e_x, e_y),
    e_a)``, whose log map agrees with it to first order.

    :return: (3, 3) J, so that the between factor's covariance is J Q J^T
    """
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def tangent_to_world(theta: float) -> FloatArray:
    """d(x, y, theta in world coordinates)/d(Pose2 tangent vector) at a pose of heading theta.

    ``Pose2`` retracts as ``pose * Exp(xi)``: its position part moves along the robot's
    own axes. :return: (3, 3) blockdiag(R(theta), 1)
    """
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class _FactorGraph:
    """The factor graph of a log as it is read, and the numbering of its variables.

    New factors and initial values gather in ``new_factors`` / ``new_values`` until the
    subclass takes them (:meth:`take_new`).
    """

    def __init__(self, params: FilterParams | None) -> None:
        self.gtsam: Any = import_gtsam()
        gt = self.gtsam
        self.params = params if params is not None else FilterParams()
        p = self.params
        self._Q = p.Q
        self._R = p.R
        self._measurement_noise = gt.noiseModel.Diagonal.Sigmas(
            np.array([p.sigma_bearing, p.sigma_range])
        )
        self.pose_index = 0  # k of the current pose X(k)
        self._slot: dict[int, int] = {}  # landmark id -> j of its variable L(j)
        self.ids: list[int] = []
        self.new_factors = gt.NonlinearFactorGraph()
        self.new_values = gt.Values()
        start = np.array([p.init_pose[0], p.init_pose[1], wrap_angle(p.init_pose[2])])
        # the prior's world-frame covariance, in the tangent space of the start pose
        to_world = tangent_to_world(float(start[2]))
        # a start known exactly (a sigma of 0) is a prior of PRIOR_SIGMA_FLOOR: GTSAM's
        # factors whiten by an invertible covariance
        sigmas = np.maximum(np.asarray(p.init_pose_sigma, dtype=np.float64), PRIOR_SIGMA_FLOOR)
        prior_cov = to_world.T @ np.diag(np.square(sigmas)) @ to_world
        self.new_factors.add(
            gt.PriorFactorPose2(self.pose_key(0), self._pose(start), self._noise(prior_cov))
        )
        self.new_values.insert(self.pose_key(0), self._pose(start))

    # -- keys and conversions ------------------------------------------------------------

    def pose_key(self, k: int) -> int:
        return int(self.gtsam.symbol("x", k))

    def landmark_key(self, j: int) -> int:
        return int(self.gtsam.symbol("l", j))

    def state_keys(self) -> list[int]:
        """The current pose, then every landmark in state order."""
        return [self.pose_key(self.pose_index)] + [
            self.landmark_key(j) for j in range(len(self.ids))
        ]

    def _pose(self, pose_xytheta: FloatArray) -> gtsam.Pose2:
        x, y, theta = (float(v) for v in pose_xytheta)
        pose: gtsam.Pose2 = self.gtsam.Pose2(x, y, theta)
        return pose

    def _noise(self, cov: FloatArray) -> gtsam.noiseModel.Base:
        # a singular covariance (a sigma of 0) cannot whiten: GTSAM says so, ekfviz too
        try:
            model: gtsam.noiseModel.Base = self.gtsam.noiseModel.Gaussian.Covariance(cov)
        except RuntimeError as error:
            raise FilterError(f"a noise covariance GTSAM cannot use: {reason(error)}") from error
        return model

    # -- the graph -----------------------------------------------------------------------

    def add_control(self, d: float, alpha: float, guess_xytheta: FloatArray) -> None:
        """A new pose after the control, initialised at ``guess_xytheta``."""
        if not (math.isfinite(d) and math.isfinite(alpha)):
            raise FilterError("a control that is not finite")
        J = between_jacobian(alpha)
        k = self.pose_index
        self.new_factors.add(
            self.gtsam.BetweenFactorPose2(
                self.pose_key(k),
                self.pose_key(k + 1),
                self.gtsam.Pose2(d, 0.0, alpha),
                self._noise(J @ self._Q @ J.T),
            )
        )
        self.pose_index = k + 1
        self.new_values.insert(self.pose_key(k + 1), self._pose(guess_xytheta))

    def add_observation(
        self, ids: IntArray, z: FloatArray, pose_xytheta: FloatArray
    ) -> list[tuple[int, FloatArray]]:
        """A bearing-range factor per landmark; new landmarks are initialised from ``z`` seen
        at ``pose_xytheta``.

        :return: (row in ``ids``, initial position) of each new landmark
        :raises FilterError: a landmark named twice, a non-finite measurement
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        z = np.asarray(z, dtype=np.float64).reshape(len(ids), 2)
        if len(set(ids.tolist())) != len(ids):
            raise FilterError("an observation names the same landmark twice")
        if not np.isfinite(z).all():
            raise FilterError("an observation that is not finite")
        gt = self.gtsam
        pose_key = self.pose_key(self.pose_index)
        new: list[tuple[int, FloatArray]] = []
        for row, (landmark_id, (bearing, rng)) in enumerate(
            zip(ids.tolist(), z.tolist(), strict=True)
        ):
            j = self._slot.get(landmark_id)
            if j is None:
                j = self._slot[landmark_id] = len(self.ids)
                self.ids.append(landmark_id)
                landmark_xy = landmark_from_measurement(pose_xytheta, np.array([bearing, rng]))
                self.new_values.insert(self.landmark_key(j), landmark_xy)
                new.append((row, landmark_xy))
            self.new_factors.add(
                gt.BearingRangeFactor2D(
                    pose_key, self.landmark_key(j), gt.Rot2(bearing), rng, self._measurement_noise
                )
            )
        return new

    def take_new(self) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """The factors and values added since the last call."""
        taken = self.new_factors, self.new_values
        self.new_factors = self.gtsam.NonlinearFactorGraph()
        self.new_values = self.gtsam.Values()
        return taken

    def state(self, values: gtsam.Values) -> FloatArray:
        """x = [current pose, landmarks] (3+2N,) from ``values``, theta in (-pi, pi]."""
        pose = values.atPose2(self.pose_key(self.pose_index))
        x = np.empty(3 + 2 * len(self.ids))
        x[:3] = pose.x(), pose.y(), wrap_angle(pose.theta())
        for j in range(len(self.ids)):
            x[3 + 2 * j : 5 + 2 * j] = values.atPoint2(self.landmark_key(j))
        return x

    def world_covariance(self, tangent_cov: FloatArray, theta: float) -> FloatArray:
        """A joint covariance over [pose, landmarks] from GTSAM's tangent spaces to the world
        frame (only the pose's rows and columns turn), made exactly symmetric."""
        T = tangent_to_world(theta)
        P = np.array(tangent_cov, dtype=np.float64)
        P[:3, :] = T @ P[:3, :]
        P[:, :3] = P[:, :3] @ T.T
        symmetric: FloatArray = 0.5 * (P + P.T)
        return symmetric


class Isam2Slam:
    """Incremental smoothing and mapping (``gtsam.ISAM2``) behind ekfviz's filter protocol.

    Every predict and update adds its factors and runs one iSAM2 update (relinearising
    variables whose change exceeds ``RELINEARIZE_THRESHOLD``). ``x`` is the current pose
    and every landmark of the current estimate, ``P`` their joint marginal covariance in
    world coordinates: computed from the Bayes tree on first read after an update (an
    O(N^2) joint marginal), and after a predict carried from the one before through the
    linearised motion (exact for the linearised graph: the new pose is tied to the rest by
    its between factor alone).
    """

    RELINEARIZE_THRESHOLD = 0.01

    def __init__(self, params: FilterParams | None = None) -> None:
        self._graph = _FactorGraph(params)
        gt = self._graph.gtsam
        self._isam = self._new_isam("CHOLESKY")
        self._factorization = "CHOLESKY"
        self._factors = gt.NonlinearFactorGraph()  # all of them, for a switch to QR
        self._estimate = gt.Values()
        self._Q = self._graph.params.Q
        self._x = np.zeros(3)
        self._P: FloatArray | None = None
        self._solve()

    @property
    def x(self) -> FloatArray:
        return self._x

    @property
    def P(self) -> FloatArray:
        if self._P is None:
            keys = self._graph.gtsam.KeyVector(self._graph.state_keys())
            try:
                joint = self._isam.jointMarginalCovariance(keys).fullMatrix()
            except RuntimeError as error:
                raise FilterError(
                    f"iSAM2 could not compute the marginals: {reason(error)}"
                ) from error
            self._P = self._graph.world_covariance(joint, float(self._x[2]))
        return self._P

    @property
    def landmark_ids(self) -> list[int]:
        return list(self._graph.ids)

    def predict(self, d: float, alpha: float) -> None:
        pose = self._x[:3].copy()
        before = self._P
        self._graph.add_control(d, alpha, motion(pose, d, alpha))
        self._solve()
        if before is not None:
            # The new pose hangs on the graph by its between factor alone: its joint
            # marginal with the map is the one before, carried through the linearised
            # motion (the EKF's predict), which spares a joint marginal per predict.
            G, W = motion_jacobians(pose, d)
            P = before.copy()
            P[:3, :] = G @ P[:3, :]
            P[:, :3] = P[:, :3] @ G.T
            P[:3, :3] += W @ self._Q @ W.T
            self._P = 0.5 * (P + P.T)

    def update(self, ids: IntArray, z: FloatArray) -> None:
        self._graph.add_observation(ids, z, self._x[:3])
        self._solve()

    def _new_isam(self, factorization: str) -> Any:
        gt = self._graph.gtsam
        isam_params = gt.ISAM2Params()
        isam_params.setRelinearizeThreshold(self.RELINEARIZE_THRESHOLD)
        isam_params.relinearizeSkip = 1
        isam_params.setFactorization(factorization)
        return gt.ISAM2(isam_params)

    def _solve(self) -> None:
        factors, values = self._graph.take_new()
        self._factors.push_back(factors)
        try:
            try:
                self._isam.update(factors, values)
            except RuntimeError:
                if self._factorization == "QR":
                    raise
                # Cholesky calls a long stretch of poorly constrained poses "indeterminate"
                # where QR (and the EKF) go on: from here on QR, several times slower
                self._factorization = "QR"
                self._isam = self._new_isam("QR")
                start = self._graph.gtsam.Values(self._estimate)
                start.insert(values)
                self._isam.update(self._factors, start)
            estimate = self._isam.calculateEstimate()
        except RuntimeError as error:  # GTSAM's exceptions (an indeterminant system, ...)
            raise FilterError(f"iSAM2 failed: {reason(error)}") from error
        self._estimate = estimate
        self._x = self._graph.state(estimate)
        if not np.isfinite(self._x).all():
            raise FilterError("the iSAM2 estimate became non-finite")
        self._P = None


class BatchSlam:
    """The Levenberg-Marquardt optimum of the whole log's factor graph, with
    ``gtsam.Marginals``: the best a Gaussian estimator gets from the data.

    Events only add factors. Until :meth:`finish`, ``x`` and ``P`` are the graph's initial
    guess, where Levenberg-Marquardt starts: the dead-reckoned pose and every landmark
    where its first sighting put it, with the covariance of that guess (the EKF's predict
    and landmark initialisation without its corrections, a growing uncertainty). After
    ``finish``: the optimum's last pose and landmarks with their joint marginal covariance.
    """

    MAX_ITERATIONS = 100

    def __init__(self, params: FilterParams | None = None) -> None:
        self._graph = _FactorGraph(params)
        p = self._graph.params
        self._factors = self._graph.gtsam.NonlinearFactorGraph()
        self._initial = self._graph.gtsam.Values()
        self._x = np.array([p.init_pose[0], p.init_pose[1], wrap_angle(p.init_pose[2])])
        self._P = np.diag(np.square(np.asarray(p.init_pose_sigma, dtype=np.float64)))
        self._Q = p.Q
        self._R = p.R
        self._poses_xytheta: FloatArray | None = None
        self._finished = False
        self._take()

    @property
    def x(self) -> FloatArray:
        return self._x

    @property
    def P(self) -> FloatArray:
        return self._P

    @property
    def landmark_ids(self) -> list[int]:
        return list(self._graph.ids)

    @property
    def poses_xytheta(self) -> FloatArray | None:
        """(T+1, 3) every pose of the optimum, after :meth:`finish`; None before."""
        return self._poses_xytheta

    def predict(self, d: float, alpha: float) -> None:
        self._check_open()
        pose = self._x[:3].copy()
        moved = motion(pose, d, alpha)
        self._graph.add_control(d, alpha, moved)
        G, W = motion_jacobians(pose, d)
        P = self._P
        P[:3, :] = G @ P[:3, :]
        P[:, :3] = P[:, :3] @ G.T
        P[:3, :3] += W @ self._Q @ W.T
        self._x[:3] = moved
        self._take()

    def update(self, ids: IntArray, z: FloatArray) -> None:
        self._check_open()
        pose = self._x[:3].copy()
        new = self._graph.add_observation(ids, z, pose)
        z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
        for row, landmark_xy in new:
            # the guess's covariance: l = g(pose, z), cross-covariances through the pose
            l_D_pose, l_D_z = landmark_init_jacobians(pose, z[row])
            n = len(self._x)
            P = np.zeros((n + 2, n + 2))
            P[:n, :n] = self._P
            cross = l_D_pose @ self._P[:3, :]
            P[n:, :n] = cross
            P[:n, n:] = cross.T
            P[n:, n:] = l_D_pose @ self._P[:3, :3] @ l_D_pose.T + l_D_z @ self._R @ l_D_z.T
            self._P = P
            self._x = np.concatenate([self._x, landmark_xy])
        self._take()

    def finish(self) -> None:
        """Solve the whole graph (Levenberg-Marquardt) and show the optimum's last pose and
        landmarks with their joint marginal covariance.

        :raises FilterError: GTSAM could not solve it (an indeterminant system, ...)
        """
        self._check_open()
        self._finished = True
        gt = self._graph.gtsam
        lm_params = gt.LevenbergMarquardtParams()
        lm_params.setMaxIterations(self.MAX_ITERATIONS)
        lm_params.setRelativeErrorTol(1e-12)
        lm_params.setAbsoluteErrorTol(1e-12)
        lm_params.setLinearSolverType("MULTIFRONTAL_QR")  # as robust as iSAM2's (see there)
        try:
            result = gt.LevenbergMarquardtOptimizer(
                self._factors, self._initial, lm_params
            ).optimize()
            marginals = gt.Marginals(self._factors, result)
            keys = gt.KeyVector(self._graph.state_keys())
            joint = marginals.jointMarginalCovariance(keys).fullMatrix()
        except RuntimeError as error:
            raise FilterError(f"the batch optimisation failed: {reason(error)}") from error
        x = self._graph.state(result)
        if not np.isfinite(x).all():
            raise FilterError("the batch optimum is non-finite")
        self._x = x
        self._P = self._graph.world_covariance(joint, float(x[2]))
        poses = [result.atPose2(self._graph.pose_key(k)) for k in range(self._graph.pose_index + 1)]
        self._poses_xytheta = np.array([[p.x(), p.y(), wrap_angle(p.theta())] for p in poses])

    def _take(self) -> None:
        factors, values = self._graph.take_new()
        self._factors.push_back(factors)
        self._initial.insert(values)

    def _check_open(self) -> None:
        if self._finished:
            raise FilterError("the batch optimum is final: no events after finish()")
