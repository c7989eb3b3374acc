"""The options the commands share, declared once: each group a frozen dataclass of typer
parameters that a command takes as one argument (``noise: FilterNoise``).

:func:`expands_options` spreads a group's fields into the command's signature where the
group stands, so that typer shows them as before (same names, help, panels and order), and
gathers them back into the dataclass before the command runs. A field added to a group
appears on every command that takes the group, by that one edit.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import shutil
import typing
from collections.abc import Callable
from dataclasses import astuple, dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import typer

from ekfviz.association import AssociationParams
from ekfviz.cli.common import (
    DEFAULT,
    DEFAULT_FILTER_TIMEOUT_S,
    FILTER_NOISE,
    FILTER_OPTIONS,
    Triple,
    _option,
    fail,
    given,
    out,
    piped_input,
)
from ekfviz.cli.scans import (  # the association's options stay beside its set-up
    DEFAULT_ASSOCIATION,
    AssociationOption,
    Confirm,
    ConfirmWindow,
    GateProbability,
    association_params,
    study_association,
)
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams, LandmarkInit, UpdateMode
from ekfviz.io.text import MAX_MAGNITUDE, RANGE_TEXT
from ekfviz.sim.scenarios import Scenario, ScenarioName
from ekfviz.sim.simulate import Detection, Noise
from ekfviz.studies.executors import Executor, ExecutorError, ExecutorName, make_executor

# -- the declarations --------------------------------------------------------------------

TRUE_NOISE = "True noise (default: the scenario's)"
LOOP = "Loop scenario"
SENSOR = "Detection"
USER_FILTERS = "User filters"
STUDY = "Where the runs execute"

WatchOption = Annotated[
    bool,
    typer.Option(
        "--watch",
        help="Check again on every save of the filter's files (the module and the files"
        " beside it that it imports) or of the log, each run a new recording in the viewer"
        " that stays open (as ekfviz watch does), until Ctrl-C.",
    ),
]
SigmaX = Annotated[
    float, _option("Motion noise sigma along the heading (m).", FILTER_NOISE, min=0.0)
]
SigmaY = Annotated[float, _option("Motion noise sigma sideways (m).", FILTER_NOISE, min=0.0)]
SigmaAlpha = Annotated[
    float, _option("Motion noise sigma of the turn (rad).", FILTER_NOISE, min=0.0)
]
SigmaBearing = Annotated[
    float, _option("Measurement noise sigma of the bearing (rad); positive.", FILTER_NOISE)
]
SigmaRange = Annotated[
    float, _option("Measurement noise sigma of the range (m); positive.", FILTER_NOISE)
]
OdometryScale = Annotated[
    tuple[float, float],
    _option(
        "Systematic odometry error to take out of every control: the true distance is"
        " DISTANCE times the odometry's, the true turn TURN times its turn (plus"
        " --odometry-bias); ekfviz calibrate estimates them.",
        FILTER_NOISE,
        metavar="DISTANCE TURN",
        min=0.0,
    ),
]
OdometryBias = Annotated[
    float,
    _option(
        "Systematic turn per metre driven to add to every control (rad/m), as wheels of"
        " unequal size turn a robot; a robot standing still does not turn.",
        FILTER_NOISE,
    ),
]
LandmarkInitOption = Annotated[
    LandmarkInit,
    _option("Keep the new landmark's cross-covariances (correlated) or drop them.", FILTER_OPTIONS),
]
UpdateOption = Annotated[
    UpdateMode,
    _option("Fold a line's landmarks one after another, or all at once.", FILTER_OPTIONS),
]
InitPoseSigma = Annotated[
    Triple,
    _option(
        "Sigma of the initial pose prior, around the start pose: (0, 0, 0), the true pose of"
        " the first event of a dataset with truth, or --init-pose.",
        FILTER_OPTIONS,
        metavar="SX SY STHETA",
    ),
]
# consistency: the same option, read as the prior of the simulated start as well
ScenarioInitPoseSigma = Annotated[
    Triple | None,
    _option(
        "The prior the true start is drawn from AND the filter's initial covariance"
        " \\[default: the scenario's: classic 0.02 0.02 0.1, loop 0.01 0.01 0.005].",
        FILTER_OPTIONS,
        metavar="SX SY STHETA",
        show_default=False,
    ),
]
LogArgument = Annotated[
    Path,
    typer.Argument(
        help="A log in the classic or the extended format ('-': from standard input, as"
        " a pipe gives it), an MRCLAM dataset directory (with --robot), the Victoria Park"
        " directory or a ROS 2 bag directory (with --odom, --landmarks).",
        show_default=False,
        callback=piped_input,
    ),
]
# sweep, compare, check and calibrate: Victoria Park has no ids nor true poses
StudyLogArgument = Annotated[
    Path,
    typer.Argument(
        help="A log in the classic or the extended format ('-': from standard input), or"
        " an MRCLAM dataset directory (with --robot); the Victoria Park directory is for"
        " replay only.",
        show_default=False,
        callback=piped_input,
    ),
]
TruthOption = Annotated[
    Path | None,
    _option(
        "True landmark positions: 'x y' per line, or JSON.",
        show_default=False,
        callback=piped_input,
    ),
]
FilterOption = Annotated[
    str,
    typer.Option(
        "--filter",
        help="The filter: ekf (built-in), a registered backend, PATH.py:ClassName or"
        " package.module:ClassName (a class of the filter protocol, see the README).",
        rich_help_panel=FILTER_OPTIONS,
    ),
]
PythonOption = Annotated[
    Path | None,
    typer.Option(
        "--python",
        help="Run a user's filter under this interpreter (any Python >= 3.8 with numpy >="
        " 1.17, without ekfviz): a solution written for numpy 1 runs in its own environment.",
        rich_help_panel=USER_FILTERS,
        show_default=False,
    ),
]
FilterTimeout = Annotated[
    float,
    typer.Option(
        "--filter-timeout",
        help="Seconds one call of a user's filter may take; it is stopped after that.",
        rich_help_panel=USER_FILTERS,
        min=0.1,
    ),
]
FilterMemory = Annotated[
    int | None,
    typer.Option(
        "--filter-memory",
        help="Megabytes of address space a user's filter may take (none: no limit).",
        rich_help_panel=USER_FILTERS,
        min=64,
        show_default=False,
    ),
]
Workers = Annotated[
    int | None, _option("Processes to use \\[default: one per core].", min=1, show_default=False)
]
ExecutorOption = Annotated[
    ExecutorName,
    _option("local: processes on this machine; dask: a Dask cluster (--scheduler).", STUDY),
]
SchedulerOption = Annotated[
    str | None,
    _option(
        "The Dask scheduler's address, e.g. tcp://10.0.0.5:8786 (needs the dask extra:"
        " pip install -e '.\\[dask]' in a clone).",
        STUDY,
        metavar="ADDRESS",
        show_default=False,
    ),
]


# bounds of what a simulation is asked for: beyond them the run is not a bigger study but
# numbers that overflow (a sigma of 1e300), a Poisson draw numpy refuses, or memory
MAX_TRUE_SIGMA = 1e6
MAX_CLUTTER = 1000.0
MAX_STEPS = 10_000_000
MAX_LANDMARKS = 100_000
MAX_LAPS = 10_000


def refuse_too_long(steps: int, laps: int) -> None:
    """Refuse (one line, exit 2) a simulated run of more than :data:`MAX_STEPS` controls:
    ``--steps`` and ``--laps`` each within bounds multiply past them (memory)."""
    if steps * laps > MAX_STEPS:
        fail(f"--laps {laps} of {steps:,} controls make {steps * laps:,}, more than a simulated"
             f" run takes ({MAX_STEPS:,})")  # fmt: skip


def _true(what: str) -> Any:
    return _option(f"True {what}.", TRUE_NOISE, min=0.0, max=MAX_TRUE_SIGMA, show_default=False)


TrueSigmaX = Annotated[float | None, _true("motion noise sigma along the heading")]
TrueSigmaY = Annotated[float | None, _true("motion noise sigma sideways")]
TrueSigmaAlpha = Annotated[float | None, _true("motion noise sigma of the turn")]
TrueSigmaBearing = Annotated[float | None, _true("bearing noise sigma")]
TrueSigmaRange = Annotated[float | None, _true("range noise sigma")]
ScenarioOption = Annotated[ScenarioName, _option("The world and route.")]
Steps = Annotated[
    int | None,
    _option(
        "loop: controls in one lap \\[default: 1000].",
        LOOP,
        min=4,
        max=MAX_STEPS,
        show_default=False,
    ),
]
Landmarks = Annotated[
    int | None,
    _option(
        "loop: number of landmarks \\[default: 200].",
        LOOP,
        min=1,
        max=MAX_LANDMARKS,
        show_default=False,
    ),
]
MaxRange = Annotated[
    float | None,
    _option(
        "loop: sensor range in metres \\[default: 15].",
        LOOP,
        min=0.0,
        max=1e6,
        show_default=False,
    ),
]
Fov = Annotated[
    float | None,
    _option(
        "loop: sensor field of view in degrees \\[default: 180].",
        LOOP,
        min=0.0,
        max=360.0,
        show_default=False,
    ),
]
UnknownIds = Annotated[
    bool,
    typer.Option(
        "--unknown-ids",
        help="Write id-less 'scan' lines (extended format); the truth's scan_ids keep"
        " each measurement's landmark (null for clutter).",
        rich_help_panel=SENSOR,
    ),
]
Clutter = Annotated[
    float,
    _option(
        "Mean false alarms per scan (Poisson), uniform over the field.",
        SENSOR,
        min=0.0,
        max=MAX_CLUTTER,
        metavar="RATE",
    ),
]
DetectionProbability = Annotated[
    float,
    _option(
        "Probability of detecting a landmark in reach (0 to 1).",
        SENSOR,
        metavar="P",
        min=0.0,
        max=1.0,
    ),
]
Laps = Annotated[int, _option("Drive the route this many times.", min=1, max=MAX_LAPS)]
# sweep and compare: a study's outputs
SummaryReport = Annotated[
    Path | None, _option("Write the summary as JSON here.", show_default=False)
]


def study_save(kind: str) -> Any:
    """The ``--save`` of a study (``sweep``, ``compare``): its default file named."""
    return _option(
        f"Write the recording here \\[default: recordings/<input>-{kind}.rrd].",
        show_default=False,
    )


Seed = Annotated[int, _option("Seed of the first run; run k uses seed + k.", min=0)]


# -- reading them ---------------------------------------------------------------------------


def worker_options(
    python: Path | None,
    timeout_s: float,
    memory_mb: int | None,
    echo: bool = True,
    *,
    timeout_option: str = "--filter-timeout",
) -> Any:
    """How a user's filter runs (:class:`~ekfviz.sandbox.host.WorkerOptions`), the
    interpreter checked first.

    :param timeout_option: how the time limit was given, for the message of a bad one
    """
    from ekfviz.sandbox.host import WorkerOptions

    if math.isnan(timeout_s):
        fail(f"{timeout_option} {timeout_s}: expected a number of seconds (inf: no bound)")
    if python is not None:
        found = shutil.which(str(python))
        if found is None or not Path(found).is_file():
            fail(f"--python {python}: no such interpreter (expected a Python executable)")
        python = Path(found)
    return WorkerOptions(
        python=None if python is None else str(python),
        timeout_s=None if math.isinf(timeout_s) else timeout_s,
        memory_mb=memory_mb,
        echo=echo,
    )


def study_executor(name: ExecutorName, scheduler: str | None, workers: int | None) -> Executor:
    """The executor of ``--executor``/``--scheduler``/``--workers``, or a one-line error."""
    try:
        return make_executor(name, scheduler, workers)
    except ExecutorError as error:
        fail(str(error))


def detection_of(unknown_ids: bool, clutter: float, probability: float) -> Detection:
    """The simulated sensor's misses, false alarms and ids, refusing what cannot be."""
    if not 0.0 <= probability <= 1.0:
        fail(f"--detection-probability: {probability:g} is not between 0 and 1")
    if clutter > 0 and not unknown_ids:
        fail("--clutter: only with --unknown-ids (a log with ids names no false alarms)")
    return Detection(unknown_ids, clutter, probability)


