"""``ekfviz sweep``: one log replayed with filter parameters varied."""

from __future__ import annotations

import enum
import shlex
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any

import typer
from rich import box
from rich.markup import escape
from rich.progress import Progress
from rich.table import Table

from ekfviz import __version__
from ekfviz.cli.common import (
    DEFAULT,
    InitPoseSigma,
    LandmarkInitOption,
    LogArgument,
    SigmaAlpha,
    SigmaBearing,
    SigmaRange,
    SigmaX,
    SigmaY,
    TruthOption,
    UpdateOption,
    _option,
    app,
    check_outputs,
    command_hint,
    default_output,
    err,
    fail,
    filter_params,
    log_events,
    out,
    write_json,
)
from ekfviz.core.filter import FilterError
from ekfviz.io.errors import InputError
from ekfviz.io.truth import read_truth


class Preset(str, enum.Enum):
    TUNING = "tuning"


@app.command()
def sweep(
    data: LogArgument,
    truth: TruthOption = None,
    save: Annotated[
        Path | None,
        _option(
            "Write the recording here \\[default: recordings/<input>-sweep.rrd].",
            show_default=False,
        ),
    ] = None,
    report: Annotated[
        Path | None, _option("Write the summary as JSON here.", show_default=False)
    ] = None,
    vary: Annotated[
        list[str] | None,
        _option(
            "NAME=V1,V2,...: values absolute (0.5) or factors of the baseline (x10, /10);"
            " repeat to vary several.",
            metavar="NAME=VALUES",
            show_default=False,
        ),
    ] = None,
    one_at_a_time: Annotated[
        bool,
        typer.Option(
            "--one-at-a-time",
            help="Vary each --vary on its own around the baseline, not as a grid.",
        ),
    ] = False,
    preset: Annotated[
        Preset | None,
        _option(
            "tuning: each noise sigma x10 and /10, one at a time (11 variants).", show_default=False
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
    workers: Annotated[
        int | None,
        _option("Processes to use \\[default: one per core].", min=1, show_default=False),
    ] = None,
) -> None:
    """Replay one log with filter parameters varied around a baseline, side by side.

    Every variant lands in one recording under variants/<name>/ on shared timelines, so
    that scrubbing moves them all together; a table compares them.
    """
    from ekfviz import viz
    from ekfviz.sweep import (
        SweepError,
        build_variants,
        parse_vary,
        run_variants,
        summarise,
        tuning_preset,
    )
    from ekfviz.viz.sweep import record_sweep

    baseline = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range),
        init_pose_sigma,
        landmark_init,
        update,
    )
    try:
        if preset is Preset.TUNING:
            if vary:
                raise SweepError("--preset tuning and --vary: give one or the other")
            variants = tuning_preset(baseline)
        elif vary:
            variants = build_variants(
                baseline, [parse_vary(text) for text in vary], one_at_a_time=one_at_a_time
            )
        else:
            raise SweepError("nothing to vary: give --vary NAME=VALUES or --preset tuning")
    except SweepError as error:
        fail(str(error))
    check_outputs(("--save", save), ("--report", report))
    target = save if save is not None else default_output(f"{data.stem}-sweep.rrd")
    try:
        truth_xy = read_truth(truth) if truth is not None else None
        for _ in log_events(data, truth_xy, truth):
            pass  # read the whole log once here: bad input stops the sweep before any work
        with Progress(console=err, transient=True) as bar:
            task = bar.add_task(f"{len(variants)} variants", total=len(variants))
            runs = run_variants(data, variants, truth_xy, workers, done=lambda _: bar.advance(task))
        summaries = [summarise(run, runs[0]) for run in runs]
        info = viz.run_info(
            name=f"{data.stem}-sweep",
            command=shlex.join(["ekfviz", *sys.argv[1:]]),
            parameters={
                "baseline": baseline.as_dict(),
                "variants": [variant.label for variant in variants],
            },
            input_path=data,
            truth=truth_xy,
            truth_path=truth,
            kind="sweep",
        )
        table = sweep_table(summaries, truth_xy is not None)
        with viz.open_recording(info, viz.Sinks(save=target)) as recording:
            record_sweep(recording, runs, truth_xy, sweep_markdown(summaries))
    except (InputError, FilterError, viz.SinkError) as error:
        fail(str(error))
    out.print(table)
    if report is not None:
        write_json(
            report,
            {
                "ekfviz_version": __version__,
                "input": {"name": data.name, "sha256": info.input_sha256},
                "baseline": baseline.as_dict(),
                "variants": [
                    {**asdict(summary), **run.evaluation.to_json()}
                    for summary, run in zip(summaries, runs, strict=True)
                ],
            },
        )
    out.print(f"Saved {target}; open it with: {command_hint('rerun')} {target}")


def sweep_table(summaries: list[Any], has_truth: bool) -> Table:
    """The sweep's comparison table for the terminal (the report has every column)."""
    table = Table(title="Variants", title_justify="left", box=box.SIMPLE_HEAD, padding=(0, 1))
    columns = ["variant"]
    if has_truth:
        columns += ["mean err", "Mahal.", "in 3σ"]
    columns += ["Δ base", "NIS in", "reading"]
    for column in columns:
        table.add_column(column, justify="left" if column in ("variant", "reading") else "right")
    for s in summaries:
        cells = [s.label]
        if has_truth:
            inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
            cells += [_num(s.mean_error, 3), _num(s.mean_mahalanobis, 2), inside]
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        cells += [f"{s.from_baseline:.3f}", nis_inside, s.reading]
        table.add_row(*(escape(c) for c in cells))
    return table


def sweep_markdown(summaries: list[Any]) -> str:
    """The sweep's comparison table as markdown, for the recording."""
    columns = ["variant", "mean error", "max error", "mean Mahalanobis", "in 3σ", "final pose",
               "Δ baseline", "mean NIS", "NIS in 95%", "reading"]  # fmt: skip
    rows = ["# Sweep", "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for s in summaries:
        pose = ", ".join(f"{v:.3f}" for v in s.final_pose)
        inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        rows.append(
            f"| {s.label} | {_num(s.mean_error, 3)} | {_num(s.max_error, 3)} |"
            f" {_num(s.mean_mahalanobis, 2)} | {inside} | {pose} | {s.from_baseline:.3f} |"
            f" {_num(s.mean_nis, 2)} | {nis_inside} | {s.reading} |"
        )
    return "\n".join(rows) + "\n"


def _num(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
