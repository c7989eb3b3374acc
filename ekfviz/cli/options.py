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
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import typer

from ekfviz.app.errors import Interrupted, UsageError
from ekfviz.app.inputs import read_piped
from ekfviz.app.scenarios import (
    MAX_CLUTTER,
    MAX_LANDMARKS,
    MAX_LAPS,
    MAX_STEPS,
    MAX_TRUE_SIGMA,
    LoopSettings,
    ScenarioName,
    SensingSettings,
    TrueNoiseSettings,
)
from ekfviz.app.settings import (
    DEFAULT_ASSOCIATION,
    DEFAULT_PARAMS,
    DEFAULT_TIMEOUT_S,
    AssociationSettings,
    ExecutionSettings,
    ExecutorName,
    FilterSettings,
    LandmarkInit,
    Method,
    UpdateMode,
    WorkerOptions,
    filter_params,
    worker_options,
)
from ekfviz.app.settings import Triple as Triple  # (the option groups' own type)
from ekfviz.cli.console import fail, interrupted, note
from ekfviz.cli.program import given

DEFAULT = DEFAULT_PARAMS  # the classic defaults, stated once
FILTER_NOISE = "Filter noise"
FILTER_OPTIONS = "Filter options"
ASSOCIATION_PANEL = "Association (id-less scans)"


def _option(help: str, panel: str | None = None, **kwargs: Any) -> Any:
    if "min" in kwargs or "max" in kwargs:  # a number's range: NaN is in none
        kwargs.setdefault("callback", not_nan)
    return typer.Option(help=help, rich_help_panel=panel, **kwargs)


def not_nan(value: Any) -> Any:
    """An option's value with no NaN in it: a range (``min=0``) lets NaN through, since
    every comparison with it is false, and a NaN sigma, share or range ran without a word
    (``consistency --true-sigma-x nan`` read "consistent")."""
    values = value if isinstance(value, tuple | list) else (value,)
    if any(isinstance(v, float) and math.isnan(v) for v in values):
        raise typer.BadParameter("found nan, expected a number")
    return value


def piped_input(ctx: typer.Context, value: Path | None) -> Path | None:
    """The callback of an input's argument or option (a log, its truth): one given
    through a pipe (``-``, ``<(zcat log.gz)``) read ahead, so that it reads as a file (see
    :func:`ekfviz.app.inputs.read_piped`); one line where it cannot be, exit 2 (130 or
    143 on a signal while the pipe has not ended)."""
    if value is None:
        return None
    given_path, meta = str(value), ctx.find_root().meta
    try:
        path = read_piped(given_path, stdin_taken=meta.get("ekfviz.stdin_taken", False))
    except UsageError as error:
        fail(str(error))
    except Interrupted as stop:
        interrupted(stop, "before the piped input had ended; nothing was written")
    if given_path == "-":
        meta["ekfviz.stdin_taken"] = True
    return value if path == given_path else Path(path)


# -- the declarations --------------------------------------------------------------------

