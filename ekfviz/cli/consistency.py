"""``ekfviz consistency``: Monte-Carlo consistency of a filter on a scenario."""

from __future__ import annotations

import functools
import json
import shlex
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Annotated

from rich.progress import Progress
from rich.table import Table

from ekfviz import __version__, signals
from ekfviz.association import Method
from ekfviz.cli.common import (
    DEFAULT,
    FILTER_OPTIONS,
    Clutter,
    DetectionProbability,
    ExecutorOption,
    FilterOption,
    Fov,
    LandmarkInitOption,
    Landmarks,
    Laps,
    MaxRange,
    ScenarioOption,
    SchedulerOption,
    SigmaAlpha,
    SigmaBearing,
    SigmaRange,
    SigmaX,
    SigmaY,
    Steps,
    Triple,
    TrueSigmaAlpha,
    TrueSigmaBearing,
    TrueSigmaRange,
    TrueSigmaX,
    TrueSigmaY,
    UnknownIds,
    UpdateOption,
    _option,
    app,
    check_outputs,
    command_hint,
    detection_of,
    err,
    fail,
    filter_params,
    interrupted,
    out,
    scenario_world,
    stopped_study,
    study_executor,
    true_noise,
    write_json,
)
from ekfviz.cli.scans import (
    DEFAULT_ASSOCIATION,
    AssociationOption,
    Confirm,
    ConfirmWindow,
    GateProbability,
    association_params,
)
from ekfviz.evaluation.consistency import Verdict
from ekfviz.filters.ekf import FilterError
from ekfviz.filters.spec import BUILTIN, FilterSpecError, load_filter
from ekfviz.sim.scenarios import ScenarioName
from ekfviz.studies.executors import ExecutorError, ExecutorName


