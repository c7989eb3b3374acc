"""The filter's parameters: noise levels, prior and options; the classic defaults.

Every filter, source and command takes one frozen :class:`FilterParams`; its enums say
how a new landmark is initialised, how an observation line is folded in and what the
motion sigmas mean.
"""

from __future__ import annotations

import enum
import math
from dataclasses import asdict, dataclass

import numpy as np

from ekfviz.core.errors import FilterError
from ekfviz.core.types import FloatArray


class LandmarkInit(str, enum.Enum):
    """How a new landmark's covariance is initialised."""

    CORRELATED = "correlated"  # with cross-covariances to the pose and the map (exact)
    INDEPENDENT = "independent"  # cross-covariances set to zero (the simplification)


class UpdateMode(str, enum.Enum):
    """How the landmarks of one observation line are folded in."""

    SEQUENTIAL = "sequential"  # one after another in file order, re-linearising between
    JOINT = "joint"  # all at once, linearised at the predicted state


class MotionNoise(str, enum.Enum):
    """What the motion noise sigmas (``sigma_x``, ``sigma_y``, ``sigma_alpha``) mean."""

    # per control, whatever time it spans: Q = diag(sigma^2), sigmas in m and rad (classic)
    PER_STEP = "per-step"
    # per square-root second of the time dt a control spans: Q = diag(sigma^2) * dt,
    # sigmas in m/sqrt(s) and rad/sqrt(s): a random walk, whatever the logging rate. The
    # noise follows the motion: a control that reads no motion (d = alpha = 0, a robot
    # standing still) adds none, since wheels that do not turn do not slip
    PER_SQRT_SECOND = "per-sqrt-second"


def _number(name: str, value: object) -> float:
    """A finite real number of a parameter, as a float.

    :raises ValueError: naming the parameter
    """
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{name} {value!r}: expected a number")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name} {value!r}: expected a finite number")
    return number


