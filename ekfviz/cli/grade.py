"""``ekfviz grade``: a class's submissions checked on the battery, each in its own sandbox."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz import signals
from ekfviz.app.grade import Battery, GradeTask, sandbox_said
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
    NoSandbox,
    PythonOption,
    Triple,
    _option,
    expands_options,
    worker_options,
)
from ekfviz.cli.program import app, given
from ekfviz.core.tables import utf8
from ekfviz.io.files import (
    check_outputs,
    json_text,
    real_path,
    refuse_output_over_input,
    write_bytes_atomic,
)
from ekfviz.studies.executors import ExecutorError

if TYPE_CHECKING:
    from ekfviz.app.grade import ClassGrade
    from ekfviz.core.params import FilterParams

Submissions = Annotated[
    Path | None,
    typer.Argument(
        help="The submissions: a folder of .py files or of directories (one each); not"
        " with --gradescope, which grades --submission.",
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
GRADESCOPE = "Gradescope"
Gradescope = Annotated[
    bool,
    typer.Option(
        "--gradescope",
        help="Grade one submission in Gradescope's autograder layout and write its"
        " results.json (points from --rubric).",
        rich_help_panel=GRADESCOPE,
    ),
]
GradescopeSubmission = Annotated[
    Path | None,
    typer.Option(
        "--submission",
        help="With --gradescope: the submission's folder \\[default:"
        " $EKFVIZ_AUTOGRADER_ROOT/submission, the root /autograder].",
        rich_help_panel=GRADESCOPE,
        show_default=False,
    ),
]
GradescopeResults = Annotated[
    Path | None,
    typer.Option(
        "--results",
        help="With --gradescope: where results.json goes \\[default:"
        " $EKFVIZ_AUTOGRADER_ROOT/results/results.json].",
        rich_help_panel=GRADESCOPE,
        show_default=False,
    ),
]
Rubric = Annotated[
    Path | None,
    typer.Option(
        "--rubric",
        help="The points of each part, as TOML (examples/rubric.toml) \\[default: the"
        " sample rubric's parts].",
        rich_help_panel=GRADESCOPE,
        show_default=False,
    ),
]
GradescopeZip = Annotated[
    Path | None,
    typer.Option(
        "--gradescope-zip",
        help="Write the autograder zip Gradescope asks for (setup.sh, run_autograder, the"
        " rubric, ekfviz's source) here, and grade nothing.",
        rich_help_panel=GRADESCOPE,
        show_default=False,
        metavar="OUT.zip",
    ),
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
    no_sandbox: bool = False


@app.command()
@expands_options
def grade(
    *,
    folder: Submissions = None,
    logs: LogsOption = None,
    timeout: Timeout = 60.0,
    memory: Memory = 2048,
    report: CsvReport = None,
    json_output: JsonOutput = False,
    save_dir: SaveDir = None,
    python: PythonOption = None,
    no_sandbox: NoSandbox = False,
    execution: Execution,
    noise: FilterNoise,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    form: FilterForm,
    gradescope: Gradescope = False,
    submission: GradescopeSubmission = None,
    results: GradescopeResults = None,
    rubric: Rubric = None,
    gradescope_zip: GradescopeZip = None,
) -> None:
    """Check every submission of a class (check --all) and tabulate the results.

    Each submission runs in a sandbox of its own (bubblewrap: no network, none of your
    files but a private copy of the submission, no process left behind), with an
    address-space limit (--memory) and a time limit for the whole submission (--timeout);
    a broken or hostile one gets its row (error, timeout, memory, crashed) and the others
    go on. SIGINT or SIGTERM writes the rows done, the rest "not graded".
    """
    if gradescope_zip is not None or gradescope:
        _refuse_class_options(gradescope_zip is not None)
    if gradescope_zip is not None:
        write_autograder_zip(gradescope_zip, rubric)
        return
    if gradescope:
        run_gradescope(submission, results, rubric, python, no_sandbox)
        return
    for name in ("submission", "results", "rubric"):
        if given(name):
            fail(f"--{name} is for --gradescope (one submission in Gradescope's layout)")
    if folder is None:
        fail("grade needs the folder of submissions (or --gradescope)")
    request = (
        GradeRequest(
            folder=folder, logs=logs, timeout=timeout, memory=memory, report=report,
            json_output=json_output, save_dir=save_dir, python=python, execution=execution,
            noise=noise, init_pose_sigma=init_pose_sigma, form=form, no_sandbox=no_sandbox,
        )
    )  # fmt: skip
    try:
        run_grade(request)
    except signals.Interrupted as stop:  # before any submission was graded
        interrupted(stop, "nothing was graded; nothing was written")


# the options of a class's grade, which a rubric replaces in Gradescope's layout
CLASS_OPTIONS = ("folder", "logs", "timeout", "memory", "report", "json_output", "save_dir",
                 "workers", "executor", "scheduler")  # fmt: skip


def _refuse_class_options(zip_only: bool) -> None:
    """--gradescope and --gradescope-zip take a rubric, not a class's options (each part
    has its own log, time and memory there)."""
    used = [name for name in CLASS_OPTIONS if given(name)]
    if zip_only and given("gradescope"):
        used.append("gradescope")
    if used:
        shown = ", ".join("FOLDER" if n == "folder" else "--json" if n == "json_output" else
                          "--" + n.replace("_", "-") for n in used)  # fmt: skip
        what = "--gradescope-zip" if zip_only else "--gradescope"
        fail(f"{what} does not take {shown}: a rubric (--rubric) gives each part its log,"
             " time and memory")  # fmt: skip


def run_grade(request: GradeRequest) -> None:
    """Grade every submission, print the table, write the CSV and JSON asked for."""
    from ekfviz.app.grade import grade_class, recording_key, submissions

    if request.json_output:
        human_output_to_stderr()
    _check_inputs(request)
    folder = real_path(request.folder)
    entries = submissions(folder)
    if not entries:
        fail(f"{request.folder}: no submissions in it (expected .py files or directories)")
    # a submission's file or a log is never written over by the report
    refuse_output_over_input(("--report", request.report), inputs=_read_files(request, entries))
    _refuse_report_in_a_submission(request.report, entries)
    python_text = worker_options(
        request.python, request.timeout, request.memory, timeout_option="--timeout"
    ).python
    sandbox = sandbox_said(python_text, request.no_sandbox)
    params = request.form.params(request.noise, request.init_pose_sigma)
    try:
        chosen = request.execution.make()
    except ExecutorError as error:
        fail(str(error))
    if request.save_dir is not None:
        request.save_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as battery_folder:
        battery = _battery(request, battery_folder, params)
        out.print(plain(f"grade: {len(entries)} submission(s) on {len(battery)} log(s), each"
                        f" in a sandbox: {sandbox}"))  # fmt: skip
        tasks = [
            GradeTask(name=utf8(entry.name), path=entry, logs=battery, params=params,
                      timeout_s=request.timeout, memory_mb=request.memory, python=python_text,
                      save_dir=None if request.save_dir is None else real_path(request.save_dir),
                      sandbox=not request.no_sandbox, key=recording_key(os.fsencode(entry.name)),
                      index=index)
            for index, entry in enumerate(entries)
        ]  # fmt: skip
        try:
            graded = grade_class(tasks, chosen.map)
        except ExecutorError as error:
            fail(str(error))
    _finish(request, graded, sandbox, tasks)


def _finish(
    request: GradeRequest, graded: ClassGrade, sandbox: str, tasks: list[GradeTask]
) -> None:
    """Print the table, write the CSV and JSON; a grade stopped by a signal writes them
    too (the rows not graded said so, the files marked partial) and exits 130 or 143."""
    from ekfviz.app.grade_rows import counts, grades_table, to_csv, to_document

    stop = graded.stopped_by
    rows = graded.rows
    with signals.held():  # a second signal now would lose what the first one kept
        show(grades_table(rows))
        out.print(plain(", ".join(f"{n} {status}" for status, n in counts(rows).items())))
        if request.report is not None:
            csv = to_csv(rows, sandbox, complete=stop is None)
            write_bytes_atomic(request.report, csv.encode("utf-8"))
            out.print(plain(f"Wrote {request.report}" + (" (partial)" if stop else "")))
        if request.json_output:
            print_json(to_document(rows, sandbox, None if stop is None else stop.name))
    if stop is not None:
        kept = _stopped(request, tasks)
        done = sum(1 for row in rows if row.status != "not graded")
        written = f"{request.report} written, marked partial; " if request.report else ""
        interrupted(stop, f"{done} of {len(rows)} submissions graded, the rest not graded;"
                          f" {written}{kept}")  # fmt: skip


def _stopped(request: GradeRequest, tasks: list[GradeTask]) -> str:
    """The temporary files of the recordings a stopped grade's workers were writing,
    removed; what it kept of the recordings."""
    if request.save_dir is None:
        return "no recording was asked for"
    from ekfviz.app.grade import recording_names

    names = {name for task in tasks for name in recording_names(task)}
    for leftover in request.save_dir.glob(".*.part"):  # a worker killed while it saved
        if any(leftover.name.startswith(f".{name}.") for name in names):
            leftover.unlink(missing_ok=True)
    return f"the recordings of the submissions checked before it are in {request.save_dir}"


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


def _refuse_report_in_a_submission(report: Path | None, entries: list[Path]) -> None:
    """A report inside a submission's folder would be a file of the submission."""
    if report is None:
        return
    where = str(real_path(report))
    for entry in entries:
        if entry.is_dir() and where.startswith(str(real_path(entry)) + os.sep):
            fail(f"--report {report}: inside the submission {utf8(entry.name)}; write it"
                 " elsewhere")  # fmt: skip


