"""What the commands share: the app, one-line errors, option declarations, output helpers."""

from __future__ import annotations

import enum
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import astuple
from pathlib import Path
from typing import Annotated, Any, NoReturn

import numpy as np
import typer
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, DownloadColumn, Progress, TimeRemainingColumn
from rich.table import Table
from rich.text import Text
from typer._click.core import ParameterSource
from typer._click.globals import get_current_context

from ekfviz import __version__, signals
from ekfviz.core.evaluation import Evaluation
from ekfviz.core.filter import HAVE_KERNEL, FilterParams, LandmarkInit, UpdateMode
from ekfviz.core.records import AnyEvent, EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.io.errors import InputError
from ekfviz.io.paths import OutputPathError, check_output_path, distinct_paths, unused_path
from ekfviz.io.text import MAX_MAGNITUDE, RANGE_TEXT, ProgressCallback
from ekfviz.sim.scenarios import Scenario, ScenarioName
from ekfviz.sim.simulate import Detection, Noise
from ekfviz.studies.executors import (
    Executor,
    ExecutorError,
    ExecutorName,
    make_executor,
)
from ekfviz.tables import Cell, Styled, TextTable


class LogFormat(str, enum.Enum):
    CLASSIC = "classic"
    EXTENDED = "extended"


app = typer.Typer(
    help="Replay a 2-D EKF-SLAM run and explore it in Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


class _Unpadded:
    """A text stream for a console: stdout (or, for ``--json``, stderr) looked up at every
    write, so that test runners can swap it, with the trailing spaces of every line
    dropped where there is no terminal (rich pads table cells and wrapped lines)."""

    def __init__(self) -> None:
        self.to_stderr = False
        self._partial = ""

    @property
    def _stream(self) -> Any:
        return sys.stderr if self.to_stderr else sys.stdout

    def isatty(self) -> bool:
        return bool(self._stream.isatty())

    def fileno(self) -> int:
        return int(self._stream.fileno())

    @property
    def encoding(self) -> str:
        return str(getattr(self._stream, "encoding", None) or "utf-8")

    def write(self, text: str) -> int:
        if self.isatty():
            return int(self._stream.write(text))
        lines = (self._partial + text).split("\n")
        self._partial = lines.pop()
        if lines:
            self._stream.write("".join(line.rstrip(" ") + "\n" for line in lines))
        return len(text)

    def flush(self) -> None:
        if self._partial:
            self._stream.write(self._partial.rstrip(" "))
            self._partial = ""
        self._stream.flush()


OUT_STREAM = _Unpadded()
out = Console(file=OUT_STREAM, highlight=False, emoji=False)  # type: ignore[arg-type]
err = Console(stderr=True, highlight=False, emoji=False)
NO_TERMINAL_WIDTH = 10_000  # piped output: full lines, nothing cut


def fit_consoles() -> None:
    """Full-width lines and nothing truncated where a console has no terminal."""
    for console in (out, err):
        console.width = NO_TERMINAL_WIDTH if not console.is_terminal else None  # type: ignore[assignment]


def human_output_to_stderr() -> None:
    """Keep stdout for a JSON document: what is printed for people goes to stderr."""
    OUT_STREAM.to_stderr = True


def print_json(document: object) -> None:
    """A JSON document on stdout, for scripts."""
    sys.stdout.write(json.dumps(document, indent=2) + "\n")
    sys.stdout.flush()


PROGRESS_MIN_BYTES = 1 << 20  # files under 1 MiB replay in well under a second
RECORDINGS_DIR = Path("recordings")


# as ekfviz.filters.worker.DEFAULT_TIMEOUT_S (a test holds them equal; that module is
# not imported at start-up)
DEFAULT_FILTER_TIMEOUT_S = 60.0


def worker_options(
    python: Path | None, timeout_s: float, memory_mb: int | None, echo: bool = True
) -> Any:
    """How a user's filter runs (:class:`~ekfviz.filters.worker.WorkerOptions`), the
    interpreter checked first."""
    from ekfviz.filters.worker import WorkerOptions

    if python is not None:
        found = shutil.which(str(python))
        if found is None or not Path(found).is_file():
            fail(f"--python {python}: no such interpreter (expected a Python executable)")
        python = Path(found)
    return WorkerOptions(
        python=None if python is None else str(python),
        timeout_s=timeout_s,
        memory_mb=memory_mb,
        echo=echo,
    )


def rendered(cell: Cell) -> Text:
    """A cell of a table or a line as rich text (no markup read in it)."""
    if isinstance(cell, Styled):
        return Text(cell.text, style=cell.style or "")
    return Text(cell)


def show(table: TextTable) -> None:
    """Print a table (see :mod:`ekfviz.tables`)."""
    rich_table = Table(title=table.title, title_justify="left")
    if not table.lines:
        rich_table.box = box.SIMPLE_HEAD
    for column in table.columns:
        rich_table.add_column(column, justify="left" if column in table.left else "right")
    for row in table.rows:
        rich_table.add_row(*(rendered(cell) for cell in row))
    out.print(rich_table)


def say(lines: Sequence[Cell]) -> None:
    """Print lines (see :mod:`ekfviz.tables`)."""
    for line in lines:
        wrap = not isinstance(line, Styled) or line.wrap
        out.print(rendered(line), soft_wrap=not wrap)


def plain(text: object) -> Text:
    """Text printed as it is: no rich markup read in it (``x[theta]``, ``[bold]``)."""
    return Text(str(text))


def fail(message: str, code: int = 2) -> NoReturn:
    """Print one line on stderr and exit: no traceback for a user's mistake (unless
    ``--debug``, and then only when called while handling an exception)."""
    if DEBUG["traceback"] and sys.exc_info()[1] is not None:
        raise
    err.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)
    raise typer.Exit(code)


