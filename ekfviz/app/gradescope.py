"""``ekfviz grade --gradescope``: one submission graded in Gradescope's autograder layout.

Gradescope runs ``run_autograder`` in a container of its own for every submission, the
student's files in ``/autograder/submission``, and reads ``/autograder/results/
results.json``: ``score``, ``execution_time``, ``output``, and ``tests``, each with
``name``, ``score``, ``max_score``, ``status`` (``passed`` or ``failed``), ``output`` and
``visibility`` (Gradescope's autograder specification). ``$EKFVIZ_AUTOGRADER_ROOT`` puts
that tree elsewhere (a test's).

Points come from a rubric (TOML; ``examples/rubric.toml`` is :data:`DEFAULT_RUBRIC`): a
part per operation (``init``: the landmarks' initialisation at the first line;
``predict``: every control, from the first line's state, no update between; ``update``:
the updates of a whole log), per battery log (``log``: every event) and ``consistency``
(NEES and NIS of a whole run against the log's truth). Each part is checked in a run of
its own with its own time limit, so one slow part never zeroes the others (predict and
update still start from the landmarks' initialisation). A part's events pass when every
divergence among them is of a cause the rubric accepts (``accept``: by default the
handout's block-diagonal P, ``landmark_cross_covariance.skipped``; a cause's short name
is taken too). :func:`grade_in_gradescope` is the use case: the submission graded and its
``results.json`` written; :func:`write_autograder_zip` writes the zip Gradescope asks for
(:func:`autograder_files`). Numpy only.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ekfviz.app.grade_rows import shown
from ekfviz.app.settings import worker_options
from ekfviz.core.errors import UsageError
from ekfviz.core.params import FilterParams
from ekfviz.io.files import check_outputs, json_text, write_bytes_atomic

ROOT_VARIABLE = "EKFVIZ_AUTOGRADER_ROOT"
KINDS = ("init", "predict", "update", "log", "consistency")
VISIBILITIES = ("hidden", "after_due_date", "after_published", "visible")
DEFAULT_RUBRIC = """\
# ekfviz grade --gradescope: the points of each part (ekfviz's own default)
[grade]
memory = 2048                            # MB of address space, each part
tolerance = 1e-6                         # the largest scaled difference that agrees
accept = ["landmark_cross_covariance.skipped"]   # causes that lose no points: the handout's P
visibility = "visible"                   # Gradescope's, for every part not saying its own

[[part]]
name = "Landmark initialisation"
kind = "init"        # the first line's landmarks
points = 10
timeout = 30         # seconds, this part alone
log = "classic"      # a battery log (classic, edge) or a log file beside the rubric

[[part]]
name = "Prediction"
kind = "predict"
points = 20
timeout = 30
log = "classic"

[[part]]
name = "Update"
kind = "update"
points = 30
timeout = 60
log = "classic"

[[part]]
name = "Battery: classic"
kind = "log"
points = 15
timeout = 60
log = "classic"

[[part]]
name = "Battery: edge (angle wrapping)"
kind = "log"
points = 15
timeout = 60
log = "edge"

[[part]]
name = "Consistency (NEES and NIS)"
kind = "consistency"
points = 10
timeout = 60
log = "classic"
"""


class RubricError(UsageError):
    """A rubric that cannot be used; one line naming the file and what was expected."""


@dataclass(frozen=True, slots=True)
class Part:
    """One graded part: ``points`` when its events pass, else none."""

    name: str
    kind: str
    points: float
    timeout_s: float
    log: str
    visibility: str


@dataclass(frozen=True, slots=True)
class Rubric:
    """The parts and how they are judged; ``folder``: where a part's log file is found."""

    parts: tuple[Part, ...]
    accept: tuple[str, ...]
    memory_mb: int
    tolerance: float
    folder: Path


