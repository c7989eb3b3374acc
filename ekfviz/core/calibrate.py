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

What a filter should be told: real logs have errors these estimates do not see (odometry
errors correlated over many seconds, a measurement bias, heavy tails), and a filter
told only the white part is over-confident. :func:`consistent_scale` replays the log
with the estimates and scales every sigma by the smallest factor k >= 1 that brings the
time-averaged pose NEES to its expected value, 3 (chi-square with 3 dof), the standard
consistency test against ground truth (Bar-Shalom et al., 2001, ch. 5.4).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ekfviz.core.consistency import pose_nees
from ekfviz.core.filter import FilterError, FilterParams, MotionNoise
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
NEES_TARGET = 3.0  # the mean of chi-square with 3 degrees of freedom
NEES_TOLERANCE = 1.1  # a mean NEES up to 10 % above it counts as consistent
SCALE_ROUNDS = 8  # replays at most
SCALE_RESOLUTION = 1.2  # the factor is found to within this ratio


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


@dataclass(frozen=True, slots=True)
class Calibration:
    """What ``ekfviz calibrate`` estimates: measurement and motion noise."""

    bearing: ResidualStats
    range: ResidualStats
    motion: MotionFit | None
    sightings: int  # sightings of landmarks the truth knows, at events with a true pose


@dataclass(slots=True)
class _Window:
    """A motion window being composed: the true start, the pose so far, the unit-noise
    covariances M_x, M_y, M_a as 6 floats each (00, 01, 02, 11, 12, 22)."""

    start: FloatArray
    pose: FloatArray
    span: float
    M: list[list[float]]


def calibrate(
    events: Iterable[LogEvent],
    truth: GroundTruth,
    *,
    window_s: float = WINDOW_S,
) -> Calibration:
    """Estimate the measurement and motion noise of a log from its truth.

    A log whose controls carry their time span (velocity odometry) gets the time-scaled
    motion noise, fitted on windows of ``window_s`` seconds; an untimed one the per-step
    noise, one control a window. True poses come from a timestamped track
    (:meth:`GroundTruth.pose_at`) or per step (``poses_xytheta``, steps counted as the
    replay counts them).

    :raises ValueError: a truth without true poses
    """
    if not truth.has_poses:
        raise ValueError("calibration needs true poses (a track, or one pose per step)")
    bearings: list[FloatArray] = []
    ranges: list[FloatArray] = []
    residuals: list[FloatArray] = []
    units: list[list[list[float]]] = []
    timed: bool | None = None
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
            pose = truth.pose_of(step, event.time)
            if pose is not None:
                b, r = _measurement_residuals(event, pose, truth)
                bearings.append(b)
                ranges.append(r)
        else:
            if timed is None:
                timed = event.dt is not None
            step += 1
            step_has_update = False
            window = _advance(window, event, step, truth, bool(timed), window_s, residuals, units)
        first = False
    bearing = robust_stats("bearing", "rad", _joined(bearings))
    rng = robust_stats("range", "m", _joined(ranges))
    motion_fit = None
    if residuals:
        model = MotionNoise.PER_SQRT_SECOND if timed else MotionNoise.PER_STEP
        motion_fit = _fit_motion(
            np.array(residuals), np.array(units), model, window_s if timed else None
        )
    return Calibration(bearing, rng, motion_fit, int(sum(len(b) for b in bearings)))


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
    residuals: list[FloatArray],
    units: list[list[list[float]]],
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
            m00 + 2 * a * m02 + a * a * m22 + scale * q[0],
            m01 + a * m12 + b * m02 + a * b * m22 + scale * q[1],
            r02,
            m11 + 2 * b * m12 + b * b * m22 + scale * q[3],
            r12,
            m22 + scale * q[5],
        )
    window.pose = motion(window.pose, control.d, control.alpha)
    window.span += scale
    if timed and window.span < window_s:
        return window
    end = _track_pose(truth, control.time) if timed else truth.pose_of(step, None)
    if end is not None:
        r = end - window.pose
        r[2] = math.remainder(float(r[2]), 2.0 * math.pi)
        residuals.append(r)
        units.append([list(M) for M in window.M])
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
    return MotionFit(model, (sx, sy, sa), int(use.sum()), int(K - use.sum()), window_s, components)


@dataclass(frozen=True, slots=True)
class Scaling:
    """The factor on every sigma that makes the filter consistent with the truth.

    :param factor: k >= 1
    :param nees_before: time-averaged pose NEES with the estimates as they are
    :param nees_after: with every sigma times k
    :param replays: replays it took
    """

    factor: float
    nees_before: float
    nees_after: float
    replays: int


def mean_nees(events: Sequence[LogEvent], truth: GroundTruth, params: FilterParams) -> float:
    """The pose NEES averaged over the updates that have a true pose (inf if the filter
    fails, NaN when none has)."""
    values: list[float] = []
    try:
        for record in replay(events, params):
            if record.kind is EventKind.UPDATE:
                nees = pose_nees(record, truth)
                if nees is not None:
                    values.append(nees)
    except FilterError:
        return math.inf
    return float(np.mean(values)) if values else math.nan


def consistent_scale(
    events: Sequence[LogEvent], truth: GroundTruth, params: FilterParams
) -> Scaling:
    """The smallest factor k >= 1 on all five sigmas whose replay has a mean pose NEES of
    at most ``NEES_TARGET`` (within ``NEES_TOLERANCE``); see the module.

    The NEES of a filter falls about as 1 / k^2 with its sigmas scaled by k: k grows by
    sqrt(NEES / 3) (a little more, at most 3 times a round) until the filter is
    consistent, then is bisected (on a log scale) down to ``SCALE_RESOLUTION``.
    """

    def scaled(k: float) -> FilterParams:
        return replace(
            params,
            sigma_x=params.sigma_x * k,
            sigma_y=params.sigma_y * k,
            sigma_alpha=params.sigma_alpha * k,
            sigma_bearing=params.sigma_bearing * k,
            sigma_range=params.sigma_range * k,
        )

    before = mean_nees(events, truth, params)
    if before <= NEES_TARGET * NEES_TOLERANCE or math.isnan(before):
        return Scaling(1.0, before, before, 1)
    low, high = 1.0, None  # inconsistent at low; consistent at high, with its NEES
    nees, high_nees, rounds = before, math.nan, 1
    while high is None and rounds < SCALE_ROUNDS:
        # NEES ~ 1 / k^2 while the filter tracks; a diverged one needs no more than x3
        grow = 3.0 if not math.isfinite(nees) else 1.05 * math.sqrt(nees / NEES_TARGET)
        k = low * min(grow, 3.0)
        nees = mean_nees(events, truth, scaled(k))
        rounds += 1
        if nees <= NEES_TARGET * NEES_TOLERANCE:
            high, high_nees = k, nees
        else:
            low = k
    if high is None:
        return Scaling(low, before, nees, rounds)
    while high / low > SCALE_RESOLUTION and rounds < SCALE_ROUNDS:
        k = math.sqrt(low * high)  # bisect on a log scale
        nees = mean_nees(events, truth, scaled(k))
        rounds += 1
        if nees <= NEES_TARGET * NEES_TOLERANCE:
            high, high_nees = k, nees
        else:
            low = k
    return Scaling(high, before, high_nees, rounds)