def interrupted(stop: signals.Interrupted, kept: str) -> NoReturn:
    """Say in one line that the command was stopped by a signal and what it kept, and
    exit with 130 (SIGINT) or 143 (SIGTERM); ``--debug`` shows the traceback instead.

    :param kept: what was kept and where, e.g. ``nothing was written``
    """
    if DEBUG["traceback"]:
        raise stop
    err.print(f"[bold red]error:[/] interrupted ({stop.name}): {escape(kept)}", soft_wrap=True)
    raise SystemExit(stop.exit_code)


def stopped_study(done: int, total: int, what: str, outputs: Sequence[Path | None]) -> str:
    """What an interrupted study kept: the runs done of all, and that no output was
    written (each is written whole at the end), an existing one left as it was."""
    existing = [str(path) for path in outputs if path is not None and path.exists()]
    kept = f" ({', '.join(existing)} left as it was)" if existing else ""
    return f"{done} of {total} {what} done, the rest cancelled; nothing was saved{kept}"


def check_outputs(*outputs: tuple[str, Path | None]) -> None:
    """Check every output path of a command before any work starts (see
    :func:`ekfviz.io.paths.check_output_path`); two outputs must be two files.

    :param outputs: (how the path was given, e.g. ``--save``; the path or None)
    """
    for option, path in outputs:
        if path is not None:
            try:
                check_output_path(path, option)
            except OutputPathError as error:
                fail(str(error))
    clash = distinct_paths(dict(outputs))
    if clash is not None:
        fail(clash)


ForceOption = Annotated[bool, typer.Option("--force", help="Replace an existing output file.")]


def refuse_overwrite(force: bool, *outputs: tuple[str, Path | None]) -> None:
    """Without ``--force``, refuse (one line, exit 2) to write over an existing file.

    :param outputs: (how the path was given, e.g. ``--output``; the path or None)
    """
    if force:
        return
    for option, path in outputs:
        if path is not None and path.is_file():
            fail(f"{option} {path}: exists; add --force to replace it")