@dataclass(frozen=True, slots=True)
class FilterParams:
    """Noise levels, prior and options of the filter; defaults are the classic ones.

    ``motion_noise`` says how the motion sigmas scale (see :class:`MotionNoise`);
    ``gate`` rejects outliers (see :mod:`ekfviz.association.gating`).
    """

    sigma_x: float = 0.25
    sigma_y: float = 0.1
    sigma_alpha: float = 0.1
    sigma_bearing: float = 0.01
    sigma_range: float = 0.08
    init_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    init_pose_sigma: tuple[float, float, float] = (0.02, 0.02, 0.1)
    landmark_init: LandmarkInit = LandmarkInit.CORRELATED
    update: UpdateMode = UpdateMode.SEQUENTIAL
    motion_noise: MotionNoise = MotionNoise.PER_STEP
    # NIS (2 dof) beyond which an observation of a known landmark is rejected as an
    # outlier (see ekfviz.association.gating); None: no gate
    gate: float | None = None
    # systematic odometry errors the replay takes out of every control before the filter
    # sees it (see corrected): scales on the distance and on the turn, and a turn bias in
    # rad per metre driven (wheels of unequal size turn the robot as it drives)
    odometry_scale: tuple[float, float] = (1.0, 1.0)
    odometry_bias: float = 0.0

    def __post_init__(self) -> None:
        """Refuse parameters no filter can run with, naming the field (a notebook's
        ``FilterParams(update="joint")`` ran the sequential update, ``sigma_bearing=0``
        a singular R), and take the options' values as text and the tuples as lists.

        :raises ValueError: naming the field, its value and what was expected
        """
        for name, kind in (
            ("landmark_init", LandmarkInit),
            ("update", UpdateMode),
            ("motion_noise", MotionNoise),
        ):
            value = getattr(self, name)
            if not isinstance(value, kind):
                try:
                    object.__setattr__(self, name, kind(value))
                except ValueError:
                    choices = ", ".join(repr(member.value) for member in kind)
                    raise ValueError(f"{name} {value!r}: expected one of {choices}") from None
        for name in ("sigma_x", "sigma_y", "sigma_alpha", "sigma_bearing", "sigma_range"):
            value = _number(name, getattr(self, name))
            measured = name in ("sigma_bearing", "sigma_range")
            if value < 0.0 or (value == 0.0 and measured):
                raise ValueError(
                    f"{name} {value!r}: "
                    + ("expected a sigma above 0 (R must be invertible)" if measured
                       else "expected a sigma of 0 or more")
                )  # fmt: skip
            object.__setattr__(self, name, value)
        for name, size in (("init_pose", 3), ("init_pose_sigma", 3), ("odometry_scale", 2)):
            values = getattr(self, name)
            try:
                numbers = tuple(_number(name, v) for v in values)
            except (TypeError, ValueError):  # (not a sequence; not numbers)
                numbers = ()
            if len(numbers) != size:
                raise ValueError(f"{name} {values!r}: expected {size} finite numbers")
            if name == "init_pose_sigma" and min(numbers) < 0.0:
                raise ValueError(f"{name} {values!r}: expected sigmas of 0 or more")
            object.__setattr__(self, name, numbers)
        object.__setattr__(self, "odometry_bias", _number("odometry_bias", self.odometry_bias))
        if self.gate is not None and not _number("gate", self.gate) > 0.0:
            raise ValueError(f"gate {self.gate!r}: expected a NIS threshold above 0, or None")

    @property
    def corrects_odometry(self) -> bool:
        """Whether the controls are corrected (a scale other than 1 or a bias)."""
        return self.odometry_scale != (1.0, 1.0) or self.odometry_bias != 0.0

    def corrected(self, d: float, alpha: float) -> tuple[float, float]:
        """A control with the systematic odometry errors taken out.

        d' = k_d d, alpha' = k_alpha alpha + b d (the bias follows the distance, so a
        robot standing still does not turn).
        """
        k_d, k_alpha = self.odometry_scale
        return k_d * d, k_alpha * alpha + self.odometry_bias * d

    @property
    def Q(self) -> FloatArray:
        """Motion noise covariance (3x3) in the robot frame: per control, or per second
        with the time-scaled model (then Q * dt is that of a control spanning dt)."""
        return np.diag(np.square([self.sigma_x, self.sigma_y, self.sigma_alpha]))

    def Q_of(self, dt: float | None) -> FloatArray:
        """The motion noise covariance (3x3) of a control spanning ``dt`` seconds.

        :raises FilterError: the time-scaled model and a control without a known dt
        """
        return self.Q * noise_scale(self.motion_noise, dt)

    def Q_of_motion(self, d: float, alpha: float, dt: float | None) -> FloatArray:
        """The motion noise covariance (3x3) of a control: with the time-scaled model, a
        control that reads no motion (d = alpha = 0) adds none (see :class:`MotionNoise`).
        """
        return self.Q * noise_scale(self.motion_noise, dt, moving=d != 0.0 or alpha != 0.0)

    @property
    def R(self) -> FloatArray:
        """Measurement noise covariance (2x2) of (bearing, range)."""
        return np.diag(np.square([self.sigma_bearing, self.sigma_range]))

    def as_dict(self) -> dict[str, object]:
        """Every value as plain JSON-friendly Python objects."""
        values = asdict(self)
        values["init_pose"] = list(self.init_pose)
        values["init_pose_sigma"] = list(self.init_pose_sigma)
        values["odometry_scale"] = list(self.odometry_scale)
        values["landmark_init"] = self.landmark_init.value
        values["update"] = self.update.value
        values["motion_noise"] = self.motion_noise.value
        return values


def noise_scale(model: MotionNoise, dt: float | None, moving: bool = True) -> float:
    """The factor of diag(sigma^2) in a control's Q: 1 per step, dt per second (0 for a
    control that reads no motion: ``moving`` False)."""
    if model is MotionNoise.PER_STEP:
        return 1.0
    if dt is None:
        raise FilterError(
            "the motion noise is per square-root second (--motion-noise per-sqrt-second),"
            " but this control has no time span: use --motion-noise per-step"
        )
    if not dt >= 0.0:
        raise FilterError(f"a control spans {dt:g} s, expected a time span >= 0")
    return dt if moving else 0.0
