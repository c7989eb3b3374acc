"""The ``--help`` pages as a reader expects them: whole sentences, no stray placeholders.

Typer keeps the line breaks of a docstring in its rich help (sentences broken where the
source wraps), shows ``<bool>`` after every flag and ``{data}`` for a required argument.
:func:`polish` reflows the commands' docstrings into paragraphs and, where the installed
typer has the hooks (they are looked up, never assumed), drops the flag placeholder and
writes arguments in capitals. :func:`one_line_usage_error` is how the commands' group
(:class:`ekfviz.cli.program.Commands`) says a usage error.
"""

from __future__ import annotations

import inspect
import re
import sys
from typing import Any

import typer


def reflow(doc: str) -> str:
    """A docstring's paragraphs, each on one line (blank lines separate paragraphs)."""
    paragraphs = re.split(r"\n\s*\n", inspect.cleandoc(doc))
    return "\n\n".join(" ".join(p.split()) for p in paragraphs if p.strip())


_UNESCAPED_DEFAULT = re.compile(r"(?<!\\)\[default:")


def escape_defaults(callback: Any) -> None:
    """Escape a "[default: ...]" written into an option's help: rich help reads it as
    markup and drops it, leaving "text ." behind."""
    for parameter in inspect.signature(callback, eval_str=True).parameters.values():
        for info in getattr(parameter.annotation, "__metadata__", ()):
            text = getattr(info, "help", None)
            if isinstance(text, str) and _UNESCAPED_DEFAULT.search(text):
                info.help = _UNESCAPED_DEFAULT.sub(r"\\[default:", text)


def polish(app: typer.Typer) -> None:
    """Reflow every command's help and tidy typer's placeholders (see the module); again
    for commands registered since (each is polished once)."""
    for command in app.registered_commands:
        if command.callback is None or command.callback in _POLISHED:
            continue
        _POLISHED.add(command.callback)
        if command.help is None and command.callback.__doc__:
            command.help = reflow(command.callback.__doc__)
        escape_defaults(command.callback)
    if not _POLISHED_TYPER:
        _POLISHED_TYPER.append(True)
        _tidy_typer()


_POLISHED: set[Any] = set()
_POLISHED_TYPER: list[bool] = []  # typer's classes are patched once a process


def _tidy_typer() -> None:
    """No ``<bool>`` after a flag, arguments in capitals."""
    try:
        from typer import core
    except ImportError:  # pragma: no cover - a typer without the module: keep its pages
        return
    option = getattr(core, "TyperOption", None)
    argument = getattr(core, "TyperArgument", None)
    if option is not None and hasattr(option, "display_type_rich"):
        shown = option.display_type_rich

        def display_type_rich(self: Any, ctx: Any) -> str | None:
            if getattr(self, "is_flag", False) and getattr(self, "metavar", None) is None:
                return None  # a flag takes no value: no "<bool>"
            result: str | None = shown(self, ctx)
            return result

        option.display_type_rich = display_type_rich
    if argument is not None and hasattr(argument, "_usage_display_name"):  # typer 0.29
        usage = argument._usage_display_name

        def usage_display_name(self: Any) -> str:
            return _capitals(str(usage(self)))

        argument._usage_display_name = usage_display_name
    elif argument is not None and hasattr(argument, "make_metavar"):  # typer 0.26-0.28
        metavar = argument.make_metavar

        def make_metavar(self: Any, ctx: Any, *, usage: bool = False) -> str:
            name = str(metavar(self, ctx, usage=usage))
            return _capitals(name) if usage else name

        argument.make_metavar = make_metavar


def _capitals(name: str) -> str:
    """An argument of the usage line in capitals: ``{data}`` (required) as ``DATA``,
    ``[data]`` (optional) as ``[DATA]``."""
    name = re.sub(r"\{([^}]*)\}", lambda m: m.group(1).upper(), name)
    return re.sub(r"\[([a-z_]+)\]", lambda m: f"[{m.group(1).upper()}]", name)


def one_line_usage_error(error: Any) -> None:
    """A usage error as ``error: COMMAND: what is wrong (COMMAND --help)``, on stderr."""
    if type(error).__name__ == "NoArgsIsHelpError":  # the help page was printed
        return
    ctx = getattr(error, "ctx", None)
    command = getattr(ctx, "command_path", None) or "ekfviz"
    message = " ".join(str(error.format_message()).split())
    sys.stderr.write(f"error: {command}: {message} (see {command} --help)\n")
