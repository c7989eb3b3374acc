"""``ekfviz grade``: every submission of a class checked on the battery, each apart.

A submission is a ``.py`` file or a directory holding one (a course module, or a file
with a filter class), never a symbolic link. Each is surveyed within bounds
(:mod:`ekfviz.sandbox.submission`: files, bytes, depth; none read whole before that),
then checked (``check --all``) on every log in a sandbox of its own (:mod:`ekfviz.sandbox`)
that shows it only its private copy, with an address-space limit and one deadline for the
whole submission. Whatever a submission does ends in its own row; the others go on, and a
grade stopped by a signal still writes the rows done. Rows cross from the processes that
grade them as JSON text (:mod:`.grade_rows`). Runs are spread over an executor like any
study. Numpy only (the check recording, with ``save_dir``, imports the viz layer where it
runs).
"""

from __future__ import annotations

import os
import re
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz import signals
from ekfviz.app.grade_rows import DIAGNOSIS, GradeRow, not_graded, shown
from ekfviz.check.mistakes import UNKNOWN
from ekfviz.core.params import FilterParams
from ekfviz.sandbox.submission import MAX_BYTES, Submission, SubmissionRefused, survey
from ekfviz.sandbox.text import printable

if TYPE_CHECKING:
    from ekfviz.filters.spec import FilterSpec

# how a failure's kind (WorkerFault, FilterSpecError) reads in the table
_STATUS_OF_KIND = {"timeout": "timeout", "memory": "memory", "crashed": "crashed",
                   "exit": "crashed", "start": "grader_error", "refused": "error"}  # fmt: skip
MODULE_NAMES = ("ekf_slam.py", "ekf.py", "slam.py")
# per log: (log, truth, initial pose or None, the parameters of that log or None for the
# task's: a log's header states its noise, as ``check`` of that log takes it)
Battery = tuple[
    tuple[Path, Path | None, tuple[float, float, float] | None, FilterParams | None], ...
]


@dataclass(frozen=True, slots=True)
class GradeTask:
    """One submission to check.

    :param name: how its row names it (the entry's name in the folder)
    :param path: the submission (a file or a directory), not resolved: a link is refused
    :param logs: (log, truth, initial pose or None, parameters or None) to check it on
    :param sandbox: run it in the sandbox (else ``--no-sandbox``)
    :param key: its recordings' names start with this (:func:`recording_key` of its
        entry's name: unique per submission)
    :param index: its place in the class, so that a row finds its task
    """

    name: str
    path: Path
    logs: Battery
    params: FilterParams
    timeout_s: float
    memory_mb: int | None
    python: str | None = None
    tolerance: float = 1e-6
    save_dir: Path | None = None
    sandbox: bool = True
    key: str = ""
    index: int = 0


class NoModule(Exception):
    """A submission with no Python module to check."""


def submission_of(entry: Path) -> Submission:
    """What of the caller's files a submission's sandbox shows: the file alone, or the
    directory's files."""
    if entry.is_dir() and not entry.is_symlink():
        return Submission(str(entry))
    return Submission(str(entry.parent), only=entry.name)


def module_of(entry: Path, name: str | None = None, files: tuple[str, ...] | None = None) -> Path:
    """The module a submission hands in: the file itself, or in a directory the one
    ``.py`` file, else one named like the handout's (:data:`MODULE_NAMES`), else the one
    that defines ``predict`` and ``update``.

    :param name: the submission's name in its folder, for messages
    :param files: the directory's files, as its survey found them (None: surveyed here)
    :raises NoModule: none, or several that cannot be told apart; a link; not a file
    """
    said = name or entry.name
    if entry.is_symlink():
        raise NoModule(f"{said} is a symbolic link (a submission is a file or a folder of its own)")
    if entry.is_file():
        if entry.suffix != ".py":
            raise NoModule(f"{said} is not a Python file")
        return entry
    if not entry.is_dir():  # a FIFO, a socket, a device, a link to nothing
        from ekfviz.io.text import special_kind

        try:
            kind = special_kind(entry.stat().st_mode) or "not a regular file"
        except OSError as error:
            kind = f"unreadable ({error.strerror})"
        raise NoModule(f"{said} is {kind}, expected a .py file or a directory")
    if files is None:
        try:
            files = tuple(f for f, _ in survey(Submission(str(entry))).files)
        except SubmissionRefused as error:
            raise NoModule(str(error)) from None
    found = sorted(entry / f for f in files if f.endswith(".py"))
    if not found:
        raise NoModule("no .py file in it")
    if len(found) == 1:
        return found[0]
    for handout in MODULE_NAMES:
        named = [p for p in found if p.name == handout]
        if len(named) == 1:
            return named[0]
    defining = [p for p in found if _defines_filter(p)]
    if len(defining) == 1:
        return defining[0]
    names = ", ".join(str(p.relative_to(entry)) for p in found[:5])
    raise NoModule(f"several .py files ({names}), none named ekf_slam.py")


