"""The options the commands share, as plain values, and what they become: the filter's
parameters, the association of id-less scans, the executor of a study's runs.

A front end fills these from what the user gave (the command line from its option
groups) and says which options were given (:data:`Given`): a value the user gave is
kept, a default may yield to what the input states of itself (an extended log's noise
header, a dataset's models).
"""

from __future__ import annotations

import enum
import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ekfviz.association.params import AssociationParams, Method
from ekfviz.core.errors import InputError, UsageError
from ekfviz.core.params import FilterParams, LandmarkInit, MotionNoise, UpdateMode
from ekfviz.filters.spec import BUILTIN
from ekfviz.io.text import MAX_MAGNITUDE, RANGE_TEXT
from ekfviz.sandbox.options import DEFAULT_TIMEOUT_S, WorkerOptions
from ekfviz.studies.executors import Executor, ExecutorName

__all__ = [
    "BUILTIN",
    "DEFAULT_ASSOCIATION",
    "DEFAULT_PARAMS",
    "DEFAULT_TIMEOUT_S",
    "AssociationSettings",
    "ExecutionSettings",
    "ExecutorName",
    "FilterSettings",
    "Given",
    "LandmarkInit",
    "Method",
    "MotionNoiseChoice",
    "Triple",
    "UpdateMode",
    "WorkerOptions",
    "filter_params",
    "worker_options",
]

Triple = tuple[float, float, float]
Sigmas = tuple[float, float, float, float, float]
Given = Callable[[str], bool]  # whether the option of a parameter's name was given
DEFAULT_PARAMS = FilterParams()  # the classic defaults, stated once
DEFAULT_ASSOCIATION = AssociationParams()
SIGMA_NAMES = ("sigma_x", "sigma_y", "sigma_alpha", "sigma_bearing", "sigma_range")


class MotionNoiseChoice(str, enum.Enum):
    """What the motion sigmas mean: a model of :class:`~ekfviz.core.params.MotionNoise`,
    or what the source implies (``auto``)."""

    AUTO = "auto"
    PER_STEP = MotionNoise.PER_STEP.value
    PER_SQRT_SECOND = MotionNoise.PER_SQRT_SECOND.value


def nothing_given(name: str) -> bool:
    """No option was given: every value is a default (a program's request)."""
    return False


@dataclass(frozen=True, slots=True)
class FilterSettings:
    """The filter's noise and form as asked: its five sigmas (x, y, alpha, bearing,
    range), the sigma of its initial pose, how it adds landmarks and folds a line's
    observations in."""

    sigmas: Sigmas = (
        DEFAULT_PARAMS.sigma_x, DEFAULT_PARAMS.sigma_y, DEFAULT_PARAMS.sigma_alpha,
        DEFAULT_PARAMS.sigma_bearing, DEFAULT_PARAMS.sigma_range,
    )  # fmt: skip
    init_pose_sigma: Triple = DEFAULT_PARAMS.init_pose_sigma
    landmark_init: LandmarkInit = DEFAULT_PARAMS.landmark_init
    update: UpdateMode = DEFAULT_PARAMS.update


def filter_params(
    settings: FilterSettings,
    *,
    log: Path | None = None,
    given: Given = nothing_given,
    note: Callable[[str], None] | None = None,
) -> FilterParams:
    """The filter's parameters as asked, refusing what cannot work.

    :param log: the log replayed: the noise its source states (see
        :meth:`ekfviz.sources.Source.stated_noise`) replaces the defaults of the options
        not ``given``, and ``note`` is told so (a log file: a directory's source needs
        its own options to open)
    :raises UsageError: a sigma out of range, a singular R, a negative prior
    :raises InputError: a noise header that does not read
    """
    names = ("--sigma-x", "--sigma-y", "--sigma-alpha", "--sigma-bearing", "--sigma-range")
    sigmas, init_pose_sigma = settings.sigmas, settings.init_pose_sigma
    for name, value in [
        *zip(names, sigmas, strict=True),
        ("--init-pose-sigma", max(init_pose_sigma)),
    ]:
        if not value <= MAX_MAGNITUDE:  # nan too
            raise UsageError(f"{name} {value:g}: expected a sigma within {RANGE_TEXT}")
    if log is not None and log.is_file():
        sigmas, init_pose_sigma = _log_noise(log, sigmas, init_pose_sigma, given, note)
    sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range = sigmas
    if sigma_bearing <= 0 or sigma_range <= 0:
        raise UsageError("--sigma-bearing and --sigma-range must be positive: R must be invertible")
    if min(init_pose_sigma) < 0:
        raise UsageError("--init-pose-sigma values must not be negative")
    return FilterParams(
        sigma_x=sigma_x,
        sigma_y=sigma_y,
        sigma_alpha=sigma_alpha,
        sigma_bearing=sigma_bearing,
        sigma_range=sigma_range,
        init_pose_sigma=init_pose_sigma,
        landmark_init=settings.landmark_init,
        update=settings.update,
    )


