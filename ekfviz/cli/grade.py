"""``ekfviz grade``: a class's submissions checked on the battery, each in its own sandbox."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.class_grade import GradeOutcome, GradeRequest, grade_submissions
from ekfviz.app.errors import Interrupted
from ekfviz.app.session import printing_held
from ekfviz.cli.console import (
    TerminalReporter,
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
    _option,
    expands_options,
)
from ekfviz.cli.program import app, given, given_options

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


@app.command()
@expands_options
def grade(
    *,
    ctx: typer.Context,
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
        _autograder_zip(gradescope_zip, rubric)
        return
    if gradescope:
        _gradescope(submission, results, rubric, python, no_sandbox)
        return
    for name in ("submission", "results", "rubric"):
        if given(name):
            fail(f"--{name} is for --gradescope (one submission in Gradescope's layout)")
    if folder is None:
        fail("grade needs the folder of submissions (or --gradescope)")
    if json_output:  # stdout for the document; what is printed for people goes to stderr
        human_output_to_stderr()
    request = GradeRequest(
        folder=folder, logs=tuple(logs or ()), timeout=timeout, memory=memory, report=report,
        save_dir=save_dir, python=python, no_sandbox=no_sandbox, execution=execution.values(),
        filter=form.values(noise, init_pose_sigma), given=given_options(ctx),
    )  # fmt: skip
    try:
        outcome = grade_submissions(request, TerminalReporter())
    except Interrupted as stop:  # before any submission was graded
        interrupted(stop, "nothing was graded; nothing was written")
    with printing_held():  # a second signal now would cut the table short
        _print(outcome, json_output)
    if outcome.stopped_by is not None:
        interrupted(outcome.stopped_by, outcome.kept)


def _autograder_zip(path: Path, rubric: Path | None) -> None:
    """Write Gradescope's autograder zip and say how to use it."""
    from ekfviz.app.gradescope import write_autograder_zip

    write_autograder_zip(path, rubric)
    out.print(plain(f"Wrote {path}: upload it as the autograder of a Gradescope programming"
                    " assignment (Ubuntu 22.04 image or later)"))  # fmt: skip


def _print(outcome: GradeOutcome, json_output: bool) -> None:
    """The table and its counts, where the CSV went, the document with ``--json``."""
    show(outcome.table())
    out.print(plain(outcome.counts_line()))
    if outcome.report is not None:
        partial = " (partial)" if outcome.stopped_by is not None else ""
        out.print(plain(f"Wrote {outcome.report}{partial}"))
    if json_output:
        print_json(outcome.document())


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


def _gradescope(
    submission: Path | None,
    results: Path | None,
    rubric: Path | None,
    python: Path | None,
    no_sandbox: bool,
) -> None:
    """Grade one submission in Gradescope's layout, say what its results say."""
    from ekfviz.app.gradescope import GradescopeRequest, grade_in_gradescope

    graded = grade_in_gradescope(GradescopeRequest(submission, results, rubric, python, no_sandbox))
    out.print(plain(f"{graded.output}\nWrote {graded.written}"))
