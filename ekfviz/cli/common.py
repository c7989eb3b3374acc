"""What the commands share: the app, one-line errors, option declarations, output helpers."""

from __future__ import annotations

import enum
import json
import math
import os
import shlex
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, NoReturn

import numpy as np
import typer
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text
from typer import _click as click
from typer._click.core import ParameterSource
from typer._click.globals import get_current_context

from ekfviz import __version__, signals
from ekfviz.core.params import FilterParams
from ekfviz.core.records import AnyEvent
from ekfviz.core.tables import Cell, Styled, TextTable, one_line, utf8
from ekfviz.core.truth import GroundTruth
from ekfviz.filters.ekf import HAVE_KERNEL
from ekfviz.io.paths import (
    OutputPathError,
    check_output_path,
    distinct_paths,
    output_over_input,
    real_path,
    temporary_prefix,
    unused_path,
)
from ekfviz.io.text import ProgressCallback


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
        if self.to_stderr and HELD.add(lambda: self.write(text)):
            return len(text)
        with _unwritable("standard error" if self.to_stderr else "standard output"):
            if self.isatty():
                return int(self._stream.write(text))
            lines = (self._partial + text).split("\n")
            self._partial = lines.pop()
            if lines:
                self._stream.write("".join(line.rstrip(" ") + "\n" for line in lines))
            return len(text)

    def flush(self) -> None:
        with _unwritable("standard error" if self.to_stderr else "standard output"):
            if self._partial:
                self._stream.write(self._partial.rstrip(" "))
                self._partial = ""
            self._stream.flush()


@contextmanager
def _unwritable(name: str) -> Iterator[None]:
    """A standard stream that takes nothing more (a full disk, ``> /dev/full``) ends the
    command with one line on stderr and exit 2; a reader that went away (a closed pipe,
    ``| head``) is left to end it as Python does, quietly."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as error:
        if name == "standard error":
            raise  # nowhere to say it
        fail(refused(name, error))


def refused(name: str, error: BaseException) -> str:
    """What to say of a standard stream that took nothing more, why as the system says
    it ("No space left on device")."""
    why = (error.strerror if isinstance(error, OSError) else None) or str(error)
    return f"{name}: {why}: what the command prints was not written whole"


class _Held:
    """What a command says on stderr while it runs (its warnings; with ``--json``, what
    it prints for people), held until it is done, so that a command stopped by an error
    or a signal says that in one line, with nothing before it (a warning of line 3 is
    noise beside the error of line 9). Said once the command is done, or where it says
    its results (:func:`release_held`); dropped where it fails. ``--debug`` holds
    nothing."""

    def __init__(self) -> None:
        self.active = False
        self.items: list[Callable[[], object]] = []

    def start(self) -> None:
        self.active, self.items = not DEBUG["traceback"], []

    def add(self, say: Callable[[], object]) -> bool:
        """Hold ``say`` (True) or leave it to be said now (False: nothing is held)."""
        if self.active:
            self.items.append(say)
        return self.active

    def release(self) -> None:
        self.active = False
        items, self.items = self.items, []
        for say in items:
            say()
        if items:
            OUT_STREAM.flush()

    def drop(self) -> None:
        self.active, self.items = False, []


HELD = _Held()


def release_held() -> None:
    """Say what was held (warnings, notes): the command's input has been read whole."""
    HELD.release()


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
    """A JSON document on stdout, for scripts: a non-finite number as null (JSON has
    none; Python's NaN and Infinity are not JSON)."""
    with _unwritable("standard output"):
        sys.stdout.write(json_text(document))
        sys.stdout.flush()


def json_text(document: object) -> str:
    """A document as ekfviz writes JSON (reports and ``--json``): indented, a non-finite
    number as null."""
    return json.dumps(_finite(document), indent=2, allow_nan=False) + "\n"


