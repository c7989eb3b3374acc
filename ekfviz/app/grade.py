"""``ekfviz grade``: every submission of a class checked on the battery, each apart.

A submission is a ``.py`` file or a directory holding one (a course module, or a file
with a filter class). Each is checked (``check --all``) on every log in a worker of its
own: a fresh temporary working directory, an environment without the caller's variables,
an address-space limit, and one deadline for the whole submission. Whatever a submission
does (a syntax error, an endless loop, a memory hog, ``sys.exit``, killing itself) ends
in its own row; the others go on. Runs are spread over an executor like any study.
Numpy only (the check recording, with ``save_dir``, imports the viz layer where it runs).
"""

from __future__ import annotations

import hashlib
import re
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

from ekfviz.check.mistakes import UNKNOWN
from ekfviz.core.params import FilterParams
from ekfviz.core.tables import Styled, TextTable, one_line, utf8
from ekfviz.io.text import special_kind

STATUSES = ("match", "diverged", "error", "timeout", "memory", "crashed")
# how a failure's kind (WorkerFault, FilterSpecError) reads in the table
_STATUS_OF_KIND = {"timeout": "timeout", "memory": "memory", "crashed": "crashed",
                   "exit": "crashed", "start": "error"}  # fmt: skip
MODULE_NAMES = ("ekf_slam.py", "ekf.py", "slam.py")
# the logs a submission is checked on: (log, truth, initial pose or None)
# per log: (log, truth, initial pose or None, the parameters of that log or None for the
# task's: a log's header states its noise, as ``check`` of that log takes it)
Battery = tuple[
    tuple[Path, Path | None, tuple[float, float, float] | None, FilterParams | None], ...
]


