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

What a filter should be told: real logs have errors these estimates do not see (odometry
errors correlated over many seconds, a measurement bias, heavy tails), and a filter
told only the white part is over-confident. :func:`recommend` fits on the first part of
the run, scales the sigmas (the measurement by the NIS, the motion by the pose NEES,
:func:`scale_apart`; or one factor for all), and judges every candidate, the defaults
among them, on what the fit did not see (NEES and NIS over the held-out time, the final
map against the truth), the standard consistency tests against ground truth
(Bar-Shalom et al., 2001, ch. 5.4) beside the map's error and ellipse size.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ekfviz.core.consistency import Consistency, chi2_bounds, pose_nees, update_nis
from ekfviz.core.evaluation import MapSummary, evaluate
from ekfviz.core.filter import EkfSlam, FilterError, FilterParams, MotionNoise
from ekfviz.core.gating import gated
from ekfviz.core.records import Control, EventKind, LogEvent, Sighting
from ekfviz.core.replay import replay
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
    step = 0
    step_has_update = False
    first = True
    for event in events:
        if isinstance(event, Sighting):
            if first:
                step_has_update = True
            elif step_has_update:
                step += 1
            step_has_update = True
            pose = truth.pose_of(step, event.time)
            if pose is not None:
                b, r = _measurement_residuals(event, pose, truth)
                bearings.append(b)
                ranges.append(r)
        else:
            step += 1
            step_has_update = False
        first = False
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
    step = 0
    step_has_update = False
    window: _Window | None = None
    first = True
    for event in events:
        if isinstance(event, Sighting):
            if first:
                step_has_update = True
            elif step_has_update:
                step += 1
            step_has_update = True
        else:
            step += 1
            step_has_update = False
            if correction != NO_CORRECTION:
                d, alpha = k_d * event.d, k_alpha * event.alpha + bias * event.d
                event = replace(event, d=d, alpha=alpha)
            window = _advance(window, event, step, truth, timed, window_s, gathered)
        first = False
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


# --- scaling and validation on held-out time -------------------------------------------

FIT_SHARE = 0.6  # the first 60 % of the run are fitted, the rest judges
NEES_TARGET = 3.0  # the mean of chi-square with 3 degrees of freedom
NEES_TOLERANCE = 1.1  # a mean NEES up to 10 % above it counts as consistent
SCALE_ROUNDS = 6  # replays of a scale's search at most, before its bisection
SCALE_RESOLUTION = 1.15  # the factor is found to within this ratio
MAX_SCALE = 12.0  # no factor beyond this: the search stops there and says so
LARGE_SCALE = 5.0  # a factor over this: the model misses errors of the log
MAP_CREDIBLE = 0.8  # a held-out map with this share of landmarks inside 3 sigma is credible
WIDENINGS = (2.0, 4.0)  # where no candidate is credible, the closest one widened so
LEFT_OUT_WARNING = 0.05  # more windows left out than this: said (a Gaussian: 0.1 %)
# a sigma whose fit hit its limit (0) is replaced in the replay by this share of the
# default sigma of its component: a filter must never be told a motion is exact
LIMIT_SHARE = 0.1


@dataclass(frozen=True, slots=True)
class RunStats:
    """A replay judged against the truth: mean NEES and NIS, their counts, the map.

    :param nees: mean pose NEES (3 expected; inf: the filter failed)
    :param nis: mean NIS per degree of freedom (1 expected)
    :param nees_inside: share of NEES values inside the 95 % bounds
    :param nis_inside: share of NIS values inside the 95 % bounds
    :param verdict: NEES and NIS together (:meth:`Consistency.combined`)
    :param map: the final map's summary, None without landmarks with truth
    """

    nees: float
    nis: float
    nees_inside: float
    nis_inside: float
    verdict: str
    map: MapSummary | None

    @property
    def credible(self) -> bool:
        """A map with at least ``MAP_CREDIBLE`` of its landmarks inside 3 sigma."""
        m = self.map
        return m is not None and m.landmarks > 0 and m.inside >= MAP_CREDIBLE * m.landmarks

    @property
    def error(self) -> float:
        return math.inf if self.map is None else self.map.mean_error

    def to_json(self) -> dict[str, object]:
        def value(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "mean_nees": value(self.nees),
            "mean_nis_per_dof": value(self.nis),
            "nees_inside": value(self.nees_inside),
            "nis_inside": value(self.nis_inside),
            "verdict": self.verdict,
            "map": None if self.map is None else self.map.to_json(),
        }


