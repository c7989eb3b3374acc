"""``grade``: a class's submissions checked on the battery, each in a sandbox of its own.

:func:`grade_submissions` is the use case: the folder and the outputs checked before any
work, the battery written (or the ``--log`` files read with the noise their headers
state), every submission graded on the executor asked for (:func:`~.grade.grade_class`),
the CSV written whole as each submission's row arrives (marked partial, the rows to
come ``not graded``, until the last: a grade killed outright keeps the rows done). A grade
stopped by SIGINT or SIGTERM says what it kept; the front end prints the table and exits
as the signal asks.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from ekfviz import signals
from ekfviz.app.errors import in_family
from ekfviz.app.grade import (
    Battery,
    GradeTask,
    grade_class,
    recording_key,
    recording_names,
    sandbox_said,
    submissions,
)
from ekfviz.app.grade_rows import NOT_GRADED, GradeRow, counts, grades_table, to_csv, to_document
from ekfviz.app.reporting import Reporter
from ekfviz.app.settings import ExecutionSettings, FilterSettings, filter_params, worker_options
from ekfviz.core.errors import InputError, UsageError
from ekfviz.core.params import FilterParams
from ekfviz.core.tables import TextTable, utf8
from ekfviz.io.files import check_outputs, real_path, refuse_output_over_input, write_bytes_atomic

__all__ = ["GradeOutcome", "GradeRequest", "grade_submissions"]


@dataclass(frozen=True, slots=True)
class GradeRequest:
    """A class's grading as asked: the folder of submissions, the logs to check on (none:
    the battery), one submission's limits, the CSV report and the recordings' folder,
    the interpreter, the filter's settings and the executor.

    :param timeout: seconds one submission may take in all
    :param memory: megabytes of address space one submission may take
    :param given: the names of the options the user gave (a ``--log``'s header noise
        yields to them)
    """

    folder: Path
    logs: tuple[Path, ...] = ()
    timeout: float = 60.0
    memory: int = 2048
    report: Path | None = None
    save_dir: Path | None = None
    python: Path | None = None
    no_sandbox: bool = False
    execution: ExecutionSettings = field(default_factory=ExecutionSettings)
    filter: FilterSettings = field(default_factory=FilterSettings)
    given: frozenset[str] = frozenset()

    def was_given(self, name: str) -> bool:
        return name in self.given


@dataclass(frozen=True, slots=True)
class GradeOutcome:
    """A class graded: a row per submission in the class's order, how they ran, the CSV
    written (None: not asked for).

    :ivar stopped_by: the signal that stopped the grade (its other rows ``not graded``,
        the CSV marked partial), else None
    :ivar kept: for a stopped grade, what was graded and kept where
    """

    rows: list[GradeRow]
    sandbox: str
    report: Path | None
    stopped_by: signals.Interrupted | None = None
    kept: str = ""

    def table(self) -> TextTable:
        """The rows as the terminal shows them."""
        return grades_table(self.rows)

    def counts_line(self) -> str:
        """How many rows of each status (``2 match, 1 timeout``)."""
        return ", ".join(f"{n} {status}" for status, n in counts(self.rows).items())

    def document(self) -> dict[str, object]:
        """The rows as the JSON document of ``--json``."""
        stop = None if self.stopped_by is None else self.stopped_by.name
        return to_document(self.rows, self.sandbox, stop)


def grade_submissions(request: GradeRequest, reporter: Reporter) -> GradeOutcome:
    """Grade every submission of ``request.folder`` and write the CSV asked for.

    :raises InputError: no folder of submissions there, or none in it
    :raises UsageError: an option that cannot work (the interpreter, the sandbox, the
        executor, a sigma)
    :raises OutputError: a report that cannot be written, or would replace an input
    :raises signals.Interrupted: before any submission was graded
    """
    _check_inputs(request)
    entries = submissions(real_path(request.folder))
    if not entries:
        raise InputError(request.folder, 0, "no submissions in it (expected .py files or"
                         " directories)")  # fmt: skip
    # a submission's file or a log is never written over by the report
    refuse_output_over_input(("--report", request.report), inputs=[*request.logs, *entries])
    _refuse_report_in_a_submission(request.report, entries)
    python = worker_options(
        request.python, request.timeout, request.memory, timeout_option="--timeout"
    ).python
    sandbox = sandbox_said(python, request.no_sandbox)
    params = filter_params(request.filter)
    executor = request.execution.make()
    if request.save_dir is not None:
        request.save_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as battery_folder:
        battery = _battery(request, Path(battery_folder), reporter)
        reporter.note(f"grade: {len(entries)} submission(s) on {len(battery)} log(s), each in"
                      f" a sandbox: {sandbox}")  # fmt: skip
        save_dir = None if request.save_dir is None else real_path(request.save_dir)
        tasks = [
            GradeTask(name=utf8(entry.name), path=entry, logs=battery, params=params,
                      timeout_s=request.timeout, memory_mb=request.memory, python=python,
                      save_dir=save_dir, sandbox=not request.no_sandbox,
                      key=recording_key(os.fsencode(entry.name)), index=index)
            for index, entry in enumerate(entries)
        ]  # fmt: skip
        with in_family(), reporter.counting(f"{len(tasks)} submissions", len(tasks)) as tick:

            def arrived(rows: list[GradeRow]) -> None:
                tick()  # (a signal while the report is written: the rows kept below)
                _write_report(request.report, rows, sandbox, complete=False)

            graded = grade_class(tasks, executor.map, done=arrived)
    stop = graded.stopped_by
    with signals.held():  # a second signal now would lose what the first one kept
        _write_report(request.report, graded.rows, sandbox, complete=stop is None)
    kept = "" if stop is None else _kept(request, graded.rows, tasks)
    return GradeOutcome(graded.rows, sandbox, request.report, stop, kept)


def _write_report(report: Path | None, rows: list[GradeRow], sandbox: str, complete: bool) -> None:
    """The CSV report written whole where one was asked for (``complete``: every row
    graded, else marked partial)."""
    if report is not None:
        write_bytes_atomic(report, to_csv(rows, sandbox, complete=complete).encode("utf-8"))


def _kept(request: GradeRequest, rows: list[GradeRow], tasks: list[GradeTask]) -> str:
    """What a stopped grade kept: the submissions graded, the report, the recordings."""
    done = sum(1 for row in rows if row.status != NOT_GRADED)
    written = f"{request.report} written, marked partial; " if request.report else ""
    return (f"{done} of {len(rows)} submissions graded, the rest not graded; {written}"
            f"{_stopped(request, tasks)}")  # fmt: skip


def _stopped(request: GradeRequest, tasks: list[GradeTask]) -> str:
    """The temporary files of the recordings a stopped grade's workers were writing,
    removed; what it kept of the recordings."""
    if request.save_dir is None:
        return "no recording was asked for"
    names = {name for task in tasks for name in recording_names(task)}
    for leftover in request.save_dir.glob(".*.part"):  # a worker killed while it saved
        if any(leftover.name.startswith(f".{name}.") for name in names):
            leftover.unlink(missing_ok=True)
    return f"the recordings of the submissions checked before it are in {request.save_dir}"


def _check_inputs(request: GradeRequest) -> None:
    """The folder, the report, the recordings' folder and the logs, before any work."""
    folder, save_dir = request.folder, request.save_dir
    if not folder.is_dir():
        why = "no such directory" if not folder.exists() else "not a directory"
        raise InputError(folder, 0, f"{why} (expected a folder of submissions)")
    check_outputs(("--report", request.report))
    if save_dir is not None and save_dir.exists() and not save_dir.is_dir():
        raise UsageError(f"--save-dir {save_dir}: not a directory")
    for log in request.logs:
        if not log.is_file():
            raise UsageError(f"--log {log}: no such file")


def _battery(request: GradeRequest, folder: Path, reporter: Reporter) -> Battery:
    """The logs to check on: ``--log``, each with the noise its header states where no
    option gives it (as ``check`` of that log takes it, said to ``reporter``), else the
    battery written into ``folder``."""
    if request.logs:
        return tuple(
            (real_path(log), None, None, _log_params(request, log, reporter))
            for log in request.logs
        )
    from ekfviz.samples import write_battery

    return tuple((log, truth, start, None) for log, truth, start in write_battery(folder))


def _log_params(request: GradeRequest, log: Path, reporter: Reporter) -> FilterParams:
    """The filter's parameters on ``log``: its header's noise where no option gives it."""
    return filter_params(request.filter, log=log, given=request.was_given, note=reporter.note)


def _refuse_report_in_a_submission(report: Path | None, entries: list[Path]) -> None:
    """A report inside a submission's folder would be a file of the submission.

    :raises UsageError: naming the submission
    """
    if report is None:
        return
    where = str(real_path(report))
    for entry in entries:
        if entry.is_dir() and where.startswith(str(real_path(entry)) + os.sep):
            raise UsageError(f"--report {report}: inside the submission {utf8(entry.name)};"
                             " write it elsewhere")  # fmt: skip