def default_output(name: str) -> Path:
    """A default output path under ``recordings/`` (made here if missing), never one
    that already holds a file (see :func:`ekfviz.io.paths.unused_path`)."""
    try:
        RECORDINGS_DIR.mkdir(exist_ok=True)
    except OSError as error:
        fail(f"{RECORDINGS_DIR}: cannot make the folder for recordings ({error.strerror})")
    return unused_path(RECORDINGS_DIR / name)


def command_hint(program: str) -> str:
    """How to run ``program`` (``rerun``, ``ekfviz``) from the user's shell: its bare name
    when the shell finds this installation's, else its path beside this Python (an
    unactivated virtual environment)."""
    beside = Path(sys.executable).parent / program
    found = shutil.which(program)
    if not beside.is_file():
        return program
    if found is not None and Path(found).resolve() == beside.resolve():
        return program
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


# Options taking several values: a value that is not a number is a missing value.
NUMBER_OPTIONS = {
    "--init-pose-sigma": ("SX SY STHETA", 3),
    "--odometry-scale": ("DISTANCE TURN", 2),
}
GLOBAL_FLAGS = ("--debug",)


def prepare_argv(argv: list[str]) -> list[str]:
    """The command line as typer should see it: ``--debug`` moved before the command
    (where the app takes it) from wherever it was given; a multi-value option followed by
    too few numbers refused with one line (typer would take the next option as a value).

    :raises typer.Exit: (code 2) after printing what is missing
    """
    end = argv.index("--") if "--" in argv else len(argv)
    head, tail = argv[:end], argv[end:]
    hoisted = [a for a in head if a in GLOBAL_FLAGS]
    rest = [a for a in head if a not in GLOBAL_FLAGS]
    for k, token in enumerate(rest):
        name = token.split("=", 1)[0]
        if name in NUMBER_OPTIONS:
            metavar, count = NUMBER_OPTIONS[name]
            values = rest[k + 1 : k + 1 + count]
            if len(values) < count or not all(_is_number(v) for v in values):
                found = next((v for v in values if not _is_number(v)), None)
                what = f", found {found!r}" if found is not None else ", found fewer"
                fail(f"{name} needs {count} numbers ({metavar}){what}")
    return hoisted + rest + tail


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _version(value: bool) -> None:
    if value:
        kernel = "compiled" if HAVE_KERNEL else "numpy (the compiled kernel was not built)"
        out.print(f"ekfviz {__version__}, filter kernel for small maps: {kernel}")
        raise typer.Exit()


DEBUG = {"traceback": False}


@app.callback()
def main(
    ctx: typer.Context,
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the traceback of an error, not one line.")
    ] = False,
) -> None:
    """Replay a 2-D EKF-SLAM run and explore it in Rerun."""
    DEBUG["traceback"] = debug
    # numpy's RuntimeWarnings (overflow, sqrt of a negative) would print a source line
    # before the run's own one-line warning or error: the filter's health checks say
    # what went wrong (a covariance not PSD, a state no longer finite) and where
    np.seterr(all="ignore")
    OUT_STREAM.to_stderr = False
    fit_consoles()
    if ctx.invoked_subcommand != "replay":  # only a replay keeps signals for later
        ctx.call_on_close(signals.reset)  # (for a caller that goes on: tests, notebooks)
        signals.as_interrupts()


def warn(message: str) -> None:
    """One line on stderr that does not stop the run."""
    err.print(f"[yellow]warning:[/] {message}", soft_wrap=True, markup=True, highlight=False)


# -- options shared by several commands ------------------------------------------------

FILTER_NOISE = "Filter noise"
FILTER_OPTIONS = "Filter options"


def _option(help: str, panel: str | None = None, **kwargs: Any) -> Any:
    return typer.Option(help=help, rich_help_panel=panel, **kwargs)


Triple = tuple[float, float, float]
DEFAULT = FilterParams()  # the classic defaults, stated once


def study_executor(name: ExecutorName, scheduler: str | None, workers: int | None) -> Executor:
    """The executor of ``--executor``/``--scheduler``/``--workers``, or a one-line error."""
    try:
        return make_executor(name, scheduler, workers)
    except ExecutorError as error:
        fail(str(error))