FAILED = RunStats(math.inf, math.inf, 0.0, 0.0, "failed", None)


def run_stats(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    params: FilterParams,
    *,
    after: float | None = None,
) -> RunStats:
    """Replay ``events`` with ``params`` and judge the run against ``truth``.

    :param after: count NEES and NIS only after this time (timed) or step (untimed);
        the map is judged at the end either way
    """
    consistency = Consistency(truth)
    nees: list[float] = []
    nis_total = dof_total = 0.0
    last = None
    try:
        for record in replay(events, params):
            last = record
            if after is not None:
                when = record.time if record.time is not None else float(record.step)
                if when <= after:
                    continue
            consistency.add(record)
            if record.kind is EventKind.UPDATE:
                value = pose_nees(record, truth)
                if value is not None:
                    nees.append(value)
                nis = update_nis(record)
                if nis is not None:
                    nis_total += nis[0]
                    dof_total += nis[1]
    except FilterError:
        return FAILED
    if last is None:
        return FAILED
    evaluation = evaluate(last, truth, consistency)
    both = consistency.combined()
    return RunStats(
        nees=float(np.mean(nees)) if nees else math.nan,
        nis=nis_total / dof_total if dof_total else math.nan,
        nees_inside=consistency.nees.fraction_inside,
        nis_inside=consistency.nis.fraction_inside,
        verdict="no update" if both is None else both[0].value,
        map=evaluation.summary,
    )


def judge(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    params: FilterParams,
    *,
    after: float | None = None,
) -> RunStats:
    """What :func:`run_stats` finds, from the built-in filter driven directly.

    The replay makes a record of every event (a predict too) and checks the whole
    covariance now and then, which a judgement needs neither of: this loop does the
    filter's work as :func:`~ekfviz.core.replay.replay` does it (the same steps, gate
    and odometry correction) and takes the NEES, NIS and final map from the filter,
    several times faster. A test holds it to :func:`run_stats`.
    """
    ekf = EkfSlam(params)
    consistency = Consistency(truth)
    nees_values: list[float] = []
    nis_total = dof_total = 0.0
    gate, R = params.gate, params.R
    correct = params.corrects_odometry
    step = 0
    step_has_update = True
    time: float | None = None
    nees_bounds = chi2_bounds(3)
    try:
        for k, event in enumerate(events):
            time = event.time
            if isinstance(event, Control):
                step += 1
                step_has_update = False
                d, alpha = (
                    params.corrected(event.d, event.alpha) if correct else (event.d, event.alpha)
                )
                ekf.predict(d, alpha, event.dt)
                continue
            if k and step_has_update:
                step += 1
            step_has_update = True
            sighting = event
            if gate is not None and k:
                sighting, _ = gated(ekf.x, ekf.P, ekf.landmark_ids, event, R, gate)
            observations = ekf.observe(sighting.ids, sighting.z)
            if after is not None and (time if time is not None else float(step)) <= after:
                continue
            used = observations.nis[np.isfinite(observations.nis)]
            if used.size:
                total, dof = float(used.sum()), 2 * int(used.size)
                consistency.nis.add(total, chi2_bounds(dof))
                nis_total += total
                dof_total += dof
            true_pose = truth.pose_of(step, time)
            if true_pose is not None:
                e = ekf.x[:3] - true_pose
                e[2] = math.remainder(float(e[2]), 2.0 * math.pi)
                try:
                    value = float(e @ np.linalg.solve(ekf.P[:3, :3], e))
                except np.linalg.LinAlgError:
                    continue
                consistency.nees.add(value, nees_bounds)
                nees_values.append(value)
    except FilterError:
        return FAILED
    last = ekf.record(event=len(events), step=step, kind=EventKind.UPDATE, time=time)
    evaluation = evaluate(last, truth)
    both = consistency.combined()
    return RunStats(
        nees=float(np.mean(nees_values)) if nees_values else math.nan,
        nis=nis_total / dof_total if dof_total else math.nan,
        nees_inside=consistency.nees.fraction_inside,
        nis_inside=consistency.nis.fraction_inside,
        verdict="no update" if both is None else both[0].value,
        map=evaluation.summary,
    )


