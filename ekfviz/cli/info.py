"""``ekfviz info``: what a recording is, how it was made, how it ended, and its result."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table
from rich.text import Text

from ekfviz.app.info import InfoRequest, info
from ekfviz.app.text import one_line, utf8
from ekfviz.cli.console import human_output_to_stderr, out, print_json
from ekfviz.cli.program import app


@app.command(name="info")
def info_command(
    recording: Annotated[
        Path, typer.Argument(help="A recording written by ekfviz.", show_default=False)
    ],
    extract_input: Annotated[
        Path | None,
        typer.Option(help="Write the embedded input log here, byte for byte.", show_default=False),
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option("--json", help="Print the information as JSON on stdout, for scripts."),
    ] = False,
) -> None:
    """Print what a recording is (replay, sweep, consistency study, your own filter's),
    how it was made (version, command, parameters, input), whether the run finished or
    stopped early (where and why), and its result."""
    if as_json:
        human_output_to_stderr()
    found = info(InfoRequest(recording, extract_input))
    if as_json:
        print_json(found.to_json())
    else:
        table = Table(show_header=False, box=None, pad_edge=False)
        table.add_column(style="bold", no_wrap=True)
        table.add_column(overflow="fold")
        # what a recording holds is shown, never obeyed: rich markup in a name is text, a
        # control character (a terminal's escape sequence, a line break) is escaped
        for key, value in found.summary():
            table.add_row(Text(key), Text(one_line(utf8(value))))
        out.print(table)
        if found.evaluation_markdown:
            from rich.markdown import Markdown

            shown = "\n".join(one_line(line) for line in found.evaluation_markdown.split("\n"))
            out.print(Markdown(shown))
    if extract_input is not None:
        out.print(f"Wrote the input to {extract_input}")
