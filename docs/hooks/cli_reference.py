"""MkDocs hook: the command-line reference, generated from ekfviz's typer app.

A page holding the line ``<!-- ekfviz-cli-reference -->`` gets, in its place, every
command of ``ekfviz`` (in the order of ``ekfviz --help``): its help, its usage line and
one table per option panel (as ``--help`` groups them) with each option's help, its
default and its range, all read from the app itself (``typer.main.get_command``).

Why a hook and not a plugin: with typer 0.26-0.28, whose click is vendored as
``typer._click``, mkdocs-click's table style lists no option (it keeps parameters that
are ``click.Option`` instances) and mkdocs-typer2's native engine puts help text into
the page as HTML, so that ``filters/<name>/`` in ``compare``'s help stops the build;
both drop the option panels. This hook escapes every text it writes.
"""

from __future__ import annotations

import html
import re
from typing import Any

MARKER = "<!-- ekfviz-cli-reference -->"

# what click appends to an option's help: "  [default: 0.25; x>=0.0]" or "  [required]"
_EXTRA = re.compile(r"^(?P<help>.*?)\s{2}\[(?P<extra>[^\[\]]*)\]$", re.DOTALL)
# characters that Markdown (or a table's cell) would read as syntax, written as entities
_ENTITIES = {"*": "&#42;", "_": "&#95;", "`": "&#96;", "[": "&#91;", "]": "&#93;", "|": "&#124;"}


def on_page_markdown(markdown: str, **_: Any) -> str:
    """Put the reference where a page asks for it (MkDocs' page-markdown event)."""
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, cli_markdown())


def cli_markdown() -> str:
    """Every command of ``ekfviz`` as Markdown: a section per command, a table per panel."""
    import typer

    from ekfviz.cli import load

    group = typer.main.get_command(load())
    root = group.context_class(group, info_name="ekfviz")
    parts = [_command(group, root, level=2, title="ekfviz")]
    for name in group.list_commands(root):
        command = group.get_command(root, name)
        context = command.context_class(command, info_name=name, parent=root)
        parts.append(_command(command, context, level=2, title=f"ekfviz {name}"))
    return "\n\n".join(parts) + "\n"


def _command(command: Any, context: Any, *, level: int, title: str) -> str:
    """One command's section: title, help paragraphs, usage, its panels' tables."""
    usage = " ".join([context.command_path, *command.collect_usage_pieces(context)])
    lines = [f"{'#' * level} {title}", ""]
    for paragraph in (command.help or "").split("\n\n"):
        if paragraph.strip():
            lines += [_text(" ".join(paragraph.split())), ""]
    lines += [f"<pre><code>{html.escape(usage)}</code></pre>", ""]
    for panel, rows in _panels(command, context).items():
        kind = "argument" if panel == "Arguments" else "option"
        lines += [f"**{_text(panel)}**", "", f"| {kind} | what | default, range |", "|---|---|---|"]
        lines += rows
        lines.append("")
    return "\n".join(lines).rstrip()


def _panels(command: Any, context: Any) -> dict[str, list[str]]:
    """The parameters' table rows by panel: arguments first, then options, then each
    named panel in the order of its first parameter (as typer's ``--help`` shows them)."""
    panels: dict[str, list[str]] = {"Arguments": [], "Options": []}
    for param in command.get_params(context):
        if getattr(param, "hidden", False):
            continue
        record = param.get_help_record(context)
        if record is None:
            continue
        names, text = record
        is_argument = param.param_type_name == "argument"
        panel = getattr(param, "rich_help_panel", None) or (
            "Arguments" if is_argument else "Options"
        )
        if is_argument:
            names = (param.metavar or param.name or names).upper()
        help_text, extra = _split_extra(text)
        panels.setdefault(panel, []).append(f"| `{names}` | {_text(help_text)} | {_text(extra)} |")
    return {panel: rows for panel, rows in panels.items() if rows}


def _split_extra(text: str) -> tuple[str, str]:
    """An option's help and what click appended to it (default, range, required)."""
    text = text.replace("\\[", "[")  # rich markup's escape, which --help does not show
    match = _EXTRA.match(text)
    if match is None:
        return text, ""
    return match["help"], match["extra"]


def _text(text: str) -> str:
    """Plain text as Markdown that shows it as it is: no markup, no HTML, no table cells."""
    escaped = html.escape(text, quote=False)
    return "".join(_ENTITIES.get(character, character) for character in escaped)
