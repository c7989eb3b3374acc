"""Estimate a log's noise from its ground truth (numpy only).

Measurement noise: every (bearing, range) against the true pose at its time (or step)
and the true landmark, giving per component a robust standard deviation (1.4826 times
the median absolute deviation), the bias (median) and the outliers (farther than
``OUTLIER_SIGMAS`` robust sigmas from the median).

Motion noise: the odometry against the true pose increments over short windows. From
the true pose at a window's start the controls are composed (the filter's motion
model) and compared with the true pose at its end. The residual r of a window has, to
first order, covariance Sigma = qx M_x + qy M_y + qa M_a, where M_j propagates a unit
noise of component j through the window exactly as the filter's predict does (G, W;
times dt for the time-scaled model). q = (qx, qy, qa) = sigma^2 is then fitted to the
residuals' outer products r r^T by weighted least squares (weights from the variance
of a product of Gaussians), iterated, leaving out windows whose Mahalanobis distance
exceeds the 99.9 % chi-square bound. With one control a window and an exact truth (a
simulated log without time stamps) this is the classic per-step estimate.

Systematic odometry errors (:func:`fit_odometry`): over the same windows, the true turn
against scale_alpha sum(alpha) + bias sum(d) and the true displacement against scale_d
times the odometry's, robust least squares; the motion noise is then fitted on the
corrected controls. A control that reads no motion adds no noise (the filter's model).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ekfviz.core.params import MotionNoise
from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.core.steps import log_steps
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angles
from ekfviz.models.classic import motion

MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): the MAD of a Gaussian is 0.6745 sigma
OUTLIER_SIGMAS = 4.0  # farther than this from the median, in robust sigmas: an outlier
HEAVY_TAIL_SHARE = 0.01  # beyond 3 robust sigmas: 0.27 % for a Gaussian; more: a warning
WINDOW_S = 1.0  # seconds of odometry per motion window of a timestamped log
MAX_TRACK_GAP_S = 0.25  # a window end whose truth samples are farther apart is not used
CHI2_3_999 = 16.266  # 99.9 % quantile of chi-square with 3 degrees of freedom
FIT_ROUNDS = 5
Q_LIMIT = 1e-12  # a fitted variance at or below this hit the fit's lower limit (sigma 0)


@dataclass(frozen=True, slots=True)
class ResidualStats:
    """Robust statistics of one residual component.

    :param name: what it is (``bearing``, ``range``, ``x`` ...)
    :param unit: its unit
    :param count: residuals used
    :param bias: their median
    :param sigma: robust standard deviation, 1.4826 MAD
    :param outliers: residuals farther than ``OUTLIER_SIGMAS`` sigma from the median
    :param tail_share: share beyond 3 sigma from the median (a Gaussian: 0.27 %)
    """

    name: str
    unit: str
    count: int
    bias: float
    sigma: float
    outliers: int
    tail_share: float

    @property
    def gaussian(self) -> bool:
        """Whether the tails look Gaussian (see ``HEAVY_TAIL_SHARE``)."""
        return self.tail_share <= HEAVY_TAIL_SHARE


def robust_stats(name: str, unit: str, residuals: FloatArray) -> ResidualStats:
    """Median, 1.4826 MAD, outliers and the share of heavy tails of some residuals."""
    r = np.asarray(residuals, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return ResidualStats(name, unit, 0, math.nan, math.nan, 0, math.nan)
    bias = float(np.median(r))
    deviation = np.abs(r - bias)
    sigma = MAD_TO_SIGMA * float(np.median(deviation))
    if sigma > 0:
        outliers = int(np.count_nonzero(deviation > OUTLIER_SIGMAS * sigma))
        tail = float(np.count_nonzero(deviation > 3.0 * sigma)) / r.size
    else:
        outliers, tail = int(np.count_nonzero(deviation > 0)), 0.0
    return ResidualStats(name, unit, int(r.size), bias, sigma, outliers, tail)


@dataclass(frozen=True, slots=True)
class MotionFit:
    """The motion noise fitted from windows of odometry.

    :param model: per step or per square-root second
    :param sigmas: (sigma_x, sigma_y, sigma_alpha) in m, m, rad (per step) or per sqrt(s)
    :param windows: windows used
    :param outliers: windows left out (Mahalanobis beyond the 99.9 % bound)
    :param window_s: the window length in seconds (timestamped), None per step
    :param components: robust statistics of the whitened residuals (x, y, theta), each
        with sigma 1 when the fit matches
    """

    model: MotionNoise
    sigmas: tuple[float, float, float]
    windows: int
    outliers: int
    window_s: float | None
    components: tuple[ResidualStats, ...]
    at_limit: tuple[str, ...] = ()  # components whose fit hit its lower limit (0)
    standing: int = 0  # windows with no motion, which tell nothing of the noise

    @property
    def left_out_share(self) -> float:
        """The share of the windows left out as outliers."""
        total = self.windows + self.outliers
        return self.outliers / total if total else 0.0


@dataclass(frozen=True, slots=True)
class OdometryFit:
    """Systematic odometry errors fitted from the truth (see :func:`fit_odometry`).

    True distance = scale_d d, true turn = scale_alpha alpha + bias d over a window.

    :param scale_d: scale on the distance, with its standard error ``se_d``
    :param scale_alpha: scale on the turn, with ``se_alpha``
    :param bias: turn per metre driven (rad/m), with ``se_bias``
    :param windows: windows the fit used
    :param applied: the correction the replay applies: a term differing from no error
        (1, 1, 0) by less than ``SIGNIFICANT`` standard errors is left at it
    :param at_limit: the terms the fit pushed to a limit of ``ODOMETRY_LIMITS``
    """

    scale_d: float
    se_d: float
    scale_alpha: float
    se_alpha: float
    bias: float
    se_bias: float
    windows: int
    applied: tuple[float, float, float]
    at_limit: tuple[str, ...]

    def to_json(self) -> dict[str, object]:
        return {
            "scale_distance": self.scale_d,
            "scale_distance_se": self.se_d,
            "scale_turn": self.scale_alpha,
            "scale_turn_se": self.se_alpha,
            "turn_bias_rad_per_m": self.bias,
            "turn_bias_se": self.se_bias,
            "windows": self.windows,
            "applied": {
                "odometry_scale": list(self.applied[:2]),
                "odometry_bias": self.applied[2],
            },
            "at_limit": list(self.at_limit),
        }


@dataclass(frozen=True, slots=True)
class Calibration:
    """What ``ekfviz calibrate`` estimates: measurement and motion noise, and the
    systematic odometry errors (the motion noise is fitted on the corrected odometry)."""

    bearing: ResidualStats
    range: ResidualStats
    motion: MotionFit | None
    sightings: int  # sightings of landmarks the truth knows, at events with a true pose
    odometry: OdometryFit | None = None


@dataclass(slots=True)
class _Window:
    """A motion window being composed: the true start, the pose so far, the unit-noise
    covariances M_x, M_y, M_a as 6 floats each (00, 01, 02, 11, 12, 22), and the sums
    the odometry fit needs: distance, turn, and the distance as a vector (each control's
    d along its composed heading)."""

    start: FloatArray
    pose: FloatArray
    span: float
    M: list[list[float]]
    sum_d: float = 0.0
    sum_alpha: float = 0.0
    u_x: float = 0.0
    u_y: float = 0.0


@dataclass(slots=True)
class _Windows:
    """What the windows of a pass gathered: the noise fit's residuals and unit
    covariances, and per window (start x y theta, end x y theta, sum d, sum alpha, u_x,
    u_y) for the odometry fit."""

    residuals: list[FloatArray]
    units: list[list[list[float]]]
    spans: list[list[float]]
    standing: int = 0


def calibrate(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    *,
    window_s: float = WINDOW_S,
    odometry: bool = True,
) -> Calibration:
    """Estimate the measurement and motion noise of a log from its truth.

    A log whose controls carry their time span (velocity odometry) gets the time-scaled
    motion noise, fitted on windows of ``window_s`` seconds; an untimed one the per-step
    noise, one control a window. True poses come from a timestamped track
    (:meth:`GroundTruth.pose_at`) or per step (``poses_xytheta``, steps counted as the
    replay counts them). With ``odometry``, the systematic odometry errors are fitted
    first (:func:`fit_odometry`) and the motion noise is that of the corrected controls.

    :raises ValueError: a truth without true poses
    """
    if not truth.has_poses:
        raise ValueError("calibration needs true poses (a track, or one pose per step)")
    bearings: list[FloatArray] = []
    ranges: list[FloatArray] = []
    timed = next((e.dt is not None for e in events if isinstance(e, Control)), False)
    numbers = log_steps(isinstance(event, Control) for event in events)
    for event, (_, step) in zip(events, numbers, strict=True):
        if isinstance(event, Sighting):
            pose = truth.pose_of(step, event.time)
            if pose is not None:
                b, r = _measurement_residuals(event, pose, truth)
                bearings.append(b)
                ranges.append(r)
    bearing = robust_stats("bearing", "rad", _joined(bearings))
    rng = robust_stats("range", "m", _joined(ranges))
    windows = _gather(events, truth, timed, window_s, NO_CORRECTION)
    odometry_fit = None
    correction = NO_CORRECTION
    if odometry and windows.spans:
        odometry_fit = fit_odometry(np.array(windows.spans))
        correction = odometry_fit.applied
        if correction != NO_CORRECTION:
            windows = _gather(events, truth, timed, window_s, correction)
    motion_fit = None
    if windows.residuals:
        model = MotionNoise.PER_SQRT_SECOND if timed else MotionNoise.PER_STEP
        motion_fit = replace(
            _fit_motion(
                np.array(windows.residuals), np.array(windows.units), model,
                window_s if timed else None,
            ),
            standing=windows.standing,
        )  # fmt: skip
    sightings = int(sum(len(b) for b in bearings))
    return Calibration(bearing, rng, motion_fit, sightings, odometry_fit)


NO_CORRECTION = (1.0, 1.0, 0.0)
# a fitted term is applied when it differs from no error by this many standard errors
SIGNIFICANT = 3.0
# the odometry fit's limits: a scale off by more than 30 %, a bias over 0.5 rad per
# metre, is no odometry error but a broken log or truth; the fit stops there and says so
ODOMETRY_LIMITS = {"scale_d": (0.7, 1.3), "scale_alpha": (0.7, 1.3), "bias": (-0.5, 0.5)}
ROBUST_ROUNDS = 4  # rounds of the odometry fit, each leaving out residuals over 4 sigma


def fit_odometry(spans: FloatArray) -> OdometryFit:
    """Fit the systematic odometry errors to the windows' odometry and truth.

    The true turn of a window is scale_alpha sum(alpha) + bias sum(d), linear least
    squares; the true displacement projected on u (each control's d along its composed
    heading, summed) is scale_d |u|^2. Both robust: residuals beyond 4 robust sigmas are
    left out, and the fit repeated.

    :param spans: (K, 10) per window start (3), end (3), sum d, sum alpha, u_x, u_y
    """
    start, end = spans[:, 0:3], spans[:, 3:6]
    sum_d, sum_alpha, u = spans[:, 6], spans[:, 7], spans[:, 8:10]
    turn = np.remainder(end[:, 2] - start[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    X = np.column_stack([sum_alpha, sum_d])
    (k_alpha, bias), se_turn = _robust_lstsq(X, turn, (1.0, 0.0))
    along = np.einsum("ka,ka->k", end[:, :2] - start[:, :2], u)
    norm = np.sqrt(np.einsum("ka,ka->k", u, u))
    safe = np.maximum(norm, 1e-12)
    (k_d,), se_d = _robust_lstsq(norm[:, None], along / safe, (1.0,))
    at_limit: list[str] = []
    values = {"scale_d": k_d, "scale_alpha": k_alpha, "bias": bias}
    for name, (low, high) in ODOMETRY_LIMITS.items():
        if not low <= values[name] <= high or not math.isfinite(values[name]):
            at_limit.append(name)
            values[name] = min(max(values[name], low), high) if math.isfinite(values[name]) else 1.0
    errors = {"scale_d": se_d[0], "scale_alpha": se_turn[0], "bias": se_turn[1]}
    applied = []
    for name, none in zip(("scale_d", "scale_alpha", "bias"), NO_CORRECTION, strict=True):
        significant = abs(values[name] - none) > SIGNIFICANT * errors[name]
        applied.append(values[name] if significant and name not in at_limit else none)
    return OdometryFit(
        scale_d=values["scale_d"], se_d=float(se_d[0]),
        scale_alpha=values["scale_alpha"], se_alpha=float(se_turn[0]),
        bias=values["bias"], se_bias=float(se_turn[1]),
        windows=len(spans),
        applied=(applied[0], applied[1], applied[2]),
        at_limit=tuple(at_limit),
    )  # fmt: skip


def _robust_lstsq(
    X: FloatArray, y: FloatArray, prior: tuple[float, ...]
) -> tuple[list[float], list[float]]:
    """Least squares y ~ X b, leaving out residuals beyond 4 robust sigmas; b and its
    standard errors (``prior`` and infinite errors where X carries no information)."""
    use = np.isfinite(y) & np.isfinite(X).all(axis=1)
    b = np.array(prior, dtype=np.float64)
    se = np.full(len(prior), math.inf)
    for _ in range(ROBUST_ROUNDS):
        A, t = X[use], y[use]
        if len(t) <= X.shape[1] or np.linalg.matrix_rank(A) < X.shape[1]:
            return list(prior), se.tolist()
        b = np.asarray(np.linalg.lstsq(A, t, rcond=None)[0], dtype=np.float64)
        r = y - X @ b
        sigma = MAD_TO_SIGMA * float(np.median(np.abs(r[use] - np.median(r[use]))))
        if sigma <= 0:
            break
        use = np.isfinite(r) & (np.abs(r) <= OUTLIER_SIGMAS * sigma)
    A = X[use]
    r = (y - X @ b)[use]
    dof = max(len(r) - X.shape[1], 1)
    covariance = np.linalg.pinv(A.T @ A) * float(r @ r) / dof
    se = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    return b.tolist(), se.tolist()


def _gather(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    timed: bool,
    window_s: float,
    correction: tuple[float, float, float],
) -> _Windows:
    """One pass of motion windows over the events, their controls corrected."""
    gathered = _Windows([], [], [])
    k_d, k_alpha, bias = correction
    window: _Window | None = None
    numbers = log_steps(isinstance(event, Control) for event in events)
    for event, (_, step) in zip(events, numbers, strict=True):
        if isinstance(event, Control):
            if correction != NO_CORRECTION:
                d, alpha = k_d * event.d, k_alpha * event.alpha + bias * event.d
                event = event._replace(d=d, alpha=alpha)
            window = _advance(window, event, step, truth, timed, window_s, gathered)
    return gathered


def _joined(parts: list[FloatArray]) -> FloatArray:
    return np.concatenate(parts) if parts else np.zeros(0)


def _measurement_residuals(
    sighting: Sighting, pose: FloatArray, truth: GroundTruth
) -> tuple[FloatArray, FloatArray]:
    """Bearing and range residuals of the sighting's landmarks the truth knows."""
    landmarks = truth.lookup(sighting.ids)
    known = np.isfinite(landmarks[:, 0])
    d = landmarks[known] - pose[:2]
    true_bearing = np.arctan2(d[:, 1], d[:, 0]) - pose[2]
    true_range = np.hypot(d[:, 0], d[:, 1])
    z = sighting.z[known]
    return wrap_angles(z[:, 0] - true_bearing), z[:, 1] - true_range