def mean_nees(events: Sequence[LogEvent], truth: GroundTruth, params: FilterParams) -> float:
    """The pose NEES averaged over the updates that have a true pose (inf if the filter
    fails, NaN when none has)."""
    return run_stats(events, truth, params).nees


def scaled(params: FilterParams, motion: float, measurement: float) -> FilterParams:
    """``params`` with the motion sigmas times ``motion``, the measurement's times
    ``measurement``."""
    return replace(
        params,
        sigma_x=params.sigma_x * motion,
        sigma_y=params.sigma_y * motion,
        sigma_alpha=params.sigma_alpha * motion,
        sigma_bearing=params.sigma_bearing * measurement,
        sigma_range=params.sigma_range * measurement,
    )


@dataclass(frozen=True, slots=True)
class Scaling:
    """Separate factors on the motion and the measurement sigmas (see :func:`scale_apart`).

    :param motion: k_m >= 1 on the motion sigmas, from the pose NEES
    :param measurement: k_z >= 1 on the measurement sigmas, from the NIS
    :param before: the run with the estimates as they are
    :param after: with both factors
    :param replays: replays it took
    :param at_limit: the motion search reached ``MAX_SCALE`` without consistency
    """

    motion: float
    measurement: float
    before: RunStats
    after: RunStats
    replays: int
    at_limit: bool = False

    def to_json(self) -> dict[str, object]:
        return {
            "motion": self.motion,
            "measurement": self.measurement,
            "before": self.before.to_json(),
            "after": self.after.to_json(),
            "replays": self.replays,
            "at_limit": self.at_limit,
        }


def scale_apart(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    params: FilterParams,
    *,
    together: bool = False,
    before: RunStats | None = None,
) -> Scaling:
    """The measurement factor from the NIS, then the motion factor from the NEES.

    k_z = sqrt(mean NIS per dof) (at least 1) makes the innovations as large as the
    filter expects; then the smallest k_m >= 1 whose replay has a mean pose NEES of at
    most ``NEES_TARGET`` (within ``NEES_TOLERANCE``): k_m grows by sqrt(NEES / 3) (at
    most 3 times a round) until the filter is consistent, then is bisected on a log
    scale to ``SCALE_RESOLUTION``. With ``together``, one factor on all five sigmas
    (k_z = k_m) is searched instead, the NIS left aside.

    :param before: the run with ``params`` as they are, when it is known
    """
    replays = 0
    if before is None:
        before = judge(events, truth, params)
        replays = 1
    k_z = 1.0
    if not together and math.isfinite(before.nis) and before.nis > 1.0:
        k_z = min(math.sqrt(before.nis), MAX_SCALE)
    current = before if k_z == 1.0 else judge(events, truth, scaled(params, 1.0, k_z))
    replays += k_z != 1.0

    def ok(stats: RunStats) -> bool:
        return stats.nees <= NEES_TARGET * NEES_TOLERANCE

    def factors(k: float) -> FilterParams:
        return scaled(params, k, k if together else k_z)

    def result(k: float, stats: RunStats, at_limit: bool = False) -> Scaling:
        return Scaling(k, k if together else k_z, before, stats, replays, at_limit)

    if ok(current) or math.isnan(current.nees):
        return result(1.0, current)
    low, high = 1.0, None
    best = stats = current
    while high is None and replays < SCALE_ROUNDS and low < MAX_SCALE:
        grow = 3.0 if not math.isfinite(stats.nees) else 1.05 * math.sqrt(stats.nees / NEES_TARGET)
        k = min(low * min(grow, 3.0), MAX_SCALE)
        stats = judge(events, truth, factors(k))
        replays += 1
        if ok(stats):
            high, best = k, stats
        else:
            low = k
    if high is None:
        return result(low, stats, at_limit=low >= MAX_SCALE)
    while high / low > SCALE_RESOLUTION and replays < SCALE_ROUNDS + 3:
        k = math.sqrt(low * high)
        stats = judge(events, truth, factors(k))
        replays += 1
        if ok(stats):
            high, best = k, stats
        else:
            low = k
    return result(high, best)