@app.command()
def consistency(
    scenario: ScenarioOption = ScenarioName.CLASSIC,
    runs: Annotated[int, _option("Number of Monte-Carlo runs.", min=1)] = 50,
    seed: Annotated[int, _option("Seed of the first run; run k uses seed + k.")] = 0,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: Annotated[
        Triple | None,
        _option(
            "The prior the true start is drawn from AND the filter's initial covariance"
            " \\[default: the scenario's: classic 0.02 0.02 0.1, loop 0.01 0.01 0.005].",
            FILTER_OPTIONS,
            metavar="SX SY STHETA",
            show_default=False,
        ),
    ] = None,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
    filter_spec: FilterOption = BUILTIN,
    true_sigma_x: TrueSigmaX = None,
    true_sigma_y: TrueSigmaY = None,
    true_sigma_alpha: TrueSigmaAlpha = None,
    true_sigma_bearing: TrueSigmaBearing = None,
    true_sigma_range: TrueSigmaRange = None,
    steps: Steps = None,
    landmarks: Landmarks = None,
    max_range: MaxRange = None,
    fov: Fov = None,
    report: Annotated[
        Path | None,
        _option("Write the averaged curves and verdict as JSON here.", show_default=False),
    ] = None,
    save: Annotated[
        Path | None, _option("Write the averaged curves to this .rrd file.", show_default=False)
    ] = None,
    workers: Annotated[
        int | None,
        _option("Processes to use \\[default: one per core].", min=1, show_default=False),
    ] = None,
    executor: ExecutorOption = ExecutorName.LOCAL,
    scheduler: SchedulerOption = None,
    unknown_ids: UnknownIds = False,
    clutter: Clutter = 0.0,
    detection_probability: DetectionProbability = 1.0,
    laps: Laps = 1,
    association: AssociationOption = None,
    gate_probability: GateProbability = DEFAULT_ASSOCIATION.gate_probability,
    confirm: Confirm = DEFAULT_ASSOCIATION.confirm,
    confirm_window: ConfirmWindow = DEFAULT_ASSOCIATION.confirm_window,
) -> None:
    """Monte-Carlo consistency: average NEES and NIS over many simulated runs, per step.

    A consistent filter keeps the averaged NEES inside its 95% chi-square bounds; above
    them it is over-confident, below them too cautious.
    """
    from ekfviz.studies.montecarlo import Trials, average, run_trial

    check_outputs(("--report", report), ("--save", save))
    world = scenario_world(scenario, seed, steps, landmarks, max_range, fov)
    prior = world.init_pose_sigma if init_pose_sigma is None else init_pose_sigma
    params = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range), prior, landmark_init, update
    )
    noise = true_noise(
        world, true_sigma_x, true_sigma_y, true_sigma_alpha, true_sigma_bearing, true_sigma_range
    )
    detection = detection_of(unknown_ids, clutter, detection_probability)
    if unknown_ids and association is Method.KNOWN:
        fail("--association known: the runs have id-less scans (--unknown-ids); use nn or jcbb")
    pairing = None
    if unknown_ids:
        pairing = association_params(association, gate_probability, confirm, confirm_window)
    elif association not in (None, Method.KNOWN):
        fail(f"--association {association.value}: the runs have landmark ids; add --unknown-ids")
    trials = Trials(
        scenario=world, true_noise=noise, init_pose_sigma=prior, params=params,
        filter=filter_spec, detection=detection, laps=laps, association=pairing,
    )  # fmt: skip
    runner = study_executor(executor, scheduler, workers)
    finished: list[None] = []

    def advance(_: object) -> None:
        finished.append(None)
        bar.advance(task)

    try:
        load_filter(filter_spec)
        with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task(f"{runs} runs of the {scenario.value} scenario", total=runs)
            results = runner.map(
                functools.partial(run_trial, trials), [seed + k for k in range(runs)], done=advance
            )
        result = average(results)
    except signals.Interrupted as stop:
        interrupted(stop, stopped_study(len(finished), runs, "runs", [save, report]))
    except (FilterSpecError, FilterError) as error:
        fail(f"--scenario {scenario.value}: {error}")
    except ExecutorError as error:
        fail(str(error))

    table = Table(title=f"Consistency over {runs} runs ({scenario.value})", title_justify="left")
    for column in ("statistic", "inside 95%", "above", "below", "verdict"):
        table.add_column(column, justify="left" if column in ("statistic", "verdict") else "right")
    for name, count in (("mean NEES per step", result.nees), ("mean NIS per step", result.nis)):
        verdict = count.verdict
        colour = {Verdict.CONSISTENT: "green", Verdict.BORDERLINE: "yellow"}.get(
            verdict or Verdict.CONSISTENT, "bold red"
        )
        table.add_row(
            name,
            f"{count.inside}/{count.total} ({count.fraction_inside:.1%})" if count.total else "-",
            str(count.above),
            str(count.below),
            "-" if verdict is None else f"[{colour}]{verdict.value}[/]",
        )
    out.print(table)
    verdict = result.nees.verdict
    if verdict is not None:
        out.print(f"The filter looks [bold]{verdict.value}[/] on this scenario (by its NEES).")
    settings = {
        "scenario": scenario.value,
        "runs": runs,
        "seed": seed,
        "filter": params.as_dict(),
        "filter_class": filter_spec,
        "true_noise": asdict(noise),
        "init_pose_sigma": list(prior),
    }
    if laps > 1:
        settings["laps"] = laps
    if unknown_ids or detection_probability < 1.0:
        settings["detection"] = asdict(detection)
    if pairing is not None:
        settings["association"] = pairing.as_dict()
    if report is not None:
        write_json(report, {"ekfviz_version": __version__, **settings, **result.to_json()})
    if save is not None:
        from ekfviz.viz.montecarlo import save_monte_carlo

        lines = [f"# Consistency: {scenario.value}, {runs} runs", ""]
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
        out.print(f"Saved {save}; open it with: {command_hint('rerun')} {save}")
