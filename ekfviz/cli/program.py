"""The ``ekfviz`` program: its commands' group, its own options (``--version``,
``--debug``), the command line as typer should read it, and the one place where what
ended a command becomes its line and its exit code:

==========================================  ==========================================
ended by                                    exit code
==========================================  ==========================================
a replay cut short (bad input, a filter)    2 (its recording of what came before kept)
SIGINT, SIGTERM                             130, 143 (what was kept said)
any other of ekfviz's own errors            2
a usage error (typer's: a bad option)       2
==========================================  ==========================================

``check`` exits 1 at a divergence: a verdict, not an error.
"""

from __future__ import annotations

import os
import shlex
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Annotated, Any

import typer
from typer import _click as click
from typer._click.core import ParameterSource
from typer._click.exceptions import ClickException
from typer._click.globals import get_current_context
from typer.core import TyperGroup
from typer.exceptions import Abort

from ekfviz.app.errors import EkfvizError, Interrupted, RunStopped
from ekfviz.app.session import begin, version_line
from ekfviz.cli.console import (
    DEBUG,
    HELD,
    OUT_STREAM,
    fail,
    fit_consoles,
    interrupted,
    out,
)


@contextmanager
def reported() -> Iterator[None]:
    """What ends a command, as its one line and its exit code (see the module)."""
    try:
        yield
    except RunStopped as stopped:
        fail(str(stopped), code=stopped.exit_code)
    except EkfvizError as error:
        fail(str(error))
    except Interrupted as stop:
        interrupted(stop)


class Commands(TyperGroup):
    """The commands' group: every command's end said by :func:`reported`, and a usage
    error (an option's value out of range, an unknown option, a missing argument) in one
    line on stderr, as every other error, instead of typer's boxed paragraph."""

    def invoke(self, ctx: click.Context) -> Any:
        with reported():
            return super().invoke(ctx)

    def main(
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        run = super().main
        if not standalone_mode:
            return run(args, prog_name, complete_var, False, windows_expand_args, **extra)
        try:
            code = run(args, prog_name, complete_var, False, windows_expand_args, **extra)
        except ClickException as error:
            from ekfviz.cli.help import one_line_usage_error

            one_line_usage_error(error)
            sys.exit(error.exit_code)
        except Abort:
            sys.stderr.write("Aborted.\n")
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    cls=Commands,
    help="Replay a 2-D EKF-SLAM run and explore it in Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def given_options(ctx: click.Context) -> frozenset[str]:
    """The names of the parameters the command line gave (not left at their defaults)."""
    return frozenset(name for name in ctx.params if given(name, ctx))


def given(name: str, context: click.Context | None = None) -> bool:
    """Whether the command line gave the option of parameter ``name`` (not its default),
    in ``context`` or the current one."""
    context = context or get_current_context(silent=True)
    source = None if context is None else context.get_parameter_source(name)
    return source not in (None, ParameterSource.DEFAULT)


def command_line() -> str:
    """This process's command line, as a recording tells it."""
    return shlex.join(["ekfviz", *sys.argv[1:]])


# Options taking several values: a value that is not a number is a missing value.
NUMBER_OPTIONS = {
    "--init-pose-sigma": ("SX SY STHETA", 3),
    "--odometry-scale": ("DISTANCE TURN", 2),
}
GLOBAL_FLAGS = ("--debug",)
# the options that name a file a command writes (a folder's, as --save-dir and simulate's
# --output of a dataset, may end with '/')
FILE_OPTIONS = frozenset((
    "--save", "--report", "--tum", "--truth-tum", "--landmarks", "--csv", "--extract-input",
    "--truth-out",
))  # fmt: skip


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


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _version(value: bool) -> None:
    if value:
        out.print(version_line())
        raise typer.Exit()


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
    OUT_STREAM.to_stderr = False
    fit_consoles()
    HELD.start()
    ctx.call_on_close(HELD.release)  # a command done (one that failed dropped them)
    ctx.call_on_close(begin(ctx.invoked_subcommand))  # (for a caller that goes on: tests)