@dataclass(frozen=True, slots=True)
class Candidate:
    """A setting judged on the held-out part of the run.

    :param name: what it is (``defaults``, ``estimated``, ``scaled`` ...)
    :param params: the filter's parameters (the held-out replay starts elsewhere)
    :param held_out: the replay of the held-out part
    :param factors: (motion, measurement) scales on the estimates, None for the defaults
    """

    name: str
    params: FilterParams
    held_out: RunStats
    factors: tuple[float, float] | None = None

    def to_json(self) -> dict[str, object]:
        p = self.params
        return {
            "name": self.name,
            "sigmas": {
                "sigma_x": p.sigma_x, "sigma_y": p.sigma_y, "sigma_alpha": p.sigma_alpha,
                "sigma_bearing": p.sigma_bearing, "sigma_range": p.sigma_range,
            },
            "motion_noise": p.motion_noise.value,
            "gate": p.gate,
            "odometry_scale": list(p.odometry_scale),
            "odometry_bias": p.odometry_bias,
            "factors": None if self.factors is None else list(self.factors),
            "held_out": self.held_out.to_json(),
            "credible": self.held_out.credible,
        }  # fmt: skip


@dataclass(frozen=True, slots=True)
class Split:
    """Where a run is cut: the events fitted, the events held out and how they start.

    :param fit: the first part's events
    :param rest: the held-out events, from a control on
    :param start_pose: the true pose where the rest begins (its replay starts there)
    :param truth: the truth of the rest (per-step poses shifted to its steps)
    :param at: the time (s) or the step where it is cut
    """

    fit: list[LogEvent]
    rest: list[LogEvent]
    start_pose: FloatArray | None
    truth: GroundTruth
    at: float


def split_run(events: Sequence[LogEvent], truth: GroundTruth, share: float = FIT_SHARE) -> Split:
    """Cut a run at ``share`` of its time (of its events, untimed) at a control."""
    times = [e.time for e in events if e.time is not None]
    timed = len(times) == len(events) and len(times) > 1
    if timed:
        t0 = times[0]
        first = events[0]
        if isinstance(first, Control) and first.dt is not None:
            t0 -= first.dt
        cut_time = t0 + share * (times[-1] - t0)
        k = next((i for i, e in enumerate(events) if (e.time or 0.0) > cut_time), len(events))
    else:
        k = int(share * len(events))
    while k < len(events) and not isinstance(events[k], Control):
        k += 1
    fit, rest = list(events[:k]), list(events[k:])
    if timed:
        at = times[0] if not fit else float(fit[-1].time or 0.0)
        return Split(fit, rest, truth.pose_at(at), truth, at)
    steps = _steps(fit)
    start = truth.pose_of(steps, None)
    shifted = truth
    if truth.poses_xytheta is not None:
        shifted = replace(truth, poses_xytheta=truth.poses_xytheta[steps:])
    return Split(fit, rest, start, shifted, float(steps))


def _steps(events: Sequence[LogEvent]) -> int:
    """The step the replay of ``events`` ends at (counted as :func:`replay` counts)."""
    step = 0
    step_has_update = False
    for k, event in enumerate(events):
        if isinstance(event, Sighting):
            if k and step_has_update:
                step += 1
            step_has_update = True
        else:
            step += 1
            step_has_update = False
    return step


@dataclass(frozen=True, slots=True)
class Recommendation:
    """What ``ekfviz calibrate`` found and recommends.

    :param calibration: the estimates, fitted on the first part of the run
    :param scaling: the factors found on the first part, motion and measurement apart
    :param together: the one factor on all sigmas found there
    :param candidates: every setting judged on the held-out part
    :param chosen: the index of the recommended one
    :param split: where the run was cut
    :param notes: what a user must know (limits hit, windows left out, large factors)
    """

    calibration: Calibration
    scaling: Scaling
    together: Scaling
    candidates: tuple[Candidate, ...]
    chosen: int
    split_at: float
    fit_share: float
    notes: tuple[str, ...]

    @property
    def best(self) -> Candidate:
        return self.candidates[self.chosen]