TRUE_NOISE = "True noise (default: the scenario's)"
LOOP = "Loop scenario"
SENSOR = "Detection"
USER_FILTERS = "User filters"
STUDY = "Where the runs execute"
RERUN_OUTPUT = "Rerun output"

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
NoSandbox = Annotated[
    bool,
    typer.Option(
        "--no-sandbox",
        help="Run user code without the sandbox (bubblewrap), as you, with your files and"
        " network: only for code you trust, where the sandbox cannot start.",
        rich_help_panel=USER_FILTERS,
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


AssociationOption = Annotated[
    Method | None,
    _option(
        "known: the log's ids; nn or jcbb for id-less scans"
        " [default: known for logs with ids, jcbb for logs with scans].",
        ASSOCIATION_PANEL,
        show_default=False,
    ),
]
GateProbability = Annotated[
    float,
    _option(
        "Probability of the chi-square gates (individual and joint).",
        ASSOCIATION_PANEL,
        min=0.5,
        max=0.999999,
    ),
]
Confirm = Annotated[
    int,
    _option(
        "Sightings (the first included) that confirm a new landmark.", ASSOCIATION_PANEL, min=1
    ),
]
ConfirmWindow = Annotated[
    int,
    _option("Scans from a new landmark's first in which to confirm it.", ASSOCIATION_PANEL, min=1),
]


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
ForceOption = Annotated[bool, typer.Option("--force", help="Replace an existing output file.")]


# -- reading them ---------------------------------------------------------------------------


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

    def values(self, noise: FilterNoise, init_pose_sigma: Triple) -> FilterSettings:
        """The filter's settings with its noise and prior, as the use cases take them."""
        return FilterSettings(noise.sigmas, init_pose_sigma, self.landmark_init, self.update)

    def params(self, noise: FilterNoise, init_pose_sigma: Triple, log: Path | None = None) -> Any:
        """The filter's :class:`~ekfviz.core.params.FilterParams` (see
        :func:`ekfviz.app.settings.filter_params`), a note said where ``log`` states its
        noise; one line for what cannot work."""
        try:
            return filter_params(
                self.values(noise, init_pose_sigma), log=log, given=given, note=note
            )
        except UsageError as error:
            fail(str(error))


@dataclass(frozen=True, slots=True)
class UserFilter(OptionGroup):
    """How a user's filter runs: its interpreter and limits."""

    python: PythonOption = None
    filter_timeout: FilterTimeout = DEFAULT_TIMEOUT_S
    filter_memory: FilterMemory = None
    no_sandbox: NoSandbox = False

    def worker(self) -> WorkerOptions:
        """The :class:`~ekfviz.sandbox.options.WorkerOptions`, the interpreter checked."""
        return worker_options(
            self.python, self.filter_timeout, self.filter_memory, sandbox=not self.no_sandbox
        )


@dataclass(frozen=True, slots=True)
class Association(OptionGroup):
    """How id-less scans are associated with landmarks."""

    association: AssociationOption = None
    gate_probability: GateProbability = DEFAULT_ASSOCIATION.gate_probability
    confirm: Confirm = DEFAULT_ASSOCIATION.confirm
    confirm_window: ConfirmWindow = DEFAULT_ASSOCIATION.confirm_window

    def values(self) -> AssociationSettings:
        return AssociationSettings(
            self.association, self.gate_probability, self.confirm, self.confirm_window
        )


@dataclass(frozen=True, slots=True)
class Execution(OptionGroup):
    """Where the runs of a study execute."""

    workers: Workers = None
    executor: ExecutorOption = ExecutorName.LOCAL
    scheduler: SchedulerOption = None

    def values(self) -> ExecutionSettings:
        return ExecutionSettings(self.workers, self.executor, self.scheduler)

    def make(self) -> Any:
        """The :class:`~ekfviz.studies.executors.Executor` asked for."""
        return self.values().make()


@dataclass(frozen=True, slots=True)
class TrueNoise(OptionGroup):
    """The simulator's noise where it is not the scenario's."""

    true_sigma_x: TrueSigmaX = None
    true_sigma_y: TrueSigmaY = None
    true_sigma_alpha: TrueSigmaAlpha = None
    true_sigma_bearing: TrueSigmaBearing = None
    true_sigma_range: TrueSigmaRange = None

    def values(self) -> TrueNoiseSettings:
        return TrueNoiseSettings(
            self.true_sigma_x, self.true_sigma_y, self.true_sigma_alpha,
            self.true_sigma_bearing, self.true_sigma_range,
        )  # fmt: skip


@dataclass(frozen=True, slots=True)
class LoopShape(OptionGroup):
    """The loop scenario's size and sensor."""

    steps: Steps = None
    landmarks: Landmarks = None
    max_range: MaxRange = None
    fov: Fov = None

    def values(self) -> LoopSettings:
        return LoopSettings(self.steps, self.landmarks, self.max_range, self.fov)


@dataclass(frozen=True, slots=True)
class Sensing(OptionGroup):
    """The simulated sensor's ids, false alarms and misses."""

    unknown_ids: UnknownIds = False
    clutter: Clutter = 0.0
    detection_probability: DetectionProbability = 1.0

    def values(self) -> SensingSettings:
        return SensingSettings(self.unknown_ids, self.clutter, self.detection_probability)


@dataclass(frozen=True, slots=True)
class RerunSinks(OptionGroup):
    """Where a recording goes: a file, a viewer spawned, served or connected to."""

    save: Annotated[
        Path | None,
        typer.Option(
            help="Write the recording to this .rrd file.",
            show_default=False,
            rich_help_panel=RERUN_OUTPUT,
        ),
    ] = None
    spawn: Annotated[
        bool,
        typer.Option("--spawn", help="Open the native Rerun viewer.", rich_help_panel=RERUN_OUTPUT),
    ] = False
    serve: Annotated[
        bool,
        typer.Option(
            "--serve",
            help="Serve the web viewer on localhost (see --bind) until Ctrl-C.",
            rich_help_panel=RERUN_OUTPUT,
        ),
    ] = False
    bind: Annotated[
        str | None,
        typer.Option(
            help="With --serve: the IP address to listen on \\[default: 127.0.0.1, this"
            " machine only]; 0.0.0.0 serves the recording to the whole network.",
            show_default=False,
            metavar="ADDRESS",
            rich_help_panel=RERUN_OUTPUT,
        ),
    ] = None
    connect: Annotated[
        str | None,
        typer.Option(
            help="Stream to a running viewer at this gRPC URL.",
            show_default=False,
            rich_help_panel=RERUN_OUTPUT,
        ),
    ] = None