def detection_of(unknown_ids: bool, clutter: float, probability: float) -> Detection:
    """The simulated sensor's misses, false alarms and ids, refusing what cannot be."""
    if not 0.0 <= probability <= 1.0:
        fail(f"--detection-probability: {probability:g} is not between 0 and 1")
    if clutter > 0 and not unknown_ids:
        fail("--clutter: only with --unknown-ids (a log with ids names no false alarms)")
    return Detection(unknown_ids, clutter, probability)


def filter_params(
    sigmas: tuple[float, float, float, float, float],
    init_pose_sigma: Triple,
    landmark_init: LandmarkInit,
    update: UpdateMode,
    log: Path | None = None,
) -> FilterParams:
    """The filter's parameters from the command line, refusing what cannot work.

    :param log: the log replayed: the noise its header states (see
        :func:`ekfviz.io.extended.read_log_noise`) replaces the defaults of the options
        not given on the command line, and a note says so
    """
    names = ("--sigma-x", "--sigma-y", "--sigma-alpha", "--sigma-bearing", "--sigma-range")
    for name, value in [
        *zip(names, sigmas, strict=True),
        ("--init-pose-sigma", max(init_pose_sigma)),
    ]:
        if not value <= MAX_MAGNITUDE:  # nan too
            fail(f"{name} {value:g}: expected a sigma within {RANGE_TEXT}")
    if log is not None and log.is_file():
        sigmas, init_pose_sigma = _log_noise(log, sigmas, init_pose_sigma)
    sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range = sigmas
    if sigma_bearing <= 0 or sigma_range <= 0:
        fail("--sigma-bearing and --sigma-range must be positive: R must be invertible")
    if min(init_pose_sigma) < 0:
        fail("--init-pose-sigma values must not be negative")
    return FilterParams(
        sigma_x=sigma_x,
        sigma_y=sigma_y,
        sigma_alpha=sigma_alpha,
        sigma_bearing=sigma_bearing,
        sigma_range=sigma_range,
        init_pose_sigma=init_pose_sigma,
        landmark_init=landmark_init,
        update=update,
    )


def _log_noise(
    log: Path, sigmas: tuple[float, float, float, float, float], init_pose_sigma: Triple
) -> tuple[tuple[float, float, float, float, float], Triple]:
    """The sigmas and prior with the log's stated noise where no option was given."""
    from ekfviz.io.extended import NOISE_NAMES, read_log_noise

    try:
        stated = read_log_noise(log)
    except InputError as error:
        fail(str(error))
    context = get_current_context(silent=True)

    def given(name: str) -> bool:
        source = None if context is None else context.get_parameter_source(name)
        return source not in (None, ParameterSource.DEFAULT)

    values = dict(zip(NOISE_NAMES, sigmas, strict=True))
    used = []
    for name in NOISE_NAMES:
        value = stated.get(name)
        if isinstance(value, float) and not given(name):
            values[name] = value
            used.append(f"--{name.replace('_', '-')} {value:g}")
    prior = stated.get("init_pose_sigma")
    if isinstance(prior, tuple) and not given("init_pose_sigma"):
        init_pose_sigma = prior
        used.append("--init-pose-sigma " + " ".join(f"{v:g}" for v in prior))
    if used:
        out.print(f"{log}: the noise its header states: {' '.join(used)}", soft_wrap=True)
    sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range = (values[n] for n in NOISE_NAMES)
    return (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range), init_pose_sigma


def scenario_world(
    scenario: ScenarioName,
    seed: int,
    steps: int | None,
    landmarks: int | None,
    max_range: float | None,
    fov: float | None,
) -> Scenario:
    """The scenario asked for; the loop options are refused for the classic one."""
    from ekfviz.sim import scenarios

    options: dict[str, Any] = {
        "steps": steps, "landmarks": landmarks, "max_range": max_range, "fov_deg": fov
    }  # fmt: skip
    given = {name: value for name, value in options.items() if value is not None}
    if scenario in (ScenarioName.CLASSIC, ScenarioName.EDGE):
        if given:
            flags = (f"--{name.removesuffix('_deg').replace('_', '-')}" for name in given)
            fail(f"{', '.join(flags)}: only for --scenario loop")
        return scenarios.classic() if scenario is ScenarioName.CLASSIC else scenarios.edge()
    return scenarios.loop(seed=seed, **given)