def estimated_params(
    calibration: Calibration, base: FilterParams, *, gate: float | None
) -> tuple[FilterParams, list[str]]:
    """``base`` with the estimates: sigmas, the odometry correction, the gate; a sigma
    that hit its fit's limit replaced (``LIMIT_SHARE`` of the default's), with a note."""
    motion = calibration.motion
    assert motion is not None
    notes: list[str] = []
    defaults = FilterParams()
    sigmas = list(motion.sigmas)
    for k, (name, default) in enumerate(
        zip(("x", "y", "alpha"), (defaults.sigma_x, defaults.sigma_y, defaults.sigma_alpha),
            strict=True)
    ):  # fmt: skip
        if name in motion.at_limit:
            sigmas[k] = LIMIT_SHARE * default
            notes.append(
                f"the motion sigma {name} hit the lower limit of its fit (0): the errors"
                f" left none for it; the replay uses {sigmas[k]:.3g}, a tenth of the"
                " default, since no motion is exact"
            )
    odometry = calibration.odometry
    correction = NO_CORRECTION if odometry is None else odometry.applied
    params = replace(
        base,
        sigma_x=sigmas[0], sigma_y=sigmas[1], sigma_alpha=sigmas[2],
        sigma_bearing=calibration.bearing.sigma, sigma_range=calibration.range.sigma,
        motion_noise=motion.model, gate=gate,
        odometry_scale=(correction[0], correction[1]), odometry_bias=correction[2],
    )  # fmt: skip
    return params, notes


