"""What ``sweep`` and ``compare`` share: run a study, print and save its table, record it.

A sweep is a comparison of one filter under several parameter sets; both are a list of
:class:`~ekfviz.studies.runs.RunSpec` run by :func:`ekfviz.app.study`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

from rich.progress import Progress
from rich.text import Text

from ekfviz import __version__, signals
from ekfviz.cli.common import (
    check_outputs,
    default_output,
    err,
    fail,
    filter_module,
    interrupted,
    out,
    say_saved,
    show,
    stopped_study,
    warn,
    write_json,
)
from ekfviz.core.errors import FilterError, InputError
from ekfviz.filters.spec import FilterSpecError
from ekfviz.runner.replay import FilterLineError
from ekfviz.sources import OwnTruth, SourceArgs
from ekfviz.studies.executors import Executor, ExecutorError
from ekfviz.studies.runs import RunSpec, study_markdown, study_table

if TYPE_CHECKING:
    from ekfviz.app import StudyResult


def run_study(
    data: Path,
    truth: Path | None,
    specs: list[RunSpec],
    *,
    target: Path | None,
    report: Path | None,
    workers: int | None,
    root: str,
    parameters: dict[str, object],
    report_extra: dict[str, object],
    executor: Executor | None = None,
    keep_going: bool = False,
    source_args: SourceArgs | None = None,
    own_truth: OwnTruth | None = None,
    notes: Sequence[str] = (),
    inputs: Sequence[Path] = (),
) -> None:
    """Run every spec on the log, print the table, save the recording and the report.

    :param target: where to save the recording; None: ``recordings/<log>-sweep.rrd`` (or
        ``-compare``), under a new name if that one is taken
    :param own_truth: the source's own truth (a dataset's), where ``truth`` is None
    :param notes: what was chosen for the runs (the start pose), said before the table
    :param inputs: the files the log's source reads (a dataset directory's)
    """
    from ekfviz import app as pipeline
    from ekfviz import viz

    what = "variant" if root == "variants" else "filter"
    # none of them may be written over: the log (a dataset's files), the truth, the filters
    modules = [filter_module(spec.filter.text) for spec in specs]
    check_outputs(("--save", target), ("--report", report),
                  inputs=[data, truth, *inputs, *modules])  # fmt: skip
    if target is None:
        target = default_output(f"{data.stem}-{'sweep' if root == 'variants' else 'compare'}.rrd")
    finished: list[None] = []

    def advance() -> None:
        finished.append(None)
        bar.advance(task)

    try:
        with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task(f"{len(specs)} {what}s", total=len(specs))
            result = pipeline.study(
                data, truth, specs, target=target, workers=workers, root=root,
                parameters=parameters, markdown=lambda rows: study_markdown(rows, what),
                done=advance, executor=executor, keep_going=keep_going,
                source_args=source_args, warn=warn, own_truth=own_truth,
            )  # fmt: skip
    except signals.Interrupted as stop:
        interrupted(stop, stopped_study(len(finished), len(specs), f"{what}s", [target, report]))
    except FilterLineError as error:
        fail(f"{data}:{error.line}: {error}" if error.line else f"{data}: {error}")
    except (InputError, FilterError, FilterSpecError, viz.SinkError, ExecutorError) as error:
        fail(str(error))
    for note in notes:
        out.print(note, soft_wrap=True)
    _print_result(result, what)
    if report is not None:
        write_json(report, _report(data, result, what, report_extra))
    say_saved(target)


def _print_result(result: StudyResult, what: str) -> None:
    """The study's table, a note on the runs that used their own R, what stopped or failed."""
    own = {run.spec.label for run in result.runs if run.own_noise}
    failed = [failure.spec.label for failure in result.failures]
    show(study_table(result.summaries, result.truth is not None, what, own, failed))
    if own:
        out.print(
            Text(
                "* NIS derived with the filter's own R (measurement_noise): "
                + ", ".join(sorted(own))
            )
        )
    for run in result.runs:
        if run.failure:
            err.print(Text.assemble(("stopped: ", "bold red"), f"{run.spec.label}: {run.failure}"
                                    " (its events before that are recorded)"))  # fmt: skip
    for failure in result.failures:
        err.print(
            Text.assemble(("failed: ", "bold red"), f"{failure.spec.label}: {failure.message}")
        )


def _report(
    data: Path, result: StudyResult, what: str, report_extra: dict[str, object]
) -> dict[str, object]:
    """The study's JSON report: a row a run, then a row a filter that failed to start."""
    return {
        "ekfviz_version": __version__,
        "input": {"name": data.name, "sha256": result.input_sha256},
        **report_extra,
        f"{what}s": [
            {
                **asdict(summary),
                **run.evaluation.to_json(),
                "failure": run.failure,
                "own_noise": run.own_noise,
            }
            for summary, run in zip(result.summaries, result.runs, strict=True)
        ]
        + [
            {"label": f.spec.label, "filter": f.spec.filter.text, "failure": f.message}
            for f in result.failures
        ],
    }