def read_rubric(path: Path | None) -> Rubric:
    """The rubric at ``path`` (None: :data:`DEFAULT_RUBRIC`).

    :raises RubricError: not TOML, or a field missing or of the wrong kind
    """
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover (Python 3.10)
        import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]
    where = "the default rubric" if path is None else str(path)
    try:
        text = DEFAULT_RUBRIC if path is None else path.read_text(encoding="utf-8")
        found = tomllib.loads(text)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as error:
        raise RubricError(f"--rubric {where}: cannot be read as TOML ({error})") from None
    head = found.get("grade", {})
    parts = found.get("part")
    if not isinstance(head, dict) or not isinstance(parts, list) or not parts:
        raise RubricError(f"--rubric {where}: expected a [grade] table and [[part]] tables")
    visibility = _field(head, "visibility", str, "visible", where, "[grade]")
    memory = _field(head, "memory", int, 2048, where, "[grade]")
    tolerance = float(_field(head, "tolerance", (int, float), 1e-6, where, "[grade]"))
    accept = _field(head, "accept", list, ["landmark_cross_covariance.skipped"], where, "[grade]")
    if visibility not in VISIBILITIES or memory < 64 or not tolerance > 0:
        raise RubricError(f"--rubric {where}: [grade] expects visibility one of"
                          f" {', '.join(VISIBILITIES)}, memory >= 64, tolerance > 0")  # fmt: skip
    read = tuple(_part(part, index, where, visibility) for index, part in enumerate(parts))
    folder = Path(".") if path is None else path.resolve().parent
    return Rubric(read, _causes(accept, where), memory, tolerance, folder)


def _causes(accept: list[Any], where: str) -> tuple[str, ...]:
    """The rubric's accepted causes as ``check`` names them; an id it never names refused."""
    from ekfviz.check.mistakes import catalogue
    from ekfviz.check.mutations import resolve

    known = {cause.id for cause in catalogue()}
    named = tuple(resolve(str(cause)) for cause in accept)
    for given, cause in zip(accept, named, strict=True):
        if cause not in known:
            raise RubricError(f"--rubric {where}: [grade] accept: {given!s} is not a cause"
                              " check names (see the documentation's list of causes)")  # fmt: skip
    return named


def _field(table: dict[str, Any], key: str, kind: Any, default: Any, where: str, at: str) -> Any:
    value = table.get(key, default)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise RubricError(f"--rubric {where}: {at} {key} = {value!r}: expected {_kind(kind)}")
    return value


def _kind(kind: Any) -> str:
    names = {str: "text", int: "a whole number", list: "a list", float: "a number"}
    return names.get(kind, "a number")


def _part(table: object, index: int, where: str, visibility: str) -> Part:
    at = f"part {index + 1}"
    if not isinstance(table, dict):
        raise RubricError(f"--rubric {where}: {at}: expected a [[part]] table")
    name = _field(table, "name", str, f"Part {index + 1}", where, at)
    kind = _field(table, "kind", str, "", where, at)
    if kind not in KINDS:
        raise RubricError(f"--rubric {where}: {at} kind = {kind!r}: expected one of"
                          f" {', '.join(KINDS)}")  # fmt: skip
    points = float(_field(table, "points", (int, float), 0, where, at))
    timeout = float(_field(table, "timeout", (int, float), 60, where, at))
    seen = _field(table, "visibility", str, visibility, where, at)
    if not points >= 0 or not timeout > 0 or seen not in VISIBILITIES:
        raise RubricError(f"--rubric {where}: {at} expects points >= 0, timeout > 0 and a"
                          f" visibility of {', '.join(VISIBILITIES)}")  # fmt: skip
    log = _field(table, "log", str, "classic", where, at)
    return Part(name, kind, points, timeout, log, seen)


@dataclass(frozen=True, slots=True)
class Setting:
    """How the submission runs: interpreter, sandbox, and what the output says of it."""

    python: str | None
    sandbox: bool
    said: str  # how it ran, for the results' output


Log = tuple[Path, Path | None, tuple[float, float, float] | None]