def recommend(
    events: Sequence[LogEvent],
    truth: GroundTruth,
    base: FilterParams,
    defaults: FilterParams,
    *,
    window_s: float = WINDOW_S,
    fit_share: float = FIT_SHARE,
    gate: float | None = None,
    heavy_tail_gate: float | None = None,
) -> Recommendation:
    """Fit on the first part of the run, judge the candidates on the rest, recommend one.

    The estimates (noise and odometry errors) and the scale factors come from the first
    ``fit_share`` of the run only. The candidates: the defaults (``defaults``, what a
    replay without options does), the estimates as they are, scaled apart (motion by the
    NEES, measurement by the NIS, :func:`scale_apart`) and scaled together (one factor),
    and, where an odometry correction was found, the defaults with it and both scalings
    without it. Each is replayed
    over the whole run, as the user's replay will be (a replay of the rest alone would
    start from a map-less state the user never sees, and misses the frame errors of the
    first minutes that dominate the final map), and judged on what the fit did not see:
    NEES and NIS over the held-out time, and the final map against the truth. A credible
    map (``MAP_CREDIBLE`` inside 3 sigma) beats one that is not, then the lower mean
    landmark error wins. The defaults are a candidate, so the recommendation is never
    worse than them by that order.

    :param base: the replay's parameters (start pose, model) the estimates go into
    :param heavy_tail_gate: the gate for measurements with heavy tails (None: no gate)
    """
    split = split_run(events, truth, fit_share)
    calibration = calibrate(split.fit, truth, window_s=window_s)
    if calibration.odometry is not None and calibration.odometry.applied != NO_CORRECTION:
        # the controls corrected once, not in every replay: the replays below are told
        # no correction, the candidates keep theirs
        k_d, k_alpha, bias = calibration.odometry.applied
        corrected_events: list[LogEvent] = [
            Control(e.line, k_d * e.d, k_alpha * e.alpha + bias * e.d, e.time, e.dt)
            if isinstance(e, Control)
            else e
            for e in events
        ]
        corrected_fit = corrected_events[: len(split.fit)]
    else:
        corrected_events, corrected_fit = list(events), split.fit
    if calibration.motion is None or calibration.sightings == 0:
        raise ValueError("no sightings or no controls with a true pose in the first part")
    heavy = not (calibration.bearing.gaussian and calibration.range.gaussian)
    estimated, notes = estimated_params(
        calibration, base, gate=gate if gate is not None else heavy_tail_gate if heavy else None
    )
    as_read = replace(estimated, odometry_scale=(1.0, 1.0), odometry_bias=0.0)
    before = judge(corrected_fit, truth, as_read)
    scaling = scale_apart(corrected_fit, truth, as_read, before=before)
    one = scale_apart(corrected_fit, truth, as_read, together=True, before=before)
    settings: list[tuple[str, FilterParams, tuple[float, float] | None]] = [
        ("defaults", defaults, None),
        ("estimated", estimated, (1.0, 1.0)),
        (
            "scaled apart",
            scaled(estimated, scaling.motion, scaling.measurement),
            (scaling.motion, scaling.measurement),
        ),
        ("scaled together", scaled(estimated, one.motion, one.motion), (one.motion, one.motion)),
    ]
    if estimated.corrects_odometry:
        # a log's odometry errors may be shared by its measurements (a range scale): the
        # correction is judged, not assumed
        plain = replace(estimated, odometry_scale=(1.0, 1.0), odometry_bias=0.0)
        settings.append((
            "scaled apart, odometry as read",
            scaled(plain, scaling.motion, scaling.measurement),
            (scaling.motion, scaling.measurement),
        ))  # fmt: skip
        settings.append((
            "scaled together, odometry as read", scaled(plain, one.motion, one.motion),
            (one.motion, one.motion),
        ))  # fmt: skip
        settings.append((
            "defaults, odometry corrected",
            replace(defaults, odometry_scale=estimated.odometry_scale,
                    odometry_bias=estimated.odometry_bias),
            None,
        ))  # fmt: skip

    def judged(params: FilterParams) -> RunStats:
        """The whole run judged on the held-out part (the events corrected once)."""
        if params.corrects_odometry and params.odometry_scale == estimated.odometry_scale:
            run = replace(params, odometry_scale=(1.0, 1.0), odometry_bias=0.0)
            return judge(corrected_events, truth, run, after=split.at)
        return judge(events, truth, params, after=split.at)

    candidates: list[Candidate] = []
    for name, params, factors in settings:
        if any(c.params == params for c in candidates):
            continue  # a factor of 1: the same setting as one judged already
        candidates.append(Candidate(name, params, judged(params), factors))
    if not any(c.held_out.credible for c in candidates):
        # none credible: the most accurate, widened until its map is (a map inside its
        # ellipses with a known error beats a tighter one that is not)
        closest = min(candidates, key=lambda c: c.held_out.error)
        for widen in WIDENINGS:
            motion, measurement = closest.factors or (1.0, 1.0)
            params = scaled(closest.params, widen, widen)
            stats = judged(params)
            name = f"{closest.name}, {widen:g} times wider"
            factors = (motion * widen, measurement * widen)
            candidates.append(Candidate(name, params, stats, factors))
            if stats.credible:
                break
    chosen = min(
        range(len(candidates)),
        key=lambda k: (not candidates[k].held_out.credible, candidates[k].held_out.error, k),
    )
    notes += _notes(calibration, scaling, candidates[chosen])
    return Recommendation(
        calibration, scaling, one, tuple(candidates), chosen, split.at, fit_share, tuple(notes)
    )


def _notes(calibration: Calibration, scaling: Scaling, best: Candidate) -> list[str]:
    notes = []
    motion = calibration.motion
    assert motion is not None
    if motion.left_out_share > LEFT_OUT_WARNING:
        notes.append(
            f"{motion.left_out_share:.0%} of the motion windows lie beyond the 99.9 % bound"
            " of the fit and were left out (a Gaussian: 0.1 %): the odometry has errors the"
            " fitted noise does not describe (slips, bumps, errors correlated over longer"
            " times)"
        )
    odometry = calibration.odometry
    if odometry is not None and odometry.at_limit:
        notes.append(
            f"the odometry fit hit its limits for {', '.join(odometry.at_limit)}: those terms"
            " are not applied (a log or truth out of step?)"
        )
    if scaling.at_limit:
        notes.append(
            f"no motion factor up to {MAX_SCALE:g} made the filter consistent on the fitted part"
        )
    if best.factors is not None and max(best.factors) > LARGE_SCALE:
        notes.append(
            f"the recommendation scales sigmas by {max(best.factors):.3g} (over"
            f" {LARGE_SCALE:g}): the log has errors the noise model does not describe"
            " (odometry errors correlated over minutes, biases, heavy tails); the filter"
            " is kept honest by inflating its covariance, at the cost of a less certain map"
        )
    return notes
