"""``ekfviz consistency``: Monte-Carlo consistency of a filter on a scenario."""

from __future__ import annotations

import functools
import json
import shlex
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

from rich.progress import Progress

from ekfviz import __version__, signals
from ekfviz.association import Method
from ekfviz.cli.common import (
    Triple,
    _option,
    app,
    check_outputs,
    err,
    fail,
    filter_module,
    interrupted,
    out,
    say_saved,
    show,
    stopped_study,
    write_json,
    written_before,
)
from ekfviz.cli.options import (
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
    expands_options,
    refuse_too_long,
)
from ekfviz.core.errors import FilterError
from ekfviz.filters.spec import BUILTIN, FilterSpecError, load_filter
from ekfviz.sim.scenarios import ScenarioName
from ekfviz.studies.executors import ExecutorError

if TYPE_CHECKING:
    from ekfviz.studies.montecarlo import MonteCarlo, Trials


Runs = Annotated[int, _option("Number of Monte-Carlo runs.", min=1)]
CurvesReport = Annotated[
    Path | None, _option("Write the averaged curves and verdict as JSON here.", show_default=False)
]
CurvesSave = Annotated[
    Path | None, _option("Write the averaged curves to this .rrd file.", show_default=False)
]


@dataclass(frozen=True, slots=True)
class ConsistencyRequest:
    """A Monte-Carlo study as the command line asks for it."""

    scenario: ScenarioName
    runs: int
    seed: int
    noise: FilterNoise
    init_pose_sigma: Triple | None
    form: FilterForm
    filter_spec: str
    true_noise: TrueNoise
    loop: LoopShape
    report: Path | None
    save: Path | None
    execution: Execution
    sensing: Sensing
    laps: int
    association: Association


@app.command()
@expands_options
def consistency(
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
    run_consistency(
        ConsistencyRequest(
            scenario=scenario, runs=runs, seed=seed, noise=noise,
            init_pose_sigma=init_pose_sigma, form=form,
            filter_spec=filter_spec, true_noise=true_noise, loop=loop, report=report, save=save,
            execution=execution, sensing=sensing, laps=laps, association=association,
        )
    )  # fmt: skip


def run_consistency(request: ConsistencyRequest) -> None:
    """Run the trials, print the verdict, write the report and the recording."""
    check_outputs(("--report", request.report), ("--save", request.save),
                  inputs=[filter_module(request.filter_spec)])  # fmt: skip
    trials = _trials(request)
    result = _average(request, trials)
    settings = _settings(request, trials)
    written: list[Path] = []
    try:
        if request.report is not None:
            document = {"ekfviz_version": __version__, **settings, **result.to_json()}
            write_json(request.report, document)
            written.append(request.report)
        if request.save is not None:
            _save(request, result, settings)
    except signals.Interrupted as stop:  # said as it is: the report may be written already
        outputs = (request.report, request.save)
        interrupted(stop, written_before(written, [p for p in outputs if p not in written]))
    # said once both are written: a reader that went away (| head) loses no file
    show(result.table(f"Consistency over {request.runs} runs ({request.scenario.value})"))
    verdict = result.nees.verdict
    if verdict is not None:
        out.print(f"The filter looks [bold]{verdict.value}[/] on this scenario (by its NEES).")
    if request.save is not None:
        say_saved(request.save)


def _trials(request: ConsistencyRequest) -> Trials:
    """The runs' scenario, noise, filter and association, refusing what cannot be."""
    from ekfviz.studies.montecarlo import Trials

    world = request.loop.world(request.scenario, request.seed)
    prior = world.init_pose_sigma if request.init_pose_sigma is None else request.init_pose_sigma
    params = request.form.params(request.noise, prior)
    refuse_too_long(len(world.controls), request.laps)
    noise = request.true_noise.of(world)
    detection = request.sensing.detection()
    unknown_ids, association = request.sensing.unknown_ids, request.association.association
    if unknown_ids and association is Method.KNOWN:
        fail("--association known: the runs have id-less scans (--unknown-ids); use nn or jcbb")
    pairing = None
    if unknown_ids:
        pairing = request.association.params()
    elif association not in (None, Method.KNOWN):
        fail(f"--association {association.value}: the runs have landmark ids; add --unknown-ids")
    return Trials(
        scenario=world, true_noise=noise, init_pose_sigma=prior, params=params,
        filter=request.filter_spec, detection=detection, laps=request.laps, association=pairing,
    )  # fmt: skip


def _average(request: ConsistencyRequest, trials: Trials) -> MonteCarlo:
    """The trials run where asked, with a progress bar, averaged; errors in one line."""
    from ekfviz.studies.montecarlo import average, run_trial

    runner = request.execution.make()
    runs, seed, scenario = request.runs, request.seed, request.scenario
    finished: list[None] = []

    def advance(_: object) -> None:
        finished.append(None)
        bar.advance(task)

    try:
        load_filter(request.filter_spec)
        with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task(f"{runs} runs of the {scenario.value} scenario", total=runs)
            results = runner.map(
                functools.partial(run_trial, trials), [seed + k for k in range(runs)], done=advance
            )
        return average(results)
    except signals.Interrupted as stop:
        outputs = [request.save, request.report]
        interrupted(stop, stopped_study(len(finished), runs, "runs", outputs))
    except (FilterSpecError, FilterError) as error:
        fail(f"--scenario {scenario.value}: {error}")
    except ExecutorError as error:
        fail(str(error))


def _settings(request: ConsistencyRequest, trials: Trials) -> dict[str, object]:
    """What the study was, for its report and recording."""
    settings: dict[str, object] = {
        "scenario": request.scenario.value,
        "runs": request.runs,
        "seed": request.seed,
        "filter": trials.params.as_dict(),
        "filter_class": request.filter_spec,
        "true_noise": asdict(trials.true_noise),
        "init_pose_sigma": list(trials.init_pose_sigma),
    }
    if request.laps > 1:
        settings["laps"] = request.laps
    if request.sensing.unknown_ids or request.sensing.detection_probability < 1.0:
        settings["detection"] = asdict(trials.detection)
    if trials.association is not None:
        settings["association"] = trials.association.as_dict()
    return settings


def _save(request: ConsistencyRequest, result: MonteCarlo, settings: dict[str, object]) -> None:
    from ekfviz.viz.montecarlo import save_monte_carlo

    scenario, save, verdict = request.scenario, request.save, result.nees.verdict
    assert save is not None
    lines = [f"# Consistency: {scenario.value}, {request.runs} runs", ""]
    lines += [f"- **{key}** `{json.dumps(value)}`" for key, value in settings.items()]
    if verdict is not None:
        lines += ["", f"**Verdict (NEES):** {verdict.value}"]
    save_monte_carlo(
        save,
        result,
        f"consistency-{scenario.value}",
        "\n".join(lines) + "\n",
        command=shlex.join(["ekfviz", *sys.argv[1:]]),
        settings=settings,
    )