@dataclass(frozen=True, slots=True)
class GradescopeRequest:
    """One submission's grading in Gradescope's layout, as asked.

    :param submission: the submission's folder (None: ``ROOT/submission``)
    :param results: where ``results.json`` goes (None: ``ROOT/results/results.json``)
    :param rubric: the rubric's file (None: :data:`DEFAULT_RUBRIC`)
    :param python: the interpreter the submission runs in (None: ekfviz's)
    """

    submission: Path | None = None
    results: Path | None = None
    rubric: Path | None = None
    python: Path | None = None
    no_sandbox: bool = False


@dataclass(frozen=True, slots=True)
class GradescopeResults:
    """A submission graded: what its results say of it (``output``), and where they went."""

    output: str
    written: Path


def grade_in_gradescope(request: GradescopeRequest) -> GradescopeResults:
    """Grade one submission in Gradescope's layout and write its ``results.json``. Where
    the sandbox cannot start (a container without user namespaces), the submission runs
    without it, and the results' output says so.

    :raises UsageError: no submission folder, a rubric that cannot be used, an
        interpreter not found (:class:`RubricError` for the rubric)
    :raises OutputError: results that cannot be written there
    """
    root = autograder_root()
    folder = request.submission if request.submission is not None else root / "submission"
    target = request.results if request.results is not None else root / "results" / "results.json"
    if not folder.is_dir():
        raise UsageError(f"--submission {folder}: no such directory (Gradescope's submission"
                         " folder)")  # fmt: skip
    check_outputs(("--results", target))
    rubric = read_rubric(request.rubric)
    python = worker_options(request.python, 60.0, None).python
    setting = gradescope_setting(python, request.no_sandbox)
    document = grade_on_the_battery(folder, rubric, setting)
    write_bytes_atomic(target, json_text(document).encode("utf-8"))
    return GradescopeResults(str(document["output"]), target)


def write_autograder_zip(target: Path, rubric_path: Path | None) -> None:
    """Write the zip Gradescope asks for (see :func:`autograder_files`), whole or not at all.

    :raises RubricError: a rubric that cannot be used, or ekfviz not installed from source
    :raises OutputError: a zip that cannot be written there
    """
    import io
    import zipfile

    from ekfviz.samples import BATTERY

    check_outputs(("--gradescope-zip", target))
    files = autograder_files(rubric_path, read_rubric(rubric_path), BATTERY)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, (content, mode) in files.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = (0o100000 | mode) << 16  # a regular file, its mode
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, content)
    write_bytes_atomic(target, buffer.getvalue())


def gradescope_setting(python: str | None, no_sandbox: bool) -> Setting:
    """How a submission runs in Gradescope's container: in ekfviz's sandbox where it can
    start there (a container may lack user namespaces), else without it, said so."""
    from ekfviz.sandbox import bwrap

    if no_sandbox:
        return Setting(python, False, "The submission ran without ekfviz's sandbox (--no-sandbox).")
    try:
        said = f"The submission ran in ekfviz's sandbox ({bwrap.check(python)})."
    except bwrap.SandboxUnavailable as error:
        return Setting(python, False, f"ekfviz's sandbox could not start here ({error}); the"
                       " submission ran without it, in Gradescope's container only.")  # fmt: skip
    return Setting(python, True, said)


def grade_on_the_battery(folder: Path, rubric: Rubric, setting: Setting) -> dict[str, Any]:
    """:func:`grade_submission` on check's battery, written to a scratch folder for it."""
    from ekfviz.samples import write_battery

    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as scratch:
        battery = {log.stem: (log, truth, start)
                   for log, truth, start in write_battery(Path(scratch))}  # fmt: skip
        return grade_submission(folder, rubric, setting, battery)