def filter_params(
    sigmas: tuple[float, float, float, float, float],
    init_pose_sigma: Triple,
    landmark_init: LandmarkInit,
    update: UpdateMode,
    log: Path | None = None,
) -> FilterParams:
    """The filter's parameters from the command line, refusing what cannot work.

    :param log: the log replayed: the noise its source states (see
        :meth:`ekfviz.sources.Source.stated_noise`) replaces the defaults of the options
        not given on the command line, and a note says so (a log file: a directory's
        source needs its own options to open)
    """
    names = ("--sigma-x", "--sigma-y", "--sigma-alpha", "--sigma-bearing", "--sigma-range")
    for name, value in [
        *zip(names, sigmas, strict=True),
        ("--init-pose-sigma", max(init_pose_sigma)),
    ]:
        if not value <= MAX_MAGNITUDE:  # nan too
            fail(f"{name} {value:g}: expected a sigma within {RANGE_TEXT}")
    if log is not None and log.is_file():
        sigmas, init_pose_sigma = _log_noise(log, sigmas, init_pose_sigma)
    sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range = sigmas
    if sigma_bearing <= 0 or sigma_range <= 0:
        fail("--sigma-bearing and --sigma-range must be positive: R must be invertible")
    if min(init_pose_sigma) < 0:
        fail("--init-pose-sigma values must not be negative")
    return FilterParams(
        sigma_x=sigma_x,
        sigma_y=sigma_y,
        sigma_alpha=sigma_alpha,
        sigma_bearing=sigma_bearing,
        sigma_range=sigma_range,
        init_pose_sigma=init_pose_sigma,
        landmark_init=landmark_init,
        update=update,
    )