@dataclass(frozen=True, slots=True)
class GradeTask:
    """One submission to check.

    :param name: how its row names it (the entry's name in the folder)
    :param path: the submission (a file or a directory)
    :param logs: (log, truth, initial pose or None, parameters or None) to check it on
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


@dataclass(frozen=True, slots=True)
class GradeRow:
    """One submission's result.

    :param first: the first divergence, ``LOG:LINE event E (kind): quantity``
    :param causes: the mistakes found, ``unknown`` last where some divergence is of no
        known cause (a correct course module's row is ``independent_landmark_init`` alone:
        the handout's block-diagonal P)
    :param detail: why it failed, for ``error``, ``timeout``, ``memory``, ``crashed``; for
        ``diverged``, how many divergent events no known mistake reproduces and the first
    """

    submission: str
    status: str
    causes: tuple[str, ...]
    first: str
    seconds: float
    detail: str = ""
    module: str = ""

    def cells(self) -> tuple[Styled, ...]:
        """The row in the table of grades (no markup read in a submission's name)."""
        # a failure's reason before its first divergence, which says less
        failed = self.status not in ("match", "diverged") and self.detail
        said = self.detail if failed else "; ".join(t for t in (self.first, self.detail) if t)
        # a submission's name as one line (a file may be named with a line break)
        texts = (one_line(self.submission), self.status, ", ".join(self.causes), said,
                 f"{self.seconds:.1f}")  # fmt: skip
        return tuple(Styled(text) for text in texts)

    def to_json(self) -> dict[str, object]:
        return {
            "submission": self.submission,
            "status": self.status,
            "causes": list(self.causes),
            "first_divergence": self.first,
            "seconds": round(self.seconds, 3),
            "detail": self.detail,
            "module": self.module,
        }


def grades_table(rows: list[GradeRow]) -> TextTable:
    """The table of grades, a row a submission."""
    columns = ("submission", "status", "causes", "first divergence", "s")
    left = frozenset(columns) - {"s"}
    return TextTable("grades", columns, tuple(row.cells() for row in rows), left=left)


class NoModule(Exception):
    """A submission with no Python module to check."""


def module_of(entry: Path, name: str | None = None) -> Path:
    """The module a submission hands in: the file itself, or in a directory the one
    ``.py`` file, else one named like the handout's (:data:`MODULE_NAMES`), else the one
    that defines ``predict`` and ``update``.

    :param name: the submission's name in its folder, for messages (``entry``: maybe the
        target of its link)
    :raises NoModule: none, or several that cannot be told apart
    """
    if entry.is_file():
        if entry.suffix != ".py":
            raise NoModule(f"{name or entry.name} is not a Python file")
        return entry
    if not entry.is_dir():  # a FIFO, a socket, a device, a link to nothing
        try:
            kind = special_kind(entry.stat().st_mode) or "not a regular file"
        except OSError as error:
            kind = f"unreadable ({error.strerror})"
        raise NoModule(f"{name or entry.name} is {kind}, expected a .py file or a directory")
    files = sorted(p for p in entry.rglob("*.py") if p.is_file() and "__pycache__" not in p.parts)
    if not files:
        raise NoModule("no .py file in it")
    if len(files) == 1:
        return files[0]
    for name in MODULE_NAMES:
        named = [p for p in files if p.name == name]
        if len(named) == 1:
            return named[0]
    defining = [p for p in files if _defines_filter(p)]
    if len(defining) == 1:
        return defining[0]
    names = ", ".join(str(p.relative_to(entry)) for p in files[:5])
    raise NoModule(f"several .py files ({names}), none named ekf_slam.py")


def _defines_filter(path: Path) -> bool:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return False
    return bool(
        re.search(r"^def predict\(", text, re.M) and re.search(r"^def update\(", text, re.M)
    )


def spec_text(module: Path) -> str:
    """``--filter`` for a module: itself (a course module of functions, or of a class
    whose methods are the handout's functions) unless it has no ``init_landmarks`` and
    one filter class (the one class of its own ``predict``, else of its own ``update``,
    else the module's only class), then ``PATH.py:Class``."""
    try:
        text = module.read_text(errors="replace")
    except OSError:
        return str(module)
    if re.search(r"^\s*def init_landmarks\(", text, re.M):
        return str(module)
    bodies = _class_bodies(text)
    # a class of its own predict, else one of its own update (its predict inherited from
    # the course's base class: ``class AliceFilter(MyFilter)``)
    for method in ("predict", "update"):
        having = [c for c, body in bodies.items() if re.search(rf"^\s+def {method}\(", body, re.M)]
        if len(having) == 1:
            return f"{module}:{having[0]}"
        if having:
            return str(module)
    # else the module's one class, whose methods are all inherited (``class F(Base):
    # pass``, or only its own __init__ with other noise)
    return f"{module}:{next(iter(bodies))}" if len(bodies) == 1 else str(module)


def _class_bodies(text: str) -> dict[str, str]:
    """Each top-level class of a module's text and its body (its indented lines)."""
    pattern = r"^class (\w+)\b[^\n]*\n((?:[ \t]+[^\n]*\n|[ \t]*\n)*)"
    return {match[1]: match[2] for match in re.finditer(pattern, text, re.M)}


def recording_names(task: GradeTask) -> list[str]:
    """The file names of a submission's check recordings in ``--save-dir``, a log each."""
    return [_recording_name(task, log) for log, *_ in task.logs]


def _recording_name(task: GradeTask, log: Path) -> str:
    return f"{_safe(task.name)}-{log.stem}.rrd"


def grade_one(task: GradeTask) -> GradeRow:
    """Check one submission on every log of ``task``; never raises for what it does."""
    from ekfviz.app.check import check_log
    from ekfviz.core.errors import FilterError, InputError
    from ekfviz.filters.spec import FilterSpec, FilterSpecError
    from ekfviz.sandbox.host import WorkerOptions

    started = time.perf_counter()
    try:
        module = module_of(task.path, task.name)  # (its path: a link's target)
    except NoModule as error:
        return GradeRow(task.name, "error", (), "", 0.0, utf8(str(error)))
    causes: dict[str, None] = {}
    any_unknown = False  # some divergence no known mistake reproduces
    first = ""
    status = "match"
    detail = ""
    deadline = time.time() + task.timeout_s
    with tempfile.TemporaryDirectory(prefix="ekfviz-grade-") as home:
        options = WorkerOptions(python=task.python, timeout_s=task.timeout_s,
                                memory_mb=task.memory_mb, clean_env=True, cwd=home,
                                echo=False, deadline=deadline)  # fmt: skip
        spec = FilterSpec(spec_text(module), task.name, options)
        for log, truth, start, log_params in task.logs:
            if time.time() >= deadline:  # its time ran out on the logs before
                status = "timeout"
                detail = _one_line(f"its time (--timeout {task.timeout_s:g} s) ran out before"
                                   f" the {log.stem} log")  # fmt: skip
                break
            params = task.params if log_params is None else log_params
            if start is not None:
                params = replace(params, init_pose=start)
            save = None
            if task.save_dir is not None:
                save = task.save_dir / _recording_name(task, log)
            try:
                result, _ = check_log(log, truth, spec, params, tolerance=task.tolerance,
                                      save=save, every=True)  # fmt: skip
            except FilterSpecError as error:
                status = _STATUS_OF_KIND.get(error.kind, "error")
                detail = _one_line(str(error))
                break
            except (InputError, FilterError) as error:
                status, detail = _failure(error)
                break
            except Exception as error:  # a submission's row, whatever broke: never the class's
                status, detail = "error", _one_line(f"{type(error).__name__}: {error}")
                break
            for cause in result.causes:
                causes.setdefault(cause, None)
            unknown = [group for group in result.groups if group.cause == UNKNOWN]
            any_unknown = any_unknown or bool(unknown)
            if unknown and not detail:
                u = min(unknown, key=lambda group: group.first.event).first
                detail = (f"{sum(g.count for g in unknown)} divergent event(s) of no known"
                          f" cause, the first {log.stem}:{u.line} event {u.event}"
                          f" ({u.kind.value}): {u.worst.quantity.value}")  # fmt: skip
            if result.first_divergence is not None and not first:
                d = result.first_divergence
                first = (f"{log.stem}:{d.line} event {d.event} ({d.kind.value}):"
                         f" {d.worst.quantity.value}")  # fmt: skip
                status = "diverged"
            if result.error is not None:
                status = _STATUS_OF_KIND.get(result.error_kind, "error")
                detail = _one_line(f"{log.stem}:{result.error_line}: {result.error}")
                break
    if any_unknown:  # last: a known mistake and more (else a correct course module's row)
        causes.pop(UNKNOWN, None)
        causes[UNKNOWN] = None
    return GradeRow(task.name, status, tuple(causes), first,
                    time.perf_counter() - started, detail, utf8(str(module)))  # fmt: skip


def _failure(error: Exception) -> tuple[str, str]:
    kind = str(getattr(error, "kind", ""))
    return _STATUS_OF_KIND.get(kind, "error"), _one_line(str(error))


def _one_line(text: str) -> str:
    return utf8(" ".join(text.split())[:500])  # (a path in it may not be UTF-8)


def _safe(name: str) -> str:
    """A file name for the submission's recordings: its name where safe, else made safe
    and told apart by a digest of the name (``José.py`` and ``Josè.py`` are two students,
    ``a b.py`` and ``a_b.py`` too)."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "submission"
    if safe == name:
        return safe
    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:8]
    return f"{safe}-{digest}"


def submissions(folder: Path) -> list[Path]:
    """The entries of a class folder: its ``.py`` files and its directories, by name
    (hidden ones and ``__pycache__`` left out)."""
    return sorted(
        p
        for p in folder.iterdir()
        if not p.name.startswith((".", "__")) and (p.is_dir() or p.suffix == ".py")
    )


CSV_COLUMNS = ("submission", "status", "causes", "first_divergence", "seconds", "detail")


def to_csv(rows: list[GradeRow]) -> str:
    import csv
    import io

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in rows:
        writer.writerow(
            [row.submission, row.status, ";".join(row.causes), row.first,
             f"{row.seconds:.3f}", row.detail]
        )  # fmt: skip
    return buffer.getvalue()