def grade_submission(
    folder: Path, rubric: Rubric, setting: Setting, battery: Mapping[str, Log]
) -> dict[str, object]:
    """Gradescope's results document for the submission in ``folder``.

    :param battery: the battery's logs by name (log, truth, start), for the parts that
        name one

    :raises RubricError: a part names a log that is neither the battery's nor a file
    """
    from ekfviz import __version__
    from ekfviz.app.grade import NoModule, module_of, spec_text
    from ekfviz.sandbox.submission import Submission, SubmissionRefused, survey

    started = time.perf_counter()
    tests: list[dict[str, object]] = []
    try:
        files = tuple(f for f, _ in survey(Submission(str(folder)), "the submission").files)
        module = module_of(folder, "the submission", files)
    except (SubmissionRefused, NoModule) as error:
        said = shown(str(error))
        for part in rubric.parts:
            tests.append(_test(part, False, f"not graded: {said}"))
        return _document(tests, started, f"ekfviz {__version__}: {said}. {setting.said}")
    spec_of = spec_text(module)
    logs = _logs(rubric, battery)
    with tempfile.TemporaryDirectory(prefix="ekfviz-gradescope-") as scratch:
        for part in rubric.parts:
            tests.append(_graded(part, rubric, setting, spec_of, logs, Path(scratch), folder))
    total = sum(float(str(t["max_score"])) for t in tests)
    score = sum(float(str(t["score"])) for t in tests)
    summary = (f"ekfviz {__version__} graded {shown(module.name)}: {score:g} of {total:g}"
               f" points. {setting.said}")  # fmt: skip
    return _document(tests, started, summary)


def _document(tests: list[dict[str, object]], started: float, output: str) -> dict[str, object]:
    return {
        "score": round(sum(float(str(t["score"])) for t in tests), 6),
        "execution_time": round(time.perf_counter() - started),
        "output": output,
        "stdout_visibility": "hidden",
        "tests": tests,
    }


def _test(part: Part, passed: bool, output: str) -> dict[str, object]:
    return {"name": part.name, "score": part.points if passed else 0.0,
            "max_score": part.points, "status": "passed" if passed else "failed",
            "output": output, "visibility": part.visibility}  # fmt: skip


def _logs(rubric: Rubric, battery: Mapping[str, Log]) -> dict[str, Log]:
    """Every log a part names: the battery's and files beside the rubric."""
    logs: dict[str, Log] = dict(battery)
    for part in rubric.parts:
        if part.log not in logs:
            path = (rubric.folder / part.log).resolve()
            if not path.is_file():
                raise RubricError(f"--rubric: part {part.name!r}: log {part.log}: no such file")
            truth = path.with_name(f"{path.stem}_truth.json")
            logs[part.log] = (path, truth if truth.is_file() else None, None)
    return logs


def _graded(
    part: Part,
    rubric: Rubric,
    setting: Setting,
    spec_of: str,
    logs: dict[str, Log],
    scratch: Path,
    folder: Path,
) -> dict[str, object]:
    """One part: its run, with its own time limit, judged."""
    from ekfviz.app.check import check_log
    from ekfviz.filters.spec import FilterSpec, FilterSpecError
    from ekfviz.sandbox.options import WorkerOptions
    from ekfviz.sandbox.submission import Submission

    log, truth, start = logs[part.log]
    params = _params(log, start)
    if part.kind in ("init", "predict"):
        log = _derived(log, part.kind, scratch)
    options = WorkerOptions(python=setting.python, timeout_s=part.timeout_s,
                            memory_mb=rubric.memory_mb, clean_env=True, echo=False,
                            deadline=time.time() + part.timeout_s, sandbox=setting.sandbox,
                            submission=Submission(str(folder)),
                            cwd=str(scratch) if not setting.sandbox else None)  # fmt: skip
    spec = FilterSpec(spec_of, "submission", options)
    try:
        result, _ = check_log(log, truth if part.kind != "init" else None, spec, params,
                              tolerance=rubric.tolerance, save=None, every=True)  # fmt: skip
    except FilterSpecError as error:
        return _test(part, False, f"failed: {shown(str(error))}")
    except Exception as error:  # the submission's failure, whatever it was: this part's
        return _test(part, False, f"failed: {shown(f'{type(error).__name__}: {error}')}")
    return _judged(part, rubric, result, truth)