def _log_noise(
    log: Path, sigmas: tuple[float, float, float, float, float], init_pose_sigma: Triple
) -> tuple[tuple[float, float, float, float, float], Triple]:
    """The sigmas and prior with the log's stated noise where no option was given."""
    from ekfviz.io.extended import NOISE_NAMES
    from ekfviz.sources import open_source

    try:
        stated = open_source(log).stated_noise()
    except InputError as error:
        fail(str(error))
    values = dict(zip(NOISE_NAMES, sigmas, strict=True))
    used = []
    for name in NOISE_NAMES:
        value = stated.get(name)
        if isinstance(value, float) and not given(name):
            values[name] = value
            used.append(f"--{name.replace('_', '-')} {value:g}")
    prior = stated.get("init_pose_sigma")
    if isinstance(prior, tuple) and not given("init_pose_sigma"):
        init_pose_sigma = prior
        used.append("--init-pose-sigma " + " ".join(f"{v:g}" for v in prior))
    if used:
        out.print(f"{log}: the noise its header states: {' '.join(used)}", soft_wrap=True)
    sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range = (values[n] for n in NOISE_NAMES)
    return (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range), init_pose_sigma


def scenario_world(
    scenario: ScenarioName,
    seed: int,
    steps: int | None,
    landmarks: int | None,
    max_range: float | None,
    fov: float | None,
) -> Scenario:
    """The scenario asked for; the loop options are refused for the classic one."""
    from ekfviz.sim import scenarios

    options: dict[str, Any] = {
        "steps": steps, "landmarks": landmarks, "max_range": max_range, "fov_deg": fov
    }  # fmt: skip
    given = {name: value for name, value in options.items() if value is not None}
    if scenario in (ScenarioName.CLASSIC, ScenarioName.EDGE):
        if given:
            flags = (f"--{name.removesuffix('_deg').replace('_', '-')}" for name in given)
            fail(f"{', '.join(flags)}: only for --scenario loop")
        return scenarios.classic() if scenario is ScenarioName.CLASSIC else scenarios.edge()
    return scenarios.loop(seed=seed, **given)


