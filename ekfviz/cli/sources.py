"""The options of the commands that open a log: every format's own (see
:func:`ekfviz.app.inputs.source_options`), the truth, the start pose, the motion-noise
model and the gate of outliers."""

from __future__ import annotations

import functools
import inspect
import typing
from collections.abc import Callable
from typing import Annotated, Any, TypeVar

import typer

from ekfviz.app.inputs import SourceArgs, SourceOption, source_options
from ekfviz.app.settings import MotionNoiseChoice
from ekfviz.cli.options import FILTER_NOISE, FILTER_OPTIONS, _option
from ekfviz.cli.program import given

__all__ = [
    "NO_SOURCE_ARGS",
    "GateOption",
    "InitPoseOption",
    "MotionNoiseChoice",
    "MotionNoiseOption",
    "NoTruthOption",
    "with_source_options",
]

NoTruthOption = Annotated[
    bool,
    typer.Option("--no-truth", help="Ignore a dataset's own ground-truth files."),
]
InitPoseOption = Annotated[
    tuple[float, float, float] | None,
    _option(
        "The filter's initial pose [default: the true pose at the first event where the"
        " log comes with a timestamped truth (MRCLAM, a bag's --truth-topic), else 0 0 0].",
        FILTER_OPTIONS,
        metavar="X Y THETA",
        show_default=False,
    ),
]
MotionNoiseOption = Annotated[
    MotionNoiseChoice,
    _option(
        "What the motion sigmas mean: per-step, Q = diag(sigma^2) per control (m, rad);"
        " per-sqrt-second, Q = diag(sigma^2) * dt for a control spanning dt seconds"
        " (m/sqrt(s), rad/sqrt(s)); auto: what the source implies, per-sqrt-second for"
        " odometry over known times (MRCLAM, ROS 2 bags), else per-step.",
        FILTER_NOISE,
    ),
]
GateOption = Annotated[
    float | None,
    _option(
        "Reject an observation of a known landmark whose NIS (2 dof, against the state"
        " before its line) exceeds this, as an outlier (13.8: the 99.9 % bound) [default:"
        " no gate].",
        FILTER_OPTIONS,
        min=0.0,
        show_default=False,
    ),
]


Command = TypeVar("Command", bound=Callable[..., Any])
NO_SOURCE_ARGS = SourceArgs()  # the default of a command's source_args (replaced)


def with_source_options(command: Command) -> Command:
    """Give a command every format's options (:func:`ekfviz.app.inputs.source_options`)
    in place of its ``source_args: SourceArgs`` parameter, which receives them.

    A new format's options so reach every command that opens a log without an edit here.
    The options of the main panel (``--robot``) stand where ``source_args`` stands; those
    of a panel of their own come last, so that their panels follow the command's own.
    """
    signature = inspect.signature(command)
    hints = typing.get_type_hints(command, include_extras=True)
    options = source_options()
    parameters: list[inspect.Parameter] = []
    last: list[inspect.Parameter] = []
    for parameter in signature.parameters.values():
        if parameter.name != "source_args":
            parameters.append(parameter.replace(annotation=hints[parameter.name]))
            continue
        for option in options:
            declared = inspect.Parameter(
                option.name, parameter.kind, default=option.default, annotation=_annotated(option)
            )
            (parameters if option.panel is None else last).append(declared)
    parameters += last

    @functools.wraps(command)
    def run(*args: Any, **kwargs: Any) -> Any:
        values = {option.name: kwargs.pop(option.name) for option in options}
        named = frozenset(name for name in values if given(name))
        return command(*args, source_args=SourceArgs(values, named), **kwargs)

    run.__signature__ = signature.replace(parameters=parameters)  # type: ignore[attr-defined]
    run.__annotations__ = {p.name: p.annotation for p in parameters} | {"return": None}
    return typing.cast(Command, run)


def _annotated(option: SourceOption) -> Any:
    """The Typer declaration of a source option."""
    extra: dict[str, Any] = {}
    if option.metavar is not None:
        extra["metavar"] = option.metavar
    if option.min is not None:
        extra["min"] = option.min
    declared = _option(option.help, option.panel, show_default=option.show_default, **extra)
    kind = option.kind if option.default is not None else option.kind | None
    return Annotated[kind, declared]
