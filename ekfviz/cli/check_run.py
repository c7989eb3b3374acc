"""What ``ekfviz check`` does once its options are read (and ``watch``, which checks at
every save): the filter's parameters for each log, the check, its verdict and report."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ekfviz import __version__
from ekfviz.cli.common import (
    DEBUG,
    Triple,
    _option,
    check_outputs,
    err,
    fail,
    filter_module,
    out,
    piped_input,
    plain,
    refuse_output_over_input,
    rendered,
    say,
    say_saved,
    say_user_traceback,
    show,
    warn,
    write_json,
)
from ekfviz.cli.options import FilterForm, FilterNoise, UserFilter
from ekfviz.cli.sources import NO_SOURCE_ARGS, StudyInput, study_input
from ekfviz.core.errors import FilterError, InputError
from ekfviz.core.tables import Styled, one_line
from ekfviz.filters.spec import FilterSpec, FilterSpecError
from ekfviz.runner.replay import FilterLineError
from ekfviz.samples import write_battery
from ekfviz.sources import OwnTruth, SourceArgs

if TYPE_CHECKING:
    from ekfviz.check.coverage import Item
    from ekfviz.check.lockstep import CheckResult


CheckLog = Annotated[
    Path | None,
    typer.Argument(
        help="A log in the classic or the extended format ('-': from standard input), or an"
        " MRCLAM dataset directory (with --robot) [default: the bundled battery: the classic"
        " sample and the edge log]; the Victoria Park directory is for replay only.",
        show_default=False,
        callback=piped_input,
    ),
]
EveryOption = Annotated[
    bool,
    typer.Option(
        "--all",
        help="Go on after a divergence: find the cause of every divergent event and"
        " report them grouped.",
    ),
]
Tolerance = Annotated[
    float, _option("Largest difference allowed, |got - expected| / max(1, |expected|).", min=0.0)
]


@dataclass(frozen=True, slots=True)
class CheckRequest:
    """A check as the command line asks for it."""

    data: Path | None
    filter_text: str
    every: bool
    truth: Path | None
    tolerance: float
    report: Path | None
    save: Path | None
    user: UserFilter
    init_pose: tuple[float, float, float] | None
    noise: FilterNoise
    init_pose_sigma: Triple
    form: FilterForm
    source_args: SourceArgs = NO_SOURCE_ARGS
    no_truth: bool = False


def run_check(request: CheckRequest) -> None:
    """Check the filter on the log (or the battery), print and write the verdicts; exit 1
    at a divergence, 2 for a filter that fails."""
    if not request.filter_text:
        fail("give the filter to check: --filter PATH.py (or PATH.py:ClassName)")
    data, save, every = request.data, request.save, request.every
    module = filter_module(request.filter_text)
    check_outputs(
        ("--report", request.report), ("--save", save), inputs=[data, request.truth, module]
    )
    spec = FilterSpec.parse(request.filter_text, worker=request.user.worker())
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as folder:
        battery = write_battery(Path(folder)) if data is None else []
        logs = [(data, request.truth, request.init_pose)] if data is not None else battery
        if data is None and request.truth is not None:
            fail("--truth needs a log (DATA); the battery brings its own truth")
        results: list[dict[str, Any]] = []
        diverged = failed = False
        for log, log_truth, start in logs:
            opened = prepared_input(request, log, log_truth, start)
            params = opened.params
            target = save if data is not None or save is None else per_log_path(save, log)
            result, exercised = _run(
                log, log_truth, spec, params, request.tolerance, target, every,
                request.source_args, opened.own_truth,
            )  # fmt: skip
            for note in opened.notes:  # once the filter has loaded and run
                out.print(plain(note), soft_wrap=True)
            print_verdict(log, result, exercised, every, battery=data is None)
            diverged |= result.first_divergence is not None
            failed |= result.error is not None
            results.append(log_entry(log, result, exercised, battery=data is None))
            if target is not None:
                say_saved(target)
    if request.report is not None:
        write_json(request.report, report_document(spec, params, results, battery=data is None))
    if failed:
        raise typer.Exit(2)
    if diverged:
        raise typer.Exit(1)


def prepared_input(
    request: CheckRequest,
    log: Path,
    log_truth: Path | None,
    start: tuple[float, float, float] | None,
) -> StudyInput:
    """The filter's parameters for ``log`` (the noise its header states, the start pose)
    with its source's own truth, its outputs refused where they are one of its files.

    :param start: the start pose a battery log brings, or ``--init-pose``
    """
    params = request.form.params(request.noise, request.init_pose_sigma, log=log)
    if start is not None:
        params = replace(params, init_pose=start)
    # a dataset's own truth, and the start at its true pose (per-step noise kept: a
    # course filter's predict takes no time span)
    opened = study_input(params, log, request.source_args, log_truth, request.no_truth,
                         motion_noise=False, init_pose=start, pose_option=True)  # fmt: skip
    refuse_output_over_input(("--report", request.report), ("--save", request.save),
                             inputs=opened.files)  # fmt: skip
    return opened


def per_log_path(save: Path, log: Path) -> Path:
    """Where the recording of the battery's ``log`` goes, for ``--save NAME.rrd``:
    ``NAME-classic.rrd`` beside it."""
    return save.with_name(f"{save.stem}-{log.stem}{save.suffix or '.rrd'}")


def log_entry(
    log: Path, result: CheckResult, exercised: list[Item], *, battery: bool
) -> dict[str, Any]:
    """The report's entry of one log: its name, the verdict and what the log exercised."""
    return {"log": log.stem if battery else str(log), **result.to_json(),
            "coverage": [item.to_json() for item in exercised]}  # fmt: skip


def report_document(
    spec: FilterSpec, params: Any, entries: list[dict[str, Any]], *, battery: bool
) -> dict[str, Any]:
    """The report of a check: the filter and its parameters, the log's entry (or the
    battery's, each log's and all of them together)."""
    document: dict[str, Any] = {"ekfviz_version": __version__, "filter": spec.text,
                                "parameters": params.as_dict()}  # fmt: skip
    document.update(_battery_report(entries) if battery else entries[0])
    return document


def _run(
    log: Path,
    truth: Path | None,
    spec: FilterSpec,
    params: Any,
    tolerance: float,
    save: Path | None,
    every: bool,
    source_args: SourceArgs,
    own_truth: OwnTruth | None,
) -> tuple[CheckResult, list[Item]]:
    from ekfviz import app as pipeline
    from ekfviz import viz

    try:
        return pipeline.check(
            log, truth, spec, params, tolerance=tolerance, save=save, every=every,
            source_args=source_args, warn=warn, own_truth=own_truth,
        )  # fmt: skip
    except FilterLineError as error:
        fail(f"{log}:{error.line}: {error}" if error.line else f"{log}: {error}")
    except (InputError, FilterError, FilterSpecError, viz.SinkError) as error:
        fail(str(error))  # an InputError names its file and line itself


def print_verdict(
    log: Path,
    result: CheckResult,
    exercised: list[Item],
    every: bool,
    *,
    battery: bool,
    coverage: bool = True,
) -> None:
    """The verdict on one log, as the report says it (no markup read in any name); with
    ``coverage``, what the log did not exercise."""
    name = log.stem if battery else str(log)
    if battery:
        say([(Styled("log ", "bold"), Styled(name, "bold"), Styled(f" ({log.name})"))])
    say(result.verdict_lines(name, every))
    if result.first_divergence is not None and every and result.divergences:
        show(result.groups_table())
        say(result.group_lines())
    if result.error is not None:
        err.print(rendered((Styled("error: ", "bold red"),
                            Styled(one_line(f"{name}:{result.error_line}: {result.error}")))),
                  soft_wrap=True)  # fmt: skip
        if DEBUG["traceback"]:
            say_user_traceback(result.error_traceback)
    missing = [item for item in exercised if not item.exercised]
    if missing and coverage:
        say([Styled(f"  not exercised by {name}:")])
        say([Styled(f"    - {item.untested}") for item in missing])


def _battery_report(results: list[dict[str, Any]]) -> dict[str, Any]:
    causes: dict[str, None] = {}
    divergences = []
    for entry in results:
        for cause in entry["causes"]:
            causes.setdefault(cause, None)
        divergences += [{"log": entry["log"], **group} for group in entry["divergences"]]
    coverage: dict[str, bool] = {}
    for entry in results:
        for item in entry["coverage"]:
            coverage[item["id"]] = coverage.get(item["id"], False) or bool(item["exercised"])
    return {
        "match": all(entry["match"] for entry in results),
        "logs": results,
        "divergences": divergences,
        "causes": list(causes),
        "coverage": [{"id": k, "exercised": v} for k, v in coverage.items()],
    }
