"""``ekfviz grade``: a class's submissions checked on the battery, each in its own worker."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import (
    DEFAULT,
    ExecutorOption,
    InitPoseSigma,
    LandmarkInitOption,
    PythonOption,
    SchedulerOption,
    SigmaAlpha,
    SigmaBearing,
    SigmaRange,
    SigmaX,
    SigmaY,
    UpdateOption,
    Workers,
    _option,
    app,
    check_outputs,
    fail,
    filter_params,
    human_output_to_stderr,
    out,
    plain,
    print_json,
    study_executor,
    worker_options,
    write_bytes_atomic,
)
from ekfviz.pipeline.grade import GradeRow
from ekfviz.studies.executors import ExecutorError, ExecutorName


@app.command()
def grade(
    folder: Annotated[
        Path,
        typer.Argument(
            help="The submissions: a folder of .py files or of directories (one each).",
            show_default=False,
        ),
    ],
    logs: Annotated[
        list[Path] | None,
        typer.Option(
            "--log",
            help="Check on this log (repeat for several) \\[default: the battery: the classic"
            " sample and the edge log].",
            show_default=False,
            metavar="FILE",
        ),
    ] = None,
    timeout: Annotated[
        float, _option("Seconds one submission may take in all (its row says timeout).", min=0.1)
    ] = 60.0,
    memory: Annotated[
        int, _option("Megabytes of address space one submission may take.", min=64)
    ] = 2048,
    report: Annotated[
        Path | None,
        _option("Write the table as CSV here (grades.csv).", show_default=False),
    ] = None,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the table as JSON on stdout.")
    ] = False,
    save_dir: Annotated[
        Path | None,
        _option("Write one check recording per submission and log here.", show_default=False),
    ] = None,
    python: PythonOption = None,
    workers: Workers = None,
    executor: ExecutorOption = ExecutorName.LOCAL,
    scheduler: SchedulerOption = None,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
) -> None:
    """Check every submission of a class (check --all) and tabulate the results.

    Each submission runs in a worker of its own, with a fresh temporary working
    directory, no environment variables of the caller, an address-space limit (--memory)
    and a time limit for the whole submission (--timeout); a broken or hostile one gets
    its row (error, timeout, memory, crashed) and the others go on.
    """
    from ekfviz.pipeline.grade import GradeTask, grade_one, submissions, to_csv

    if json_output:
        human_output_to_stderr()
    if not folder.is_dir():
        fail(f"{folder}: {'no such directory' if not folder.exists() else 'not a directory'}"
             " (expected a folder of submissions)")  # fmt: skip
    check_outputs(("--report", report))
    if save_dir is not None and save_dir.exists() and not save_dir.is_dir():
        fail(f"--save-dir {save_dir}: not a directory")
    for log in logs or []:
        if not log.is_file():
            fail(f"--log {log}: no such file")
    entries = submissions(folder)
    if not entries:
        fail(f"{folder}: no submissions in it (expected .py files or directories)")
    python_text = worker_options(python, timeout, memory).python
    sigmas = (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range)
    params = filter_params(sigmas, init_pose_sigma, landmark_init, update)
    try:
        chosen = study_executor(executor, scheduler, workers)
    except ExecutorError as error:
        fail(str(error))
    if save_dir is not None:
        save_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as battery_folder:
        battery: tuple[tuple[Path, Path | None, tuple[float, float, float] | None], ...]
        if logs:
            battery = tuple((log.resolve(), None, None) for log in logs)
        else:
            from ekfviz.samples import write_battery

            battery = tuple(write_battery(Path(battery_folder)))
        tasks = [
            GradeTask(name=entry.name, path=entry.resolve(), logs=battery, params=params,
                      timeout_s=timeout, memory_mb=memory, python=python_text,
                      save_dir=None if save_dir is None else save_dir.resolve())
            for entry in entries
        ]  # fmt: skip
        try:
            rows = chosen.map(grade_one, tasks)
        except ExecutorError as error:
            fail(str(error))
    _table(rows)
    if report is not None:
        write_bytes_atomic(report, to_csv(rows).encode("utf-8"))
        out.print(plain(f"Wrote {report}"))
    if json_output:
        print_json({"submissions": [row.to_json() for row in rows]})


def _table(rows: list[GradeRow]) -> None:
    from rich.table import Table

    table = Table(title="grades", title_justify="left")
    for column in ("submission", "status", "causes", "first divergence", "s"):
        table.add_column(column, justify="right" if column == "s" else "left")
    for row in rows:
        table.add_row(plain(row.submission), plain(row.status), plain(", ".join(row.causes)),
                      plain(row.first or row.detail), plain(f"{row.seconds:.1f}"))  # fmt: skip
    out.print(table)
    counts: dict[str, int] = {}
    for row in rows:
        counts[row.status] = counts.get(row.status, 0) + 1
    out.print(plain(", ".join(f"{n} {status}" for status, n in counts.items())))