def true_noise(world: Scenario, *given: float | None) -> Noise:
    """The scenario's own noise, with the values given on the command line instead."""
    return Noise(*(d if g is None else g for g, d in zip(given, astuple(world.noise), strict=True)))


# -- helpers ---------------------------------------------------------------------------


def log_events(
    data: Path,
    truth: GroundTruth | None,
    truth_path: Path | None,
    progress: ProgressCallback | None = None,
) -> Iterator[AnyEvent]:
    """The log's events, checked against the truth's landmarks, reader warnings printed."""
    from ekfviz.pipeline import log_events as events

    return events(data, truth, truth_path, progress, warn)


class FilterWarnings:
    """Print the filter's warnings as ``FILE:LINE: warning: ...``, the first few only:
    the recording's log holds all of them."""

    PRINTED = 10

    def __init__(self, data: Path) -> None:
        self._data = data
        self.count = 0

    def add(self, record: EventRecord) -> None:
        for text in record.warnings:
            self.count += 1
            if self.count <= self.PRINTED:
                where = f"{self._data}:{record.line}" if record.line else str(self._data)
                warn(escape(f"{where}: {text}"))

    def summarise(self) -> None:
        if self.count > self.PRINTED:
            warn(
                f"{self.count - self.PRINTED} more filter warnings"
                f" ({self.count} in all) are in the recording's log"
            )


@contextmanager
def open_progress(paths: list[Path]) -> Iterator[ProgressCallback | None]:
    """A progress bar over the bytes of ``paths`` (read side by side, the callback told
    the sum of the bytes read) when they are long, else nothing."""
    size = sum(path.stat().st_size for path in paths if path.is_file())  # else the reader says
    path = paths[0]
    if size < PROGRESS_MIN_BYTES:
        yield None
        return
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        DownloadColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
    ) as bar:
        task = bar.add_task(f"replaying {path.name}", total=size)
        yield lambda done: bar.update(task, completed=done)


def print_evaluation(evaluation: Evaluation, truth: GroundTruth | None) -> None:
    """The final landmark table and pose, with errors when the truth is known."""
    show(evaluation.table(truth))
    say(evaluation.lines(truth))


def mismatch_note(params: FilterParams, truth: GroundTruth) -> None:
    """Say so when the filter was told other noise levels than the simulator used."""
    told = params.as_dict()
    flags = [
        f"--{name.replace('_', '-')} " + " ".join(f"{v:g}" for v in np.atleast_1d(value))
        for name, value in (truth.simulated_with or {}).items()
        if name in told and not np.allclose(np.asarray(told[name], dtype=float), value)
    ]
    if flags:
        out.print(
            "[yellow]note:[/] the truth file says the log was simulated with other noise"
            f" levels than the filter was told; to match them: {' '.join(flags)}",
            soft_wrap=True,
        )


def report_json(
    evaluation: Evaluation, params: FilterParams, data: Path, sha256: str
) -> dict[str, object]:
    return {
        "ekfviz_version": __version__,
        "input": {"name": data.name, "sha256": sha256},
        "parameters": params.as_dict(),
        **evaluation.to_json(),
    }


def write_json(path: Path, document: dict[str, object]) -> None:
    write_bytes_atomic(path, (json.dumps(document, indent=2) + "\n").encode("utf-8"))


def write_bytes_atomic(path: Path, content: bytes) -> None:
    """Write beside ``path`` and rename, so an existing file is never left half-written."""
    path = path.resolve()
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as error:
        fail(f"{path}: cannot write ({error.strerror})")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(content)
        os.chmod(tmp, _file_mode(path))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _file_mode(path: Path) -> int:
    """The mode a file written at ``path`` should get: the old file's, else the umask's."""
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask
