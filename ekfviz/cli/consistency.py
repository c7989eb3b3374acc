"""``ekfviz consistency``: Monte-Carlo consistency of a filter on a scenario."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from ekfviz.app.consistency import ConsistencyRequest, consistency
from ekfviz.app.scenarios import ScenarioName
from ekfviz.app.settings import BUILTIN
from ekfviz.cli.console import TerminalReporter, out, plain, show
from ekfviz.cli.options import (
    DEFAULT,
    Association,
    Execution,
    FilterForm,
    FilterNoise,
    FilterOption,
    Laps,
    LoopShape,
    ScenarioInitPoseSigma,
    ScenarioOption,
    Seed,
    Sensing,
    TrueNoise,
    _option,
    expands_options,
)
from ekfviz.cli.program import app, command_line

Runs = Annotated[int, _option("Number of Monte-Carlo runs.", min=1)]
CurvesReport = Annotated[
    Path | None, _option("Write the averaged curves and verdict as JSON here.", show_default=False)
]
CurvesSave = Annotated[
    Path | None, _option("Write the averaged curves to this .rrd file.", show_default=False)
]


@app.command(name="consistency")
@expands_options
def consistency_command(
    *,
    scenario: ScenarioOption = ScenarioName.CLASSIC,
    runs: Runs = 50,
    seed: Seed = 0,
    noise: FilterNoise,
    init_pose_sigma: ScenarioInitPoseSigma = None,
    form: FilterForm,
    filter_spec: FilterOption = BUILTIN,
    true_noise: TrueNoise,
    loop: LoopShape,
    report: CurvesReport = None,
    save: CurvesSave = None,
    execution: Execution,
    sensing: Sensing,
    laps: Laps = 1,
    association: Association,
) -> None:
    """Monte-Carlo consistency: average NEES and NIS over many simulated runs, per step.

    A consistent filter keeps the averaged NEES inside its 95% chi-square bounds; above
    them it is over-confident, below them too cautious.
    """
    request = ConsistencyRequest(
        scenario=scenario, runs=runs, seed=seed,
        filter=form.values(noise, DEFAULT.init_pose_sigma),
        init_pose_sigma=init_pose_sigma, filter_spec=filter_spec,
        true_noise=true_noise.values(), loop=loop.values(), report=report, save=save,
        execution=execution.values(), sensing=sensing.values(), laps=laps,
        association=association.values(), command=command_line(),
    )  # fmt: skip
    outcome = consistency(request, TerminalReporter())
    # said once both are written: a reader that went away (| head) loses no file
    show(outcome.table)
    if outcome.verdict is not None:
        out.print(f"The filter looks [bold]{outcome.verdict}[/] on this scenario (by its NEES).")
    if outcome.saved is not None:
        out.print(plain(outcome.saved))
