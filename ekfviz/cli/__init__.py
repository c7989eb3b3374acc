"""The ``ekfviz`` command line: one module per command, shared options in :mod:`.options`.

A command's module registers it on the app when imported. ``ekfviz CMD`` imports only
``CMD``'s module (:func:`load`, from ``ekfviz.__main__``): a replay does not pay for the
modules of ``calibrate``, ``grade`` or ``simulate`` at every start. ``from ekfviz.cli
import app`` (the tests, the samples, a script) gets the app with every command.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import typer

# in the order of `ekfviz --help`
COMMANDS = (
    "calibrate",
    "check",
    "compare",
    "consistency",
    "convert",
    "export",
    "grade",
    "info",
    "replay",
    "simulate",
    "sweep",
    "watch",
)


def load(names: Iterable[str] = COMMANDS) -> typer.Typer:
    """The app with (at least) the commands ``names`` registered and their help polished."""
    for name in names:
        importlib.import_module(f"ekfviz.cli.{name}")
    from ekfviz.cli.help import polish
    from ekfviz.cli.program import app

    polish(app)
    return app


def command_of(argv: list[str]) -> str | None:
    """The command an ``ekfviz`` command line names, if it names one of :data:`COMMANDS`
    before any option (``ekfviz replay ...``); None for ``--help``, ``--version`` or a
    word that is no command (the whole app then says what it has)."""
    return argv[0] if argv and argv[0] in COMMANDS else None


def __getattr__(name: str) -> typer.Typer:
    """``ekfviz.cli.app``: the app with every command."""
    if name == "app":
        return load()
    raise AttributeError(f"module 'ekfviz.cli' has no attribute {name!r}")
