"""``consistency``: Monte-Carlo consistency of a filter on a simulated scenario: NEES and
NIS averaged over many runs, per step, judged against their chi-square bounds."""

from __future__ import annotations

import functools
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz import __version__, signals
from ekfviz.app.errors import in_family, stopped_study, written_before
from ekfviz.app.outputs import filter_module, saved_line
from ekfviz.app.reporting import Reporter
from ekfviz.app.scenarios import (
    LoopSettings,
    ScenarioName,
    SensingSettings,
    TrueNoiseSettings,
    refuse_too_long,
)
from ekfviz.app.settings import (
    AssociationSettings,
    ExecutionSettings,
    FilterSettings,
    Method,
    Triple,
    filter_params,
)
from ekfviz.core.errors import FilterError, UsageError
from ekfviz.core.tables import TextTable
from ekfviz.filters.spec import BUILTIN, FilterSpecError, load_filter
from ekfviz.io.files import check_outputs, write_json

if TYPE_CHECKING:
    from ekfviz.studies.montecarlo import MonteCarlo, Trials


@dataclass(frozen=True, slots=True)
class ConsistencyRequest:
    """A Monte-Carlo study as asked: the scenario, how many runs from which seed, the
    filter and its settings, the true noise, the sensor, the laps, where the runs
    execute, the report and the recording.

    :param init_pose_sigma: the prior the true start is drawn from, and the filter's
        initial covariance in place of its settings' (None: the scenario's)

    :param command: the command line, as the recording tells it
    """

    scenario: ScenarioName = ScenarioName.CLASSIC
    runs: int = 50
    seed: int = 0
    filter: FilterSettings = field(default_factory=FilterSettings)
    init_pose_sigma: Triple | None = None
    filter_spec: str = BUILTIN
    true_noise: TrueNoiseSettings = field(default_factory=TrueNoiseSettings)
    loop: LoopSettings = field(default_factory=LoopSettings)
    report: Path | None = None
    save: Path | None = None
    execution: ExecutionSettings = field(default_factory=ExecutionSettings)
    sensing: SensingSettings = field(default_factory=SensingSettings)
    laps: int = 1
    association: AssociationSettings = field(default_factory=AssociationSettings)
    command: str = "ekfviz consistency"


@dataclass(frozen=True, slots=True)
class ConsistencyOutcome:
    """The averaged curves, their table, the verdict (None where no NEES could be
    judged) and the line saying where the recording is."""

    result: MonteCarlo
    table: TextTable
    verdict: str | None
    saved: str | None


def consistency(request: ConsistencyRequest, reporter: Reporter) -> ConsistencyOutcome:
    """Run the trials, average them, write the report and the recording.

    :raises Interrupted: SIGINT or SIGTERM, saying how many runs were done and what was
        written whole before it
    :raises UsageError, OutputError, FilterError: one line each
    """
    check_outputs(("--report", request.report), ("--save", request.save),
                  inputs=[filter_module(request.filter_spec)])  # fmt: skip
    trials = _trials(request)
    result = _average(request, trials, reporter)
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
        done = [*written, *(path for path in stop.written if path not in written)]
        outputs = (request.report, request.save)
        stop.kept = written_before(done, [path for path in outputs if path not in done])
        raise
    verdict = result.nees.verdict
    return ConsistencyOutcome(
        result=result,
        table=result.table(f"Consistency over {request.runs} runs ({request.scenario.value})"),
        verdict=None if verdict is None else verdict.value,
        saved=None if request.save is None else saved_line(request.save),
    )


def _trials(request: ConsistencyRequest) -> Trials:
    """The runs' scenario, noise, filter and association.

    :raises UsageError: what cannot be (an association for logs with ids, ...)
    """
    from ekfviz.studies.montecarlo import Trials

    world = request.loop.world(request.scenario, request.seed)
    prior = world.init_pose_sigma if request.init_pose_sigma is None else request.init_pose_sigma
    settings = FilterSettings(
        request.filter.sigmas, prior, request.filter.landmark_init, request.filter.update
    )
    params = filter_params(settings)
    refuse_too_long(len(world.controls), request.laps)
    noise = request.true_noise.of(world)
    detection = request.sensing.detection()
    unknown_ids, association = request.sensing.unknown_ids, request.association.association
    if unknown_ids and association is Method.KNOWN:
        raise UsageError(
            "--association known: the runs have id-less scans (--unknown-ids); use nn or jcbb"
        )
    pairing = None
    if unknown_ids:
        pairing = request.association.params()
    elif association not in (None, Method.KNOWN):
        raise UsageError(
            f"--association {association.value}: the runs have landmark ids; add --unknown-ids"
        )
    return Trials(
        scenario=world, true_noise=noise, init_pose_sigma=prior, params=params,
        filter=request.filter_spec, detection=detection, laps=request.laps, association=pairing,
    )  # fmt: skip


def _average(request: ConsistencyRequest, trials: Trials, reporter: Reporter) -> MonteCarlo:
    """The trials run where asked, progress told, averaged."""
    from ekfviz.studies.montecarlo import average, run_trial

    runner = request.execution.make()
    runs, seed, scenario = request.runs, request.seed, request.scenario
    finished: list[None] = []
    try:
        load_filter(request.filter_spec)
        with reporter.counting(f"{runs} runs of the {scenario.value} scenario", runs) as advance:

            def done(_: object) -> None:
                finished.append(None)
                advance()

            with in_family():
                results = runner.map(
                    functools.partial(run_trial, trials), [seed + k for k in range(runs)],
                    done=done,
                )  # fmt: skip
        return average(results)
    except signals.Interrupted as stop:
        stop.kept = stopped_study(len(finished), runs, "runs", [request.save, request.report])
        raise
    except (FilterSpecError, FilterError) as error:
        raise FilterError(f"--scenario {scenario.value}: {error}") from error


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
        save, result, f"consistency-{scenario.value}", "\n".join(lines) + "\n",
        command=request.command, settings=settings,
    )  # fmt: skip