def true_noise(world: Scenario, *given: float | None) -> Noise:
    """The scenario's own noise, with the values given on the command line instead."""
    return Noise(*(d if g is None else g for g, d in zip(given, astuple(world.noise), strict=True)))


# -- the groups ----------------------------------------------------------------------------


class OptionGroup:
    """A frozen dataclass of options that commands take whole (see the module).

    Every field is ``name: Annotated[type, typer.Option(...)] = default``; the field's
    name is the parameter's (``--sigma-x`` for ``sigma_x``).
    """

    __dataclass_fields__: ClassVar[dict[str, Any]]

    @classmethod
    def parameters(cls) -> list[inspect.Parameter]:
        """The fields as keyword parameters of a command, in their order."""
        hints = typing.get_type_hints(cls, include_extras=True)
        return [
            inspect.Parameter(
                field.name,
                inspect.Parameter.KEYWORD_ONLY,
                annotation=hints[field.name],
                default=field.default,
            )
            for field in dataclasses.fields(cls)
        ]

    @classmethod
    def option_names(cls) -> list[str]:
        """The flags of the group as a user types them (``--sigma-x``)."""
        names = []
        for parameter in cls.parameters():
            declared = next(
                (d for info in parameter.annotation.__metadata__ for d in info.param_decls or ()),
                None,
            )
            names.append(declared or "--" + parameter.name.replace("_", "-"))
        return names