def _finite(value: object) -> object:
    """``value`` with every non-finite float in it as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


RECORDINGS_DIR = Path("recordings")


# as ekfviz.sandbox.host.DEFAULT_TIMEOUT_S (a test holds them equal; that module is
# not imported at start-up)
DEFAULT_FILTER_TIMEOUT_S = 60.0


def rendered(cell: Cell) -> Text:
    """A cell of a table or a line as rich text (no markup read in it)."""
    if isinstance(cell, Styled):
        return Text(cell.text, style=cell.style or "")
    if isinstance(cell, tuple):
        return Text.assemble(*((span.text, span.style or "") for span in cell))
    return Text(cell)


def show(table: TextTable) -> None:
    """Print a table (see :mod:`ekfviz.core.tables`)."""
    rich_table = Table(title=table.title, title_justify="left")
    if not table.lines:
        rich_table.box = box.SIMPLE_HEAD
    for column in table.columns:
        # a terminal too narrow for the table folds a cell's text onto more lines, never
        # cuts it ("13.71..." was 13.7164)
        rich_table.add_column(
            column, justify="left" if column in table.left else "right", overflow="fold"
        )
    for row in table.rows:
        rich_table.add_row(*(rendered(cell) for cell in row))
    if Measurement.get(out, out.options.update_width(1 << 16), rich_table).maximum > out.width:
        # no lines, and two spaces between columns: room for the cells
        rich_table.box, rich_table.pad_edge, rich_table.show_edge = box.SIMPLE_HEAD, False, False
        rich_table.padding = (0, 2, 0, 0)
    out.print(rich_table)


def say(lines: Sequence[Cell]) -> None:
    """Print lines (see :mod:`ekfviz.core.tables`)."""
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
        say_user_traceback(sys.exc_info()[1])
        raise
    HELD.drop()  # the error alone
    # a file name's bytes as UTF-8 shows them, where the locale could not decode them
    err.print(f"[bold red]error:[/] {escape(one_line(utf8(message)))}", soft_wrap=True)
    raise typer.Exit(code)


def say_user_traceback(error: BaseException | str | None) -> None:
    """With ``--debug``: the traceback a user's filter raised in its worker (the error's
    own, or of one it came from), on stderr: ekfviz's own frames do not show the user's
    code, which ran in another process."""
    seen: set[int] = set()
    while isinstance(error, BaseException) and id(error) not in seen:
        seen.add(id(error))
        text = getattr(error, "user_traceback", "")
        if text:
            error = str(text)
            break
        error = error.__cause__ or error.__context__
    if isinstance(error, str) and error:
        sys.stderr.write(f"the filter's own traceback, in its worker:\n{error.rstrip()}\n")


def interrupted(stop: signals.Interrupted, kept: str) -> NoReturn:
    """Say in one line that the command was stopped by a signal and what it kept, and
    exit with 130 (SIGINT) or 143 (SIGTERM); ``--debug`` shows the traceback instead.

    :param kept: what was kept and where, e.g. ``nothing was written``
    """
    if DEBUG["traceback"]:
        raise stop
    HELD.drop()
    err.print(
        f"[bold red]error:[/] interrupted ({stop.name}): {escape(one_line(kept))}", soft_wrap=True
    )
    raise SystemExit(stop.exit_code)


def stopped_study(done: int, total: int, what: str, outputs: Sequence[Path | None]) -> str:
    """What an interrupted study kept: the runs done of all, and that no output was
    written (each is written whole at the end), an existing one left as it was."""
    existing = [str(path) for path in outputs if path is not None and path.exists()]
    kept = f" ({', '.join(existing)} left as it was)" if existing else ""
    return f"{done} of {total} {what} done, the rest cancelled; nothing was saved{kept}"


def written_before(written: Sequence[Path], not_written: Sequence[Path | None]) -> str:
    """What a command stopped while it wrote its outputs kept: those ``written`` (whole),
    and those not (an existing one left as it was)."""
    rest = [str(path) for path in not_written if path is not None]
    said = f"{', '.join(map(str, written))} written whole before it" if written else ""
    left = f"{', '.join(rest)} not written (an existing file left as it was)" if rest else ""
    return "; ".join(part for part in (said, left) if part) or "nothing was written"


def check_outputs(*outputs: tuple[str, Path | None], inputs: Sequence[Path | None] = ()) -> None:
    """Check every output path of a command before any work starts (see
    :func:`ekfviz.io.paths.check_output_path`); two outputs must be two files, and none
    may be an input (writing it would replace the file being read).

    :param outputs: (how the path was given, e.g. ``--save``; the path or None)
    :param inputs: the files the command reads (None: not given)
    """
    for option, path in outputs:
        if path is not None:
            try:
                check_output_path(path, option)
            except OutputPathError as error:
                fail(str(error))
    clash = distinct_paths(dict(outputs)) or output_over_input(dict(outputs), inputs)
    if clash is not None:
        fail(clash)


def filter_module(spec: str) -> Path | None:
    """The file a ``--filter`` names (``PATH.py`` or ``PATH.py:Class``), an input not to
    write over; None for a built-in filter or an importable module."""
    head = spec.split(":", 1)[0]
    return Path(head) if head.endswith(".py") else None


def refuse_output_over_input(
    *outputs: tuple[str, Path | None], inputs: Sequence[Path | None]
) -> None:
    """Refuse (one line, exit 2) an output that is one of ``inputs``: for the files
    known only once the input is open (a dataset directory's)."""
    clash = output_over_input(dict(outputs), inputs)
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


def say_saved(path: Path) -> None:
    """That a recording was saved at ``path``, with the command that opens it in the
    viewer, quoted for the user's shell (a name with a space, a quote or a line break)."""
    opens = f"{shlex.quote(command_hint('rerun'))} {shlex.quote(str(path))}"
    out.print(plain(f"Saved {path}; open it with: {opens}"))


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
        name, equals, first = token.partition("=")
        if name in FILE_OPTIONS:  # (a Path drops the slash: "dir/" became a file "dir")
            value = first if equals else (rest[k + 1] if k + 1 < len(rest) else "")
            if value.endswith(("/", os.sep)) and value.strip("/" + os.sep):
                fail(f"{name} {value}: ends with '/', expected the name of a file")
        if name in NUMBER_OPTIONS:
            metavar, count = NUMBER_OPTIONS[name]
            # --init-pose-sigma=0.1 0.1 0.1 (as click takes it): the first value in the token
            values = ([first] if equals else []) + rest[k + 1 : k + 1 + count - bool(equals)]
            if len(values) < count or not all(_is_number(v) for v in values):
                found = next((v for v in values if not _is_number(v)), None)
                what = f", found {found!r}" if found is not None else ", found fewer"
                fail(f"{name} needs {count} numbers ({metavar}){what}")
    return hoisted + rest + tail


# the options that name a file a command writes (a folder's, as --save-dir and simulate's
# --output of a dataset, may end with '/')
FILE_OPTIONS = frozenset((
    "--save", "--report", "--tum", "--truth-tum", "--landmarks", "--csv", "--extract-input",
    "--truth-out",
))  # fmt: skip


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
    HELD.start()
    ctx.call_on_close(HELD.release)  # a command done (one that failed dropped them)
    if ctx.invoked_subcommand != "replay":  # only a replay keeps signals for later
        ctx.call_on_close(signals.reset)  # (for a caller that goes on: tests, notebooks)
        signals.as_interrupts()


def warn(message: str) -> None:
    """One line on stderr that does not stop the run (held while the command runs: see
    :class:`_Held`)."""
    line = f"[yellow]warning:[/] {escape(one_line(utf8(message)))}"

    def say() -> None:
        err.print(line, soft_wrap=True, markup=True, highlight=False)

    if not HELD.add(say):
        say()


# -- options shared by several commands ------------------------------------------------

FILTER_NOISE = "Filter noise"
FILTER_OPTIONS = "Filter options"


def piped_input(ctx: typer.Context, value: Path | None) -> Path | None:
    """The callback of an input's argument or option (a log, its truth): one given
    through a pipe (``-``, ``<(zcat log.gz)``) read ahead, so that it reads as a file (see
    :mod:`ekfviz.io.piped`); one line where it cannot be, exit 2 (130 or 143 on a signal
    while the pipe has not ended)."""
    if value is None:
        return None
    from ekfviz.io.piped import STDIN, PipedInputError, read_ahead

    given, meta = str(value), ctx.find_root().meta
    try:
        path = read_ahead(given, stdin_taken=meta.get("ekfviz.stdin_taken", False))
    except PipedInputError as error:
        fail(str(error))
    except signals.Interrupted as stop:
        interrupted(stop, "before the piped input had ended; nothing was written")
    if given == STDIN:
        meta["ekfviz.stdin_taken"] = True
    return value if path == given else Path(path)


def _option(help: str, panel: str | None = None, **kwargs: Any) -> Any:
    if "min" in kwargs or "max" in kwargs:  # a number's range: NaN is in none
        kwargs.setdefault("callback", not_nan)
    return typer.Option(help=help, rich_help_panel=panel, **kwargs)


def given(name: str, context: click.Context | None = None) -> bool:
    """Whether the command line gave the option of parameter ``name`` (not its default),
    in ``context`` or the current one."""
    context = context or get_current_context(silent=True)
    source = None if context is None else context.get_parameter_source(name)
    return source not in (None, ParameterSource.DEFAULT)


def not_nan(value: Any) -> Any:
    """An option's value with no NaN in it: a range (``min=0``) lets NaN through, since
    every comparison with it is false, and a NaN sigma, share or range ran without a word
    (``consistency --true-sigma-x nan`` read "consistent")."""
    values = value if isinstance(value, tuple | list) else (value,)
    if any(isinstance(v, float) and math.isnan(v) for v in values):
        raise typer.BadParameter("found nan, expected a number")
    return value


Triple = tuple[float, float, float]
DEFAULT = FilterParams()  # the classic defaults, stated once


def log_events(
    data: Path,
    truth: GroundTruth | None,
    truth_path: Path | None,
    progress: ProgressCallback | None = None,
) -> Iterator[AnyEvent]:
    """The log's events, checked against the truth's landmarks, reader warnings printed."""
    from ekfviz.app import log_events as events

    return events(data, truth, truth_path, progress, warn)


def write_json(path: Path, document: dict[str, object]) -> None:
    """A JSON report, as :func:`print_json` prints it (a non-finite number as null)."""
    write_bytes_atomic(path, json_text(document).encode("utf-8"))


def write_bytes_atomic(path: Path, content: bytes) -> None:
    """Write beside ``path`` and rename, so an existing file is never left half-written."""
    write_files_atomic({path: content})


def write_files_atomic(contents: dict[Path, bytes]) -> None:
    """Write every file beside its path first, then rename them all: an existing file is
    never left half-written, and files that belong together (a log and its truth) are
    replaced together or not at all."""
    written: list[tuple[str, Path]] = []  # (the temporary file, its path)
    renamed = False
    try:
        for target, content in contents.items():
            path = real_path(target)  # (resolve() raises on a loop of links)
            try:
                fd, tmp = tempfile.mkstemp(
                    dir=path.parent, prefix=temporary_prefix(path), suffix=".tmp"
                )
            except OSError as error:
                fail(f"{path}: cannot write ({error.strerror}); nothing was replaced")
            written.append((tmp, path))
            try:
                with os.fdopen(fd, "wb") as handle:
                    handle.write(content)
                os.chmod(tmp, _file_mode(path))
            except OSError as error:  # a full disk, a file-size limit: the old files stay
                fail(f"{path}: cannot write ({error.strerror or error}); nothing was replaced")
        with signals.held():  # a signal now: after the last rename (all or none)
            for tmp, path in written:
                os.replace(tmp, path)
            renamed = True
    except BaseException as error:
        for tmp, _ in written:
            Path(tmp).unlink(missing_ok=True)
        if renamed and isinstance(error, signals.Interrupted):  # said by the command line
            error.written = tuple(path for _, path in written)  # type: ignore[attr-defined]
        raise


def _file_mode(path: Path) -> int:
    """The mode a file written at ``path`` should get: the old file's, else the umask's."""
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask
