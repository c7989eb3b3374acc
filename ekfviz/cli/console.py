"""What the commands print and how: the consoles, tables and lines, the one-line error and
the one-line interrupt, warnings held until the input is read whole, progress bars, and
the :class:`TerminalReporter` the use cases are told through."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from typing import Any, NoReturn

import typer
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.measure import Measurement
from rich.progress import BarColumn, DownloadColumn, Progress, TimeRemainingColumn
from rich.table import Table
from rich.text import Text

from ekfviz.app.errors import Interrupted, written_before
from ekfviz.app.text import Block, Cell, Styled, TextTable, json_text, one_line, utf8

DEBUG = {"traceback": False}  # --debug: a traceback instead of the one line
NO_TERMINAL_WIDTH = 10_000  # piped output: full lines, nothing cut


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
OUT_STREAM = _Unpadded()
out = Console(file=OUT_STREAM, highlight=False, emoji=False)  # type: ignore[arg-type]
err = Console(stderr=True, highlight=False, emoji=False)


def release_held() -> None:
    """Say what was held (warnings, notes): the command's input has been read whole."""
    HELD.release()


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


def show_blocks(blocks: Sequence[Block]) -> None:
    """Print tables and lines in turn."""
    for block in blocks:
        if isinstance(block, TextTable):
            show(block)
        else:
            say(block)


def plain(text: object) -> Text:
    """Text printed as it is: no rich markup read in it (``x[theta]``, ``[bold]``)."""
    return Text(str(text))


def note(text: str) -> None:
    """A line for the user, printed as it is, wrapped only by the terminal."""
    out.print(plain(text), soft_wrap=True)


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


def interrupted(stop: Interrupted, kept: str | None = None) -> NoReturn:
    """Say in one line that the command was stopped by a signal and what it kept, and
    exit with 130 (SIGINT) or 143 (SIGTERM); ``--debug`` shows the traceback instead.

    :param kept: what was kept and where (default: what the interrupt says it kept)
    """
    if DEBUG["traceback"]:
        raise stop
    HELD.drop()
    if kept is None:
        kept = stop.kept or (
            written_before(stop.written, [])
            if stop.written
            else "nothing was written; existing files are left as they were"
        )
    err.print(
        f"[bold red]error:[/] interrupted ({stop.name}): {escape(one_line(kept))}", soft_wrap=True
    )
    raise SystemExit(stop.exit_code)


def warn(message: str) -> None:
    """One line on stderr that does not stop the run (held while the command runs: see
    :class:`_Held`)."""
    line = f"[yellow]warning:[/] {escape(one_line(utf8(message)))}"

    def say() -> None:
        err.print(line, soft_wrap=True, markup=True, highlight=False)

    if not HELD.add(say):
        say()


class TerminalReporter:
    """How the use cases tell the user what they do (see
    :class:`~ekfviz.app.reporting.Reporter`): notes on stdout, warnings held on stderr,
    progress bars on stderr where it is a terminal."""

    def note(self, text: str) -> None:
        note(text)

    def warn(self, text: str) -> None:
        warn(text)

    def reading(
        self, name: str, total_bytes: int
    ) -> AbstractContextManager[Callable[[int], None] | None]:
        return _reading_bar(name, total_bytes)

    def counting(self, what: str, total: int) -> AbstractContextManager[Callable[[], None]]:
        return _counting_bar(what, total)


@contextmanager
def _reading_bar(name: str, total_bytes: int) -> Iterator[Callable[[int], None] | None]:
    """A progress bar over the bytes read, told the sum read so far, where standard error
    is a terminal (else rich's bar would still end with a blank line on a pipe or a file).

    What is printed to standard output while the bar is shown goes above it only where
    standard output is a terminal too; to a file or a pipe it goes as ever."""
    if not err.is_terminal:
        yield None
        return
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        DownloadColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        redirect_stdout=sys.stdout.isatty(),  # the same screen: above the bar
    ) as bar:
        task = bar.add_task(escape(name), total=total_bytes)
        yield lambda done: bar.update(task, completed=done)


@contextmanager
def _counting_bar(what: str, total: int) -> Iterator[Callable[[], None]]:
    """A progress bar over units of work, where standard error is a terminal."""
    with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
        task = bar.add_task(escape(what), total=total)
        yield lambda: bar.advance(task)
