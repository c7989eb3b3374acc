"""``ekfviz check``: a filter in lockstep with the reference, to the first divergent event."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz import __version__
from ekfviz.cli.common import (
    DEFAULT,
    InitPoseSigma,
    LandmarkInitOption,
    SigmaAlpha,
    SigmaBearing,
    SigmaRange,
    SigmaX,
    SigmaY,
    StudyLogArgument,
    TruthOption,
    UpdateOption,
    _option,
    app,
    check_outputs,
    command_hint,
    fail,
    filter_params,
    out,
    write_json,
)
from ekfviz.core.check import DEFAULT_TOLERANCE
from ekfviz.core.filter import FilterError
from ekfviz.core.replay import FilterLineError
from ekfviz.filters import FilterSpecError
from ekfviz.io.errors import InputError


@app.command()
def check(
    data: StudyLogArgument,
    filter_spec: Annotated[
        str,
        typer.Option(
            "--filter",
            help="The filter to check: PATH.py:ClassName or package.module:ClassName.",
            show_default=False,
        ),
    ],
    truth: TruthOption = None,
    tolerance: Annotated[
        float,
        _option("Largest difference allowed, |got - expected| / max(1, |expected|).", min=0.0),
    ] = DEFAULT_TOLERANCE,
    report: Annotated[
        Path | None, _option("Write the result as JSON here.", show_default=False)
    ] = None,
    save: Annotated[
        Path | None,
        _option(
            "Write a recording of the filter and the reference side by side here.",
            show_default=False,
        ),
    ] = None,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
) -> None:
    """Check a filter against the built-in reference, event by event.

    Before every event the reference starts from the filter's own state and applies the
    same event; the results are compared by landmark id, so the first divergent event is
    where the bug is. Exit status 0 when every event matches, 1 at a divergence, 2 for
    bad input.
    """
    from ekfviz import pipeline, viz

    check_outputs(("--report", report), ("--save", save))
    params = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range),
        init_pose_sigma,
        landmark_init,
        update,
        log=data,
    )
    try:
        result = pipeline.check(data, truth, filter_spec, params, tolerance=tolerance, save=save)
    except FilterLineError as error:
        fail(f"{data}:{error.line}: {error}" if error.line else f"{data}: {error}")
    except (InputError, FilterError, FilterSpecError, viz.SinkError) as error:
        fail(str(error))  # an InputError names its file and line itself
    if report is not None:
        write_json(report, {"ekfviz_version": __version__, "filter": filter_spec,
                            "parameters": params.as_dict(), **result.to_json()})  # fmt: skip
    first = result.first_divergence
    if first is None:
        out.print(
            f"[green]match:[/] all {result.events_checked} events agree with the reference"
            f" (largest difference {result.max_difference:.3g}, tolerance {tolerance:g})",
            soft_wrap=True,
        )
    else:
        worst = first.worst
        landmark = "" if worst.landmark_id is None else f" of landmark {worst.landmark_id}"
        out.print(
            f"[bold red]divergence[/] at event {first.event} (step {first.step},"
            f" {first.kind.value}, {data}:{first.line}): the {worst.quantity.value}{landmark}"
            f" differs\n  worst entry {worst.entry}: expected {worst.expected:.9g},"
            f" got {worst.got:.9g} (difference {worst.difference:.3g}, tolerance"
            f" {tolerance:g})\n  likely cause: {first.hint}",
            soft_wrap=True,
        )
    if save is not None:
        out.print(f"Saved {save}; open it with: {command_hint('rerun')} {save}")
    if first is not None:
        raise typer.Exit(1)
