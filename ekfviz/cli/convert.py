"""``ekfviz convert``: a classic log in the extended format."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.convert import ConvertRequest, convert
from ekfviz.cli.console import out
from ekfviz.cli.options import ForceOption
from ekfviz.cli.program import app


@app.command(name="convert")
def convert_command(
    source: Annotated[
        Path, typer.Argument(help="A log in the classic format.", show_default=False)
    ],
    target: Annotated[
        Path, typer.Argument(help="Where to write the extended log.", show_default=False)
    ],
    force: ForceOption = False,
) -> None:
    """Rewrite a classic log in the extended format, every number exactly as written."""
    events = convert(ConvertRequest(source, target, force))
    out.print(f"Wrote {target} ({events} events)")