def _read_files(request: GradeRequest, entries: list[Path]) -> list[Path | None]:
    """The files grading reads that an output could name: the logs given and the
    submissions' entries (a folder's files are not listed: a report inside a submission's
    folder is refused by the path check of its own)."""
    return [*(request.logs or []), *entries]


def write_autograder_zip(target: Path, rubric_path: Path | None) -> None:
    """Write the zip Gradescope asks for (see :func:`ekfviz.app.gradescope.autograder_files`)."""
    import io
    import zipfile

    from ekfviz.app.gradescope import RubricError, autograder_files, read_rubric

    check_outputs(("--gradescope-zip", target))
    try:
        from ekfviz.samples import BATTERY

        files = autograder_files(rubric_path, read_rubric(rubric_path), BATTERY)
    except RubricError as error:
        fail(str(error))
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, (content, mode) in files.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = (0o100000 | mode) << 16  # a regular file, its mode
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, content)
    write_bytes_atomic(target, buffer.getvalue())
    out.print(plain(f"Wrote {target}: upload it as the autograder of a Gradescope programming"
                    " assignment (Ubuntu 22.04 image or later)"))  # fmt: skip


def run_gradescope(
    submission: Path | None,
    results: Path | None,
    rubric_path: Path | None,
    python: Path | None,
    no_sandbox: bool,
) -> None:
    """Grade one submission in Gradescope's layout and write its results.json. Where the
    sandbox cannot start (a container without user namespaces), the submission runs
    without it, and the results' output says so."""
    from ekfviz.app.gradescope import (
        RubricError,
        autograder_root,
        grade_on_the_battery,
        gradescope_setting,
        read_rubric,
    )

    root = autograder_root()
    folder = submission if submission is not None else root / "submission"
    target = results if results is not None else root / "results" / "results.json"
    if not folder.is_dir():
        fail(f"--submission {folder}: no such directory (Gradescope's submission folder)")
    check_outputs(("--results", target))
    try:
        rubric = read_rubric(rubric_path)
    except RubricError as error:
        fail(str(error))
    python_text = worker_options(python, 60.0, None).python
    setting = gradescope_setting(python_text, no_sandbox)
    try:
        document = grade_on_the_battery(folder, rubric, setting)
    except RubricError as error:
        fail(str(error))
    write_bytes_atomic(target, json_text(document).encode("utf-8"))
    out.print(plain(f"{document['output']}\nWrote {target}"))