def expands_options(command: Callable[..., None]) -> Callable[..., None]:
    """The command with each parameter annotated by an :class:`OptionGroup` replaced by the
    group's fields (for typer), the fields gathered back into the group at the call."""
    signature = inspect.signature(command, eval_str=True)
    flat: list[inspect.Parameter] = []
    groups: dict[str, tuple[type[OptionGroup], list[str]]] = {}
    for parameter in signature.parameters.values():
        group = parameter.annotation
        if isinstance(group, type) and issubclass(group, OptionGroup):
            fields = group.parameters()
            groups[parameter.name] = (group, [field.name for field in fields])
            flat += fields
        else:  # keyword-only: a group's defaults may come before a required option
            flat.append(parameter.replace(kind=inspect.Parameter.KEYWORD_ONLY))
    names = [parameter.name for parameter in flat]
    if len(set(names)) != len(names):
        raise TypeError(f"{command.__name__}: an option is given twice: {sorted(names)}")

    @functools.wraps(command)
    def gathered(**values: Any) -> None:
        for name, (group, fields) in groups.items():
            values[name] = group(**{field: values.pop(field) for field in fields})
        command(**values)

    gathered.__signature__ = signature.replace(parameters=flat)  # type: ignore[attr-defined]
    gathered.__annotations__ = {p.name: p.annotation for p in flat}
    gathered.__option_groups__ = {n: g for n, (g, _) in groups.items()}  # type: ignore[attr-defined]
    return gathered


@dataclass(frozen=True, slots=True)
class FilterNoise(OptionGroup):
    """The filter's motion and measurement sigmas."""

    sigma_x: SigmaX = DEFAULT.sigma_x
    sigma_y: SigmaY = DEFAULT.sigma_y
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing
    sigma_range: SigmaRange = DEFAULT.sigma_range

    @property
    def sigmas(self) -> tuple[float, float, float, float, float]:
        return (self.sigma_x, self.sigma_y, self.sigma_alpha, self.sigma_bearing, self.sigma_range)


@dataclass(frozen=True, slots=True)
class FilterForm(OptionGroup):
    """How the filter adds landmarks and folds a line's observations in."""

    landmark_init: LandmarkInitOption = DEFAULT.landmark_init
    update: UpdateOption = DEFAULT.update

    def params(
        self, noise: FilterNoise, init_pose_sigma: Triple, log: Path | None = None
    ) -> FilterParams:
        """The filter's parameters (see :func:`filter_params`)."""
        return filter_params(
            noise.sigmas, init_pose_sigma, self.landmark_init, self.update, log=log
        )


@dataclass(frozen=True, slots=True)
class UserFilter(OptionGroup):
    """How a user's filter runs: its interpreter and limits."""

    python: PythonOption = None
    filter_timeout: FilterTimeout = DEFAULT_FILTER_TIMEOUT_S
    filter_memory: FilterMemory = None

    def worker(self) -> Any:
        """The :class:`~ekfviz.sandbox.host.WorkerOptions`, the interpreter checked."""
        return worker_options(self.python, self.filter_timeout, self.filter_memory)


@dataclass(frozen=True, slots=True)
class Association(OptionGroup):
    """How id-less scans are associated with landmarks."""

    association: AssociationOption = None
    gate_probability: GateProbability = DEFAULT_ASSOCIATION.gate_probability
    confirm: Confirm = DEFAULT_ASSOCIATION.confirm
    confirm_window: ConfirmWindow = DEFAULT_ASSOCIATION.confirm_window

    def params(self) -> AssociationParams | None:
        """None for ``known``, else the method (jcbb by default) with its settings."""
        return association_params(
            self.association, self.gate_probability, self.confirm, self.confirm_window
        )

    def for_study(self, data: Path) -> AssociationParams | None:
        """As :meth:`params`, for the runs of a study of ``data`` (Victoria Park refused).

        :raises ekfviz.core.errors.InputError: for the Victoria Park directory
        """
        return study_association(
            data, self.association, self.gate_probability, self.confirm, self.confirm_window
        )


@dataclass(frozen=True, slots=True)
class Execution(OptionGroup):
    """Where the runs of a study execute."""

    workers: Workers = None
    executor: ExecutorOption = ExecutorName.LOCAL
    scheduler: SchedulerOption = None

    def make(self) -> Executor:
        """The executor asked for, or a one-line error."""
        return study_executor(self.executor, self.scheduler, self.workers)


@dataclass(frozen=True, slots=True)
class TrueNoise(OptionGroup):
    """The simulator's noise where it is not the scenario's."""

    true_sigma_x: TrueSigmaX = None
    true_sigma_y: TrueSigmaY = None
    true_sigma_alpha: TrueSigmaAlpha = None
    true_sigma_bearing: TrueSigmaBearing = None
    true_sigma_range: TrueSigmaRange = None

    @property
    def given(self) -> tuple[float | None, float | None, float | None, float | None, float | None]:
        return (
            self.true_sigma_x, self.true_sigma_y, self.true_sigma_alpha,
            self.true_sigma_bearing, self.true_sigma_range,
        )  # fmt: skip

    def of(self, world: Scenario) -> Noise:
        """The scenario's noise with the values given instead."""
        return true_noise(world, *self.given)


@dataclass(frozen=True, slots=True)
class LoopShape(OptionGroup):
    """The loop scenario's size and sensor."""

    steps: Steps = None
    landmarks: Landmarks = None
    max_range: MaxRange = None
    fov: Fov = None

    def world(self, scenario: ScenarioName, seed: int) -> Scenario:
        """The scenario asked for (the loop options refused for the others)."""
        return scenario_world(scenario, seed, self.steps, self.landmarks, self.max_range, self.fov)


@dataclass(frozen=True, slots=True)
class Sensing(OptionGroup):
    """The simulated sensor's ids, false alarms and misses."""

    unknown_ids: UnknownIds = False
    clutter: Clutter = 0.0
    detection_probability: DetectionProbability = 1.0

    def detection(self) -> Detection:
        """The detection asked for, refusing what cannot be."""
        return detection_of(self.unknown_ids, self.clutter, self.detection_probability)
