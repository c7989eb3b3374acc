"""``ekfviz info``: how a recording was made, and its result."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from ekfviz.cli.common import (
    app,
    fail,
    out,
    write_bytes_atomic,
)


@app.command()
def info(
    recording: Annotated[
        Path, typer.Argument(help="A recording written by ekfviz.", show_default=False)
    ],
    extract_input: Annotated[
        Path | None,
        typer.Option(help="Write the embedded input log here, byte for byte.", show_default=False),
    ] = None,
) -> None:
    """Print how a recording was made (version, command, parameters, input) and its result."""
    from ekfviz import viz

    try:
        found = viz.read_recording_info(recording)
    except viz.NotARecordingError as error:
        fail(str(error))
    table = Table(show_header=False, box=None, pad_edge=False)
    table.add_column(style="bold")
    table.add_column(overflow="fold")
    for key, value in found.summary():
        table.add_row(key, value)
    out.print(table)
    if found.evaluation_markdown:
        from rich.markdown import Markdown

        out.print(Markdown(found.evaluation_markdown))
    if extract_input is not None:
        if found.input_text is None:
            fail(f"{recording}: the input is not embedded (it was over the size cap)")
        write_bytes_atomic(extract_input, found.input_text.encode("utf-8"))
        out.print(f"Wrote the input to {extract_input}")