def _params(log: Path, start: tuple[float, float, float] | None) -> FilterParams:
    """The assignment's parameters for ``log``: the defaults with the noise its header
    states, and its start."""
    from ekfviz.io.extended import NOISE_NAMES
    from ekfviz.sources import open_source

    stated = open_source(log).stated_noise()
    changes: dict[str, Any] = {
        n: stated[n] for n in NOISE_NAMES if isinstance(stated.get(n), float)
    }
    if isinstance(stated.get("init_pose_sigma"), tuple):
        changes["init_pose_sigma"] = stated["init_pose_sigma"]
    if start is not None:
        changes["init_pose"] = start
    return replace(FilterParams(), **changes)


def _derived(log: Path, kind: str, scratch: Path) -> Path:
    """A log of ``log``'s first line alone (``init``), or of its first line and every
    control (``predict``), as an extended log with its noise header."""
    from ekfviz.core.records import Control
    from ekfviz.io.extended import format_extended
    from ekfviz.sources import open_source

    source = open_source(log)
    events = list(source.events())
    kept = events[:1] + (
        [e for e in events[1:] if isinstance(e, Control)] if kind == "predict" else []
    )
    path = scratch / f"{log.stem}-{kind}.txt"
    path.write_text(format_extended(kept, precision=None, noise=source.stated_noise() or None))
    return path


def _judged(part: Part, rubric: Rubric, result: Any, truth: Path | None) -> dict[str, object]:
    """Whether a part's events pass, and what its output says: the first divergence of a
    cause not accepted (its cause, sentence and hint), or the error that stopped it."""
    scope = {"init": {"init"}, "predict": {"predict"}, "update": {"update"}}.get(part.kind)
    accepted = set(rubric.accept)
    wrong = [
        d for d in result.divergences
        if (scope is None or d.kind.value in scope) and not (d.causes and set(d.causes) <= accepted
                                                              and not d.alternatives)
    ]  # fmt: skip
    if wrong:
        return _test(part, False, _divergence_said(wrong[0], len(wrong)))
    if result.error is not None:
        return _test(part, False, f"failed at input line {result.error_line}:"
                                  f" {shown(result.error)}")  # fmt: skip
    if part.kind == "consistency":
        return _consistency(part, result, truth)
    checked = [r for r in result.records if scope is None or r.kind.value in scope]
    return _test(part, True, f"passed: the {len(checked)} event(s) agree with the reference"
                             f" (tolerance {rubric.tolerance:g})")  # fmt: skip


def _divergence_said(first: Any, count: int) -> str:
    said = first.to_json()
    cause = shown(said.get("cause", ""))
    sentence = shown(said.get("sentence", "")) if said.get("sentence") else ""
    return (f"failed: {count} event(s) diverge; the first, event {first.event} ({first.kind.value},"
            f" input line {first.line}): the {first.worst.quantity.value} differs (worst entry"
            f" {first.worst.entry}: expected {first.worst.expected:.6g}, got"
            f" {first.worst.got:.6g}). Cause: {cause}" + (f": {sentence}" if sentence else "")
            + f". Hint: {shown(said.get('hint', ''))}")  # fmt: skip


def _consistency(part: Part, result: Any, truth: Path | None) -> dict[str, object]:
    """NEES and NIS of the filter's own run against the log's truth."""
    from ekfviz.evaluation.consistency import Consistency, Verdict
    from ekfviz.io.truth import read_truth

    if truth is None:
        return _test(part, False, "not graded: the part's log has no truth (LOG_truth.json)")
    consistency = Consistency(read_truth(truth))
    consistency.add(result.records)
    combined = consistency.combined()
    if combined is None:
        return _test(part, False, "failed: no NEES or NIS to judge")
    passed = combined[0] in (Verdict.CONSISTENT, Verdict.BORDERLINE)
    said = " ".join(consistency.summary())  # the counts, then the verdict once
    return _test(part, passed, f"{'passed' if passed else 'failed'}: {said}")


