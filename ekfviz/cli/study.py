"""What ``sweep`` and ``compare`` share: run a study, print and save its table, record it.

A sweep is a comparison of one filter under several parameter sets; both are a list of
:class:`~ekfviz.studies.runs.RunSpec` run by :func:`ekfviz.pipeline.study`.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from rich import box
from rich.markup import escape
from rich.progress import Progress
from rich.table import Table
from rich.text import Text

from ekfviz import __version__, signals
from ekfviz.cli.common import (
    check_outputs,
    command_hint,
    default_output,
    err,
    fail,
    interrupted,
    out,
    stopped_study,
    write_json,
)
from ekfviz.filters.ekf import FilterError
from ekfviz.filters.spec import FilterSpecError
from ekfviz.io.errors import InputError
from ekfviz.runner.replay import FilterLineError
from ekfviz.studies.executors import Executor, ExecutorError
from ekfviz.studies.runs import RunSpec, Summary


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
) -> None:
    """Run every spec on the log, print the table, save the recording and the report.

    :param target: where to save the recording; None: ``recordings/<log>-sweep.rrd`` (or
        ``-compare``), under a new name if that one is taken
    """
    from ekfviz import pipeline, viz

    what = "variant" if root == "variants" else "filter"
    check_outputs(("--save", target), ("--report", report))
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
            )  # fmt: skip
    except signals.Interrupted as stop:
        interrupted(stop, stopped_study(len(finished), len(specs), f"{what}s", [target, report]))
    except FilterLineError as error:
        fail(f"{data}:{error.line}: {error}" if error.line else f"{data}: {error}")
    except (InputError, FilterError, FilterSpecError, viz.SinkError, ExecutorError) as error:
        fail(str(error))
    own = {run.spec.label for run in result.runs if run.own_noise}
    out.print(study_table(result.summaries, result.truth is not None, what, own))
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
    if report is not None:
        write_json(
            report,
            {
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
            },
        )
    out.print(f"Saved {target}; open it with: {command_hint('rerun')} {target}")


def study_table(
    summaries: list[Summary], has_truth: bool, what: str, own_noise: set[str] | None = None
) -> Table:
    """The study's table for the terminal (the report has every column)."""
    table = Table(
        title=f"{what.capitalize()}s", title_justify="left", box=box.SIMPLE_HEAD, padding=(0, 1)
    )
    columns = [what]
    if has_truth:
        columns += ["mean err", "worst", "aligned", "3σ axis", "Mahal.", "in 3σ"]
    columns += ["Δ base", "NIS in", "ms/step", "reading"]
    for column in columns:
        table.add_column(column, justify="left" if column in (what, "reading") else "right")
    for s in summaries:
        cells = [s.label + ("*" if own_noise and s.label in own_noise else "")]
        if has_truth:
            inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
            cells += [
                _num(s.mean_error, 3), _num(s.max_error, 3), _num(s.aligned_mean_error, 3),
                _num(s.mean_semi_major, 3), _num(s.mean_mahalanobis, 2), inside,
            ]  # fmt: skip
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        cells += [f"{s.from_baseline:.3f}", nis_inside, _num(s.ms_per_step, 3), s.reading]
        table.add_row(*(escape(c) for c in cells))
    return table


def study_markdown(summaries: list[Summary], what: str) -> str:
    """The study's table as markdown, for the recording."""
    columns = [what, "mean error", "max error", "aligned mean error", "mean 3σ semi-major",
               "mean Mahalanobis", "in 3σ", "final pose",
               "Δ baseline", "mean NIS", "NIS in 95%", "ms per step", "reading"]  # fmt: skip
    rows = [
        "# Sweep" if what == "variant" else "# Comparison",
        "",
        "| " + " | ".join(columns) + " |",
        "|" + "---|" * len(columns),
    ]
    for s in summaries:
        pose = ", ".join(f"{v:.3f}" for v in s.final_pose)
        inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        rows.append(
            f"| {s.label} | {_num(s.mean_error, 3)} | {_num(s.max_error, 3)} |"
            f" {_num(s.aligned_mean_error, 3)} | {_num(s.mean_semi_major, 3)} |"
            f" {_num(s.mean_mahalanobis, 2)} | {inside} | {pose} | {s.from_baseline:.3f} |"
            f" {_num(s.mean_nis, 2)} | {nis_inside} | {_num(s.ms_per_step, 3)} | {s.reading} |"
        )
    return "\n".join(rows) + "\n"


def _num(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