def _advance(
    window: _Window | None,
    control: Control,
    step: int,
    truth: GroundTruth,
    timed: bool,
    window_s: float,
    gathered: _Windows,
) -> _Window | None:
    """Add a control to the current window (opening one at its start when none is open),
    and close the window when it spans ``window_s`` (timestamped) or one control."""
    dt = control.dt if timed else None
    if timed and dt is None:
        return None  # a control of unknown span: no window across it
    if window is None:
        if timed:
            assert dt is not None and control.time is not None
            start = _track_pose(truth, control.time - dt)
        else:
            start = truth.pose_of(step - 1, None)
        if start is None:
            return None
        window = _Window(start.copy(), start.copy(), 0.0, [[0.0] * 6 for _ in range(3)])
    theta = float(window.pose[2])
    c, s = math.cos(theta), math.sin(theta)
    a, b = -control.d * s, control.d * c  # G[0, 2], G[1, 2]
    scale = dt if dt is not None else 1.0
    # the filter's model: a control that reads no motion adds no noise (see MotionNoise)
    noise_scale = scale if control.d != 0.0 or control.alpha != 0.0 or not timed else 0.0
    # W diag(e_j) W^T with W the rotation of the robot frame (and 1 for the heading)
    noise = (
        (c * c, c * s, 0.0, s * s, 0.0, 0.0),
        (s * s, -c * s, 0.0, c * c, 0.0, 0.0),
        (0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    )
    for M, q in zip(window.M, noise, strict=True):
        m00, m01, m02, m11, m12, m22 = M
        r02 = m02 + a * m22
        r12 = m12 + b * m22
        M[:] = (
            m00 + 2 * a * m02 + a * a * m22 + noise_scale * q[0],
            m01 + a * m12 + b * m02 + a * b * m22 + noise_scale * q[1],
            r02,
            m11 + 2 * b * m12 + b * b * m22 + noise_scale * q[3],
            r12,
            m22 + noise_scale * q[5],
        )
    window.sum_d += control.d
    window.sum_alpha += control.alpha
    window.u_x += control.d * c
    window.u_y += control.d * s
    window.pose = motion(window.pose, control.d, control.alpha)
    window.span += scale
    if timed and window.span < window_s:
        return window
    end = _track_pose(truth, control.time) if timed else truth.pose_of(step, None)
    if end is not None:
        moved = window.M[0][0] + window.M[0][3] + window.M[2][5] > 0.0
        if moved:  # a window standing still tells nothing of the noise (its M is 0)
            r = end - window.pose
            r[2] = math.remainder(float(r[2]), 2.0 * math.pi)
            gathered.residuals.append(r)
            gathered.units.append([list(M) for M in window.M])
        else:
            gathered.standing += 1
        gathered.spans.append([
            *window.start.tolist(), *end.tolist(),
            window.sum_d, window.sum_alpha, window.u_x, window.u_y,
        ])  # fmt: skip
    return None


def _track_pose(truth: GroundTruth, time: float | None) -> FloatArray | None:
    """The true pose at ``time`` where the track has samples close around it."""
    if time is None or truth.track_times is None:
        return None if time is None else truth.pose_at(time)
    times = truth.track_times
    k = int(np.searchsorted(times, time))
    if k == 0 or k >= len(times):
        return truth.pose_at(time)
    if times[k] - times[k - 1] > MAX_TRACK_GAP_S:
        return None
    return truth.pose_at(time)


def _full(M: FloatArray) -> FloatArray:
    """(..., 6) upper triangles as (..., 3, 3) symmetric matrices."""
    i = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])
    out: FloatArray = M[..., i]
    return out