def autograder_root() -> Path:
    """Gradescope's tree: ``$EKFVIZ_AUTOGRADER_ROOT``, else ``/autograder``."""
    return Path(os.environ.get(ROOT_VARIABLE) or "/autograder")


SETUP_SH = """\
#!/usr/bin/env bash
# Gradescope runs this once, building the autograder's image (Ubuntu 22.04 or later: Python
# 3.10+): ekfviz from its source in this zip, in a virtual environment, and bubblewrap for
# its sandbox (ekfviz also brings its own bwrap, for where the distribution's is too old).
set -euo pipefail
apt-get update
apt-get install -y --no-install-recommends python3 python3-venv python3-dev build-essential \\
    bubblewrap
python3 -m venv /opt/ekfviz
/opt/ekfviz/bin/pip install --upgrade pip
/opt/ekfviz/bin/pip install /autograder/source/ekfviz-src
ln -sf /opt/ekfviz/bin/ekfviz /usr/local/bin/ekfviz
"""
RUN_AUTOGRADER = f"""\
#!/usr/bin/env bash
# Gradescope runs this for every submission: the student's files in ROOT/submission, the
# results in ROOT/results/results.json; ROOT is /autograder (${ROOT_VARIABLE}: another tree)
set -u
root="${{{ROOT_VARIABLE}:-/autograder}}"
mkdir -p "$root/results"
exec ekfviz grade --gradescope --rubric "$root/source/rubric.toml" \\
    --submission "$root/submission" --results "$root/results/results.json"
"""


def autograder_files(
    rubric_path: Path | None, rubric: Rubric, battery: Sequence[str]
) -> dict[str, tuple[bytes, int]]:
    """The zip Gradescope asks for, as {name: (content, mode)}: ``setup.sh``,
    ``run_autograder``, the rubric and the log files it names beyond the ``battery``'s
    (names of the logs ekfviz writes itself), ekfviz's source.

    :raises RubricError: ekfviz is not installed from its source, or a log outside the
        rubric's folder
    """
    files: dict[str, tuple[bytes, int]] = {
        "setup.sh": (SETUP_SH.encode(), 0o755),
        "run_autograder": (RUN_AUTOGRADER.encode(), 0o755),
        "rubric.toml": (
            DEFAULT_RUBRIC.encode() if rubric_path is None else rubric_path.read_bytes(),
            0o644,
        ),
    }
    for part in rubric.parts:
        if part.log in battery:
            continue
        path = (rubric.folder / part.log).resolve()
        if not str(path).startswith(str(rubric.folder.resolve()) + os.sep) or not path.is_file():
            raise RubricError(f"--rubric: part {part.name!r}: log {part.log}: expected a file"
                              " in the rubric's folder, to go into the zip")  # fmt: skip
        files[str(path.relative_to(rubric.folder.resolve()))] = (path.read_bytes(), 0o644)
        truth = path.with_name(f"{path.stem}_truth.json")
        if truth.is_file():
            files[str(truth.relative_to(rubric.folder.resolve()))] = (truth.read_bytes(), 0o644)
    for name, content in _source_files().items():
        files[f"ekfviz-src/{name}"] = (content, 0o644)
    return files


def _source_files() -> dict[str, bytes]:
    """ekfviz's source, to build it from: its package's code and the project's files."""
    package = Path(__file__).resolve().parents[1]
    project = package.parent
    pyproject = project / "pyproject.toml"
    if not pyproject.is_file() or 'name = "ekfviz"' not in pyproject.read_text():
        raise RubricError(
            "--gradescope-zip needs ekfviz's source, to install it on Gradescope: run it from"
            " an install of a clone (pip install -e .)"
        )
    found = {name: (project / name).read_bytes() for name in ("pyproject.toml", "setup.py",
             "README.md", "LICENSE") if (project / name).is_file()}  # fmt: skip
    for path in sorted(package.rglob("*")):
        if path.suffix in (".py", ".c", ".h", ".pyi") and "__pycache__" not in path.parts:
            found[str(path.relative_to(project))] = path.read_bytes()
    return found
