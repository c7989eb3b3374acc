"""``ekfviz simulate``: simulated runs with known truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.scenarios import MAX_TRUE_SIGMA, ScenarioName
from ekfviz.app.simulate import DEFAULT_DURATION, Layout, LogFormat, SimulateRequest, simulate
from ekfviz.cli.console import out
from ekfviz.cli.options import (
    ForceOption,
    Laps,
    LoopShape,
    ScenarioOption,
    Sensing,
    TrueNoise,
    _option,
    expands_options,
    not_nan,
)
from ekfviz.cli.program import app, given_options

OutputOption = Annotated[
    Path,
    typer.Option(
        "-o",
        "--output",
        help="Where to write the log (with --layout mrclam: the dataset directory).",
        show_default=False,
    ),
]
TruthOut = Annotated[
    Path | None,
    typer.Option(
        help="Where to write the truth (JSON: landmarks, poses); not for --layout mrclam.",
        show_default=False,
    ),
]
LayoutOption = Annotated[
    Layout,
    typer.Option(
        help="file: one log (and --truth-out); mrclam: a UTIAS MRCLAM dataset directory"
        " (robot 1, odometry at 50 Hz, camera at 5 Hz, Vicon-like truth), noise per"
        " sqrt(s) for the motion.",
    ),
]
Duration = Annotated[
    float, _option("mrclam: seconds of the run.", min=1.0, max=1e6)  # (11 days)
]
NoiseSeed = Annotated[int, _option("Seed of the noise (and of the loop's landmark field).", min=0)]
FormatOption = Annotated[
    LogFormat | None,
    typer.Option(
        "--format",
        help="Log format; default classic for classic, extended for loop.",
        show_default=False,
    ),
]
TrueInitPoseSigma = Annotated[
    tuple[float, float, float] | None,
    typer.Option(
        min=0.0,
        max=MAX_TRUE_SIGMA,
        callback=not_nan,
        metavar="SX SY STHETA",
        help="The true start is drawn from N(0, diag(sigma^2)), the prior a filter should"
        " assume \\[default: classic 0.02 0.02 0.1, loop 0.01 0.01 0.005].",
        show_default=False,
    ),
]
Precision = Annotated[int, typer.Option(min=1, max=17, help="Decimals written.")]


@app.command(name="simulate")
@expands_options
def simulate_command(
    *,
    ctx: typer.Context,
    output: OutputOption,
    truth_out: TruthOut = None,
    layout: LayoutOption = Layout.FILE,
    duration: Duration = DEFAULT_DURATION,
    scenario: ScenarioOption = ScenarioName.CLASSIC,
    seed: NoiseSeed = 0,
    log_format: FormatOption = None,
    loop: LoopShape,
    true_noise: TrueNoise,
    init_pose_sigma: TrueInitPoseSigma = None,
    precision: Precision = 6,
    sensing: Sensing,
    laps: Laps = 1,
    force: ForceOption = False,
) -> None:
    """Simulate a run with known truth and write its log and truth files (deterministic)."""
    request = SimulateRequest(
        output=output, truth_out=truth_out, layout=layout, duration=duration, scenario=scenario,
        seed=seed, log_format=log_format, loop=loop.values(), true_noise=true_noise.values(),
        init_pose_sigma=init_pose_sigma, precision=precision, sensing=sensing.values(),
        laps=laps, force=force, given=given_options(ctx),
    )  # fmt: skip
    for line in simulate(request).lines:
        out.print(line, soft_wrap=True, markup=False)