def _fit_motion(
    residuals: FloatArray,
    units: FloatArray,
    model: MotionNoise,
    window_s: float | None,
) -> MotionFit:
    """Fit q to r r^T = sum_j q_j M_j (see the module), iterated with outlier rejection.

    :param residuals: (K, 3) window residuals
    :param units: (K, 3, 6) M_x, M_y, M_a per window
    """
    K = len(residuals)
    M = _full(units)  # (K, 3, 3, 3): window, component j, 3x3
    products = residuals[:, :, None] * residuals[:, None, :]  # (K, 3, 3)
    pairs = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    use = np.ones(K, dtype=bool)
    q = np.ones(3)
    weights = np.ones((K, len(pairs)))
    for _ in range(FIT_ROUNDS):
        rows = []
        targets = []
        for p, (i, j) in enumerate(pairs):
            w = np.sqrt(weights[use, p])
            rows.append(M[use][:, :, i, j] * w[:, None])
            targets.append(products[use][:, i, j] * w)
        A = np.concatenate(rows)
        y = np.concatenate(targets)
        q = np.maximum(np.linalg.lstsq(A, y, rcond=None)[0], 1e-18)
        Sigma = np.einsum("j,kjab->kab", q, M)
        # var(r_i r_j) = S_ii S_jj + S_ij^2 for a zero-mean Gaussian r
        weights = np.column_stack(
            [1.0 / (Sigma[:, i, i] * Sigma[:, j, j] + Sigma[:, i, j] ** 2) for i, j in pairs]
        )
        d2 = np.einsum("ka,ka->k", residuals, np.linalg.solve(Sigma, residuals[:, :, None])[..., 0])
        use = d2 <= CHI2_3_999
    Sigma = np.einsum("j,kjab->kab", q, M)
    whitened = residuals / np.sqrt(np.diagonal(Sigma, axis1=1, axis2=2))
    components = tuple(
        robust_stats(name, "sigma", whitened[:, k]) for k, name in enumerate(("x", "y", "theta"))
    )
    sx, sy, sa = np.sqrt(q).tolist()
    at_limit = tuple(name for name, v in zip(("x", "y", "alpha"), q, strict=True) if v <= Q_LIMIT)
    return MotionFit(
        model, (sx, sy, sa), int(use.sum()), int(K - use.sum()), window_s, components, at_limit
    )
