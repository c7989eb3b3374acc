"""``ekfviz grade``: a class's submissions checked on the battery, each in its own worker."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz import signals
from ekfviz.app.grade import Battery, GradeRow, GradeTask
from ekfviz.cli.console import (
    fail,
    human_output_to_stderr,
    interrupted,
    out,
    plain,
    print_json,
    show,
)
from ekfviz.cli.options import (
    DEFAULT,
    Execution,
    FilterForm,
    FilterNoise,
    InitPoseSigma,
    PythonOption,
    Triple,
    _option,
    expands_options,
    worker_options,
)
from ekfviz.cli.program import app
from ekfviz.core.tables import utf8
from ekfviz.io.files import check_outputs, real_path, refuse_output_over_input, write_bytes_atomic
from ekfviz.studies.executors import ExecutorError

if TYPE_CHECKING:
    from ekfviz.core.params import FilterParams

Submissions = Annotated[
    Path,
    typer.Argument(
        help="The submissions: a folder of .py files or of directories (one each).",
        show_default=False,
    ),
]
LogsOption = Annotated[
    list[Path] | None,
    typer.Option(
        "--log",
        help="Check on this log (repeat for several) \\[default: the battery: the classic"
        " sample and the edge log].",
        show_default=False,
        metavar="FILE",
    ),
]
Timeout = Annotated[
    float, _option("Seconds one submission may take in all (its row says timeout).", min=0.1)
]
Memory = Annotated[int, _option("Megabytes of address space one submission may take.", min=64)]
CsvReport = Annotated[
    Path | None, _option("Write the table as CSV here (grades.csv).", show_default=False)
]
JsonOutput = Annotated[bool, typer.Option("--json", help="Print the table as JSON on stdout.")]
SaveDir = Annotated[
    Path | None,
    _option("Write one check recording per submission and log here.", show_default=False),
]


@dataclass(frozen=True, slots=True)
class GradeRequest:
    """A class's grading as the command line asks for it."""

    folder: Path
    logs: list[Path] | None
    timeout: float
    memory: int
    report: Path | None
    json_output: bool
    save_dir: Path | None
    python: Path | None
    execution: Execution
    noise: FilterNoise
    init_pose_sigma: Triple
    form: FilterForm


@app.command()
@expands_options
def grade(
    *,
    folder: Submissions,
    logs: LogsOption = None,
    timeout: Timeout = 60.0,
    memory: Memory = 2048,
    report: CsvReport = None,
    json_output: JsonOutput = False,
    save_dir: SaveDir = None,
    python: PythonOption = None,
    execution: Execution,
    noise: FilterNoise,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    form: FilterForm,
) -> None:
    """Check every submission of a class (check --all) and tabulate the results.

    Each submission runs in a worker of its own, with a fresh temporary working
    directory, no environment variables of the caller, an address-space limit (--memory)
    and a time limit for the whole submission (--timeout); a broken or hostile one gets
    its row (error, timeout, memory, crashed) and the others go on.
    """
    run_grade(
        GradeRequest(
            folder=folder, logs=logs, timeout=timeout, memory=memory, report=report,
            json_output=json_output, save_dir=save_dir, python=python, execution=execution,
            noise=noise, init_pose_sigma=init_pose_sigma, form=form,
        )
    )  # fmt: skip


def run_grade(request: GradeRequest) -> None:
    """Grade every submission, print the table, write the CSV and JSON asked for."""
    from ekfviz.app.grade import grade_one, grades_table, submissions, to_csv

    if request.json_output:
        human_output_to_stderr()
    _check_inputs(request)
    entries = submissions(request.folder)
    if not entries:
        fail(f"{request.folder}: no submissions in it (expected .py files or directories)")
    # a submission's file or a log is never written over by the report
    refuse_output_over_input(("--report", request.report), inputs=_read_files(request, entries))
    python_text = worker_options(
        request.python, request.timeout, request.memory, timeout_option="--timeout"
    ).python
    params = request.form.params(request.noise, request.init_pose_sigma)
    try:
        chosen = request.execution.make()
    except ExecutorError as error:
        fail(str(error))
    if request.save_dir is not None:
        request.save_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as battery_folder:
        battery = _battery(request, battery_folder, params)
        tasks = [
            GradeTask(name=utf8(entry.name), path=real_path(entry), logs=battery,
                      params=params, timeout_s=request.timeout, memory_mb=request.memory,
                      python=python_text,
                      save_dir=None if request.save_dir is None else real_path(request.save_dir))
            for entry in entries
        ]  # fmt: skip
        try:
            rows = chosen.map(grade_one, tasks)
        except ExecutorError as error:
            fail(str(error))
        except signals.Interrupted as stop:
            interrupted(stop, _stopped(request, tasks))
    show(grades_table(rows))
    out.print(plain(", ".join(f"{n} {status}" for status, n in _counts(rows).items())))
    if request.report is not None:
        write_bytes_atomic(request.report, to_csv(rows).encode("utf-8"))
        out.print(plain(f"Wrote {request.report}"))
    if request.json_output:
        print_json({"submissions": [row.to_json() for row in rows]})


def _stopped(request: GradeRequest, tasks: list[GradeTask]) -> str:
    """What a grade stopped by a signal kept: no report; the recordings of the submissions
    checked whole (each is written whole or not at all), the temporary files of those its
    stopped workers were writing removed."""
    if request.save_dir is None:
        return "no report was written; existing files are left as they were"
    from ekfviz.app.grade import recording_names

    names = {name for task in tasks for name in recording_names(task)}
    for leftover in request.save_dir.glob(".*.part"):  # a worker killed while it saved
        if any(leftover.name.startswith(f".{name}.") for name in names):
            leftover.unlink(missing_ok=True)
    return (
        f"no report was written; the recordings of the submissions checked before it are in"
        f" {request.save_dir}"
    )


def _check_inputs(request: GradeRequest) -> None:
    folder, save_dir = request.folder, request.save_dir
    if not folder.is_dir():
        fail(f"{folder}: {'no such directory' if not folder.exists() else 'not a directory'}"
             " (expected a folder of submissions)")  # fmt: skip
    check_outputs(("--report", request.report))
    if save_dir is not None and save_dir.exists() and not save_dir.is_dir():
        fail(f"--save-dir {save_dir}: not a directory")
    for log in request.logs or []:
        if not log.is_file():
            fail(f"--log {log}: no such file")


def _battery(request: GradeRequest, folder: str, params: FilterParams) -> Battery:
    """The logs to check on: --log, each with the noise its header states where no option
    gives it (as ``check`` of that log takes it), else the battery written into ``folder``
    (``params``)."""
    if request.logs:
        noise, prior = request.noise, request.init_pose_sigma
        return tuple(
            (real_path(log), None, None, request.form.params(noise, prior, log=log))
            for log in request.logs
        )
    from ekfviz.samples import write_battery

    return tuple((log, truth, start, None) for log, truth, start in write_battery(Path(folder)))


def _read_files(request: GradeRequest, entries: list[Path]) -> list[Path | None]:
    """The files grading reads: the submissions' (a file, or a folder's .py files) and
    the logs given."""
    files: list[Path | None] = [*(request.logs or [])]
    for entry in entries:
        if entry.is_dir():
            files += sorted(entry.rglob("*.py"))
        else:
            files.append(entry)
    return files


def _counts(rows: list[GradeRow]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for row in rows:
        counts[row.status] = counts.get(row.status, 0) + 1
    return counts