def _lines(module: Path) -> Iterator[str]:
    """A module's lines, at most :data:`MAX_BYTES` of it read (a bigger one is refused
    before this is reached)."""
    try:
        with module.open("rb") as handle:
            text = handle.read(MAX_BYTES).decode("utf-8", "replace")
    except OSError:
        return iter(())
    return iter(text.splitlines())


def _defines_filter(path: Path) -> bool:
    """Whether a module defines ``predict`` and ``update`` at its top level (one pass)."""
    found = {line[4 : line.find("(")] for line in _lines(path) if line.startswith("def ")}
    return {"predict", "update"} <= found


_CLASS = re.compile(r"class (\w+)\b")
_DEF = re.compile(r"[ \t]+def (\w+)\(")


def spec_text(module: Path) -> str:
    """``--filter`` for a module: itself (a course module of functions, or of a class
    whose methods are the handout's functions) unless it has no ``init_landmarks`` and
    one filter class (the one class of its own ``predict``, else of its own ``update``,
    else the module's only class), then ``PATH.py:Class``.

    One pass over its lines, each matched from its start (linear in the module's size)."""
    classes: dict[str, set[str]] = {}  # top-level class -> the methods it defines
    current: str | None = None
    for line in _lines(module):
        if line.lstrip().startswith("def init_landmarks("):
            return str(module)
        if (found := _CLASS.match(line)) is not None:
            current = found[1]
            classes.setdefault(current, set())
        elif line and not line[0].isspace():
            current = None
        elif current is not None and (defined := _DEF.match(line)) is not None:
            classes[current].add(defined[1])
    # a class of its own predict, else one of its own update (its predict inherited from
    # the course's base class: ``class AliceFilter(MyFilter)``)
    for method in ("predict", "update"):
        having = [name for name, methods in classes.items() if method in methods]
        if len(having) == 1:
            return f"{module}:{having[0]}"
        if having:
            return str(module)
    # else the module's one class, whose methods are all inherited
    return f"{module}:{next(iter(classes))}" if len(classes) == 1 else str(module)


def recording_key(raw_name: bytes) -> str:
    """A file name's start for a submission's recordings, unique per entry name by
    construction: its bytes that are letters, digits, ``_`` or ``.`` as they are, every
    other byte as ``%XX`` (``a b.py`` is ``a%20b.py``; ``a_b.py`` stays). No ``-`` is
    left in it: the ``-`` before the log's name is the only one."""
    kept = b"abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_."
    key = "".join(chr(b) if b in kept else f"%{b:02X}" for b in raw_name)
    return "%2E" + key[1:] if key.startswith(".") else key  # (never a hidden file)


def log_keys(logs: Battery) -> list[str]:
    """A name per log for the recordings, unique by construction: its stem's
    :func:`recording_key`, with ``~N`` after a stem that two logs share."""
    stems = [recording_key(os.fsencode(log.stem)) for log, *_ in logs]
    return [f"{s}~{i}" if stems.count(s) > 1 else s for i, s in enumerate(stems)]


def recording_names(task: GradeTask) -> list[str]:
    """The file names of a submission's check recordings in ``--save-dir``, a log each."""
    key = task.key or recording_key(os.fsencode(task.name))
    return [f"{key}-{log}.rrd" for log in log_keys(task.logs)]


def grade_one(task: GradeTask) -> GradeRow:
    """Check one submission on every log of ``task``; never raises for what it does."""
    started = time.perf_counter()
    try:
        submission = submission_of(task.path)
        found = survey(submission, task.name)  # (bounded: before any file is read)
        files = None if submission.only else tuple(f for f, _ in found.files)
        module = module_of(task.path, task.name, files)
    except (SubmissionRefused, NoModule) as error:
        return GradeRow(task.name, "error", (), "", time.perf_counter() - started, str(error))
    if task.sandbox:
        return _checked(task, submission, module, started, None)
    # without the sandbox: a fresh working directory (whatever the code leaves in it)
    with tempfile.TemporaryDirectory(prefix="ekfviz-grade-", ignore_cleanup_errors=True) as home:
        return _checked(task, submission, module, started, home)


@dataclass
class _Verdict:
    """What the logs of one submission found so far."""

    status: str = "match"
    causes: dict[str, None] | None = None
    first: str = ""
    detail: str = ""
    any_unknown: bool = False
    diagnosis: tuple[tuple[str, str], ...] = ()

    def failed(self, status: str, detail: str) -> None:
        self.status, self.detail = status, printable(detail)


def _checked(
    task: GradeTask, submission: Submission, module: Path, started: float, home: str | None
) -> GradeRow:
    """The row of a submission found and surveyed: its check on every log."""
    from ekfviz.filters.spec import FilterSpec
    from ekfviz.sandbox.options import WorkerOptions

    verdict = _Verdict(causes={})
    deadline = time.time() + task.timeout_s
    options = WorkerOptions(python=task.python, timeout_s=task.timeout_s, memory_mb=task.memory_mb,
                            clean_env=True, cwd=home, echo=False, deadline=deadline,
                            sandbox=task.sandbox, submission=submission)  # fmt: skip
    spec = FilterSpec(spec_text(module), task.name, options)
    names = recording_names(task)
    for (log, truth, start, log_params), name in zip(task.logs, names, strict=True):
        if time.time() >= deadline:  # its time ran out on the logs before
            verdict.failed("timeout", f"its time (--timeout {task.timeout_s:g} s) ran out"
                           f" before the {log.stem} log")  # fmt: skip
            break
        params = task.params if log_params is None else log_params
        if start is not None:
            params = replace(params, init_pose=start)
        save = None if task.save_dir is None else _fresh(task.save_dir / name)
        # (a course module is not run on a log of the battery it cannot read)
        if not _check_log(verdict, spec, log, truth, params, task.tolerance, save,
                          skip_unreadable=log_params is None):  # fmt: skip
            break
    causes = verdict.causes or {}
    if verdict.any_unknown:  # last: a known mistake and more (else a correct module's row)
        causes.pop(UNKNOWN, None)
        causes[UNKNOWN] = None
    return GradeRow(task.name, verdict.status, tuple(causes), verdict.first,
                    time.perf_counter() - started, verdict.detail, str(module),
                    verdict.diagnosis)  # fmt: skip


def _fresh(path: Path) -> Path:
    """A recording's path in ``--save-dir``, a link there removed (replaced by the
    recording, never followed)."""
    if path.is_symlink():
        path.unlink()
    return path


def _check_log(
    verdict: _Verdict,
    spec: FilterSpec,
    log: Path,
    truth: Path | None,
    params: FilterParams,
    tolerance: float,
    save: Path | None,
    skip_unreadable: bool,
) -> bool:
    """Check on one log, adding to ``verdict``; whether the next log is to be checked."""
    from ekfviz.app.check import check_log
    from ekfviz.core.errors import FilterError, InputError
    from ekfviz.filters.spec import FilterSpecError

    try:
        result, _ = check_log(log, truth, spec, params, tolerance=tolerance, save=save,
                              every=True, skip_unreadable=skip_unreadable)  # fmt: skip
    except FilterSpecError as error:  # (the row names the submission: not its --filter)
        reason = str(error).removeprefix(f"--filter {spec.text}: ")
        verdict.failed(_STATUS_OF_KIND.get(error.kind, "error"), reason)
        return False
    except (InputError, FilterError) as error:
        verdict.failed(_STATUS_OF_KIND.get(str(getattr(error, "kind", "")), "error"), str(error))
        return False
    except Exception as error:  # a submission's row, whatever broke: never the class's
        verdict.failed("error", f"{type(error).__name__}: {error}")
        return False
    assert verdict.causes is not None
    for cause in result.causes:
        verdict.causes.setdefault(cause, None)
    unknown = [group for group in result.groups if group.cause == UNKNOWN]
    verdict.any_unknown = verdict.any_unknown or bool(unknown)
    if unknown and not verdict.detail:
        u = min(unknown, key=lambda group: group.first.event).first
        verdict.detail = (f"{sum(g.count for g in unknown)} divergent event(s) of no known"
                          f" cause, the first {log.stem}:{u.line} event {u.event}"
                          f" ({u.kind.value}): {u.worst.quantity.value}")  # fmt: skip
    d = result.first_divergence
    if d is not None and not verdict.first:
        verdict.first = (f"{log.stem}:{d.line} event {d.event} ({d.kind.value}):"
                         f" {d.worst.quantity.value}")  # fmt: skip
        verdict.status = "diverged"
        said = d.to_json()
        verdict.diagnosis = tuple((k, shown(said[k])) for k in DIAGNOSIS if said.get(k) is not None)
    if result.error is not None:
        verdict.failed(_STATUS_OF_KIND.get(result.error_kind, "error"),
                       f"{log.stem}:{result.error_line}: {result.error}")  # fmt: skip
        return False
    return True


def grade_json(task: GradeTask) -> str:
    """:func:`grade_one` as JSON text: what an executor's process sends back (parsed by
    :meth:`GradeRow.from_json`, never unpickled)."""
    import json

    return json.dumps({"index": task.index, "row": grade_one(task).to_json()})


@dataclass(frozen=True, slots=True)
class ClassGrade:
    """A class graded: a row per submission in the class's order; ``stopped_by`` names
    the signal that stopped it (its other rows ``not graded``), else None."""

    rows: list[GradeRow]
    stopped_by: signals.Interrupted | None = None


def grade_class(
    tasks: list[GradeTask],
    mapper: Callable[..., list[str]],
    done: Callable[[list[GradeRow]], None] | None = None,
) -> ClassGrade:
    """Grade every task through ``mapper`` (an executor's ``map``, given
    :func:`grade_json`); a signal keeps the rows done.

    :param mapper: ``mapper(function, tasks, done=..., lost=...)``; ``lost(task, why)``
        is the row of a task whose grading process died
    :param done: told every row in the class's order as each arrives (those still to
        come ``not graded``)
    """
    import json

    rows: dict[int, GradeRow] = {}

    def so_far() -> list[GradeRow]:
        return [rows.get(t.index) or not_graded(t.name) for t in tasks]

    def arrived(text: str) -> None:
        found = json.loads(text)
        rows[int(found["index"])] = GradeRow.from_json(json.dumps(found["row"]))
        if done is not None:
            done(so_far())

    def lost(task: GradeTask, why: str) -> str:
        row = GradeRow(task.name, "grader_error", (), "", 0.0, f"its grading process {why}")
        return json.dumps({"index": task.index, "row": row.to_json()})

    try:
        mapper(grade_json, tasks, done=arrived, lost=lost)
    except signals.Interrupted as stop:
        return ClassGrade(so_far(), stop)
    return ClassGrade(so_far())


def submissions(folder: Path) -> list[Path]:
    """The entries of a class folder: its ``.py`` files and its directories (and links
    to either, refused when graded), by name (hidden ones and ``__pycache__`` left out).
    Linear in the folder's entries."""
    found = []
    with os.scandir(folder) as entries:
        for entry in entries:
            if entry.name.startswith((".", "__")):
                continue
            if entry.name.endswith(".py") or entry.is_dir(follow_symlinks=False) or (
                entry.is_symlink()
            ):  # fmt: skip
                found.append(Path(entry.path))
    return sorted(found)


def sandbox_said(python: str | None, no_sandbox: bool) -> str:
    """How submissions run, for the header, the CSV and the JSON.

    :raises UsageError: the sandbox cannot start and ``no_sandbox`` is False (one line)
    """
    from ekfviz.core.errors import UsageError
    from ekfviz.sandbox import bwrap

    if no_sandbox:
        return "none (--no-sandbox): submissions run as you, with your files and network"
    try:
        return f"{bwrap.check(python)}: no network, a private copy of the submission only"
    except bwrap.SandboxUnavailable as error:
        raise UsageError(str(error)) from None