def _log_noise(
    log: Path,
    sigmas: Sigmas,
    init_pose_sigma: Triple,
    given: Given,
    note: Callable[[str], None] | None,
) -> tuple[Sigmas, Triple]:
    """The sigmas and prior with the log's stated noise where no option was given."""
    from ekfviz.sources import open_source

    stated = open_source(log).stated_noise()
    values = dict(zip(SIGMA_NAMES, sigmas, strict=True))
    used = []
    for name in SIGMA_NAMES:
        value = stated.get(name)
        if isinstance(value, float) and not given(name):
            values[name] = value
            used.append(f"--{name.replace('_', '-')} {value:g}")
    prior = stated.get("init_pose_sigma")
    if isinstance(prior, tuple) and not given("init_pose_sigma"):
        init_pose_sigma = prior
        used.append("--init-pose-sigma " + " ".join(f"{v:g}" for v in prior))
    if used and note is not None:
        note(f"{log}: the noise its header states: {' '.join(used)}")
    sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range = (values[n] for n in SIGMA_NAMES)
    return (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range), init_pose_sigma


@dataclass(frozen=True, slots=True)
class AssociationSettings:
    """How id-less scans are associated: ``known`` (the log's ids), nn or jcbb (None: the
    default of the log, known for logs with ids, jcbb for logs with scans), with the
    gates' probability and the confirmation of new landmarks."""

    association: Method | None = None
    gate_probability: float = DEFAULT_ASSOCIATION.gate_probability
    confirm: int = DEFAULT_ASSOCIATION.confirm
    confirm_window: int = DEFAULT_ASSOCIATION.confirm_window

    def params(self) -> AssociationParams | None:
        """None for ``known``, else the method (jcbb by default) with its settings."""
        if self.association is Method.KNOWN:
            return None
        return AssociationParams(
            method=Method.JCBB if self.association is None else self.association,
            gate_probability=self.gate_probability,
            confirm=self.confirm,
            confirm_window=self.confirm_window,
        )

    def for_study(self, data: Path) -> AssociationParams | None:
        """As :meth:`params`, for the runs of a study of ``data`` (sweep, compare). A
        source that is replayed on its own (Victoria Park: its vehicle and sensor models
        are the replay's) is refused.

        :raises InputError: for such a source
        """
        from ekfviz.sources import open_source

        try:
            refusal = open_source(data).study_refusal
        except InputError:
            refusal = None  # the study's own reading says what is wrong with it
        if refusal is not None:
            raise InputError(data, 0, refusal)
        return self.params()


@dataclass(frozen=True, slots=True)
class ExecutionSettings:
    """Where the runs of a study execute: local processes (``workers``, None: one per
    core) or a Dask cluster at ``scheduler``."""

    workers: int | None = None
    executor: ExecutorName = ExecutorName.LOCAL
    scheduler: str | None = None

    def make(self) -> Executor:
        """The executor asked for.

        :raises UsageError: a scheduler without Dask, Dask without its scheduler, ...
        """
        from ekfviz.app.errors import in_family
        from ekfviz.studies.executors import make_executor

        with in_family():
            return make_executor(self.executor, self.scheduler, self.workers)


def worker_options(
    python: Path | None,
    timeout_s: float,
    memory_mb: int | None,
    echo: bool = True,
    *,
    timeout_option: str = "--filter-timeout",
    sandbox: bool = True,
) -> WorkerOptions:
    """How a user's filter runs, the interpreter looked up first.

    :param timeout_option: how the time limit was given, for the message of a bad one
    :param sandbox: in the sandbox (else ``--no-sandbox`` was given)
    :raises UsageError: a time limit that is not a number, an interpreter not found
    """
    if math.isnan(timeout_s):
        raise UsageError(
            f"{timeout_option} {timeout_s}: expected a number of seconds (inf: no bound)"
        )
    if python is not None:
        found = shutil.which(str(python))
        if found is None or not Path(found).is_file():
            raise UsageError(
                f"--python {python}: no such interpreter (expected a Python executable)"
            )
        python = Path(found)
    return WorkerOptions(
        python=None if python is None else str(python),
        timeout_s=None if math.isinf(timeout_s) else timeout_s,
        memory_mb=memory_mb,
        echo=echo,
        sandbox=sandbox,
    )
