"""``ekfviz convert``: a classic log in the extended format."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import (
    app,
    fail,
    out,
    write_bytes_atomic,
)
from ekfviz.io.errors import InputError


@app.command()
def convert(
    source: Annotated[
        Path, typer.Argument(help="A log in the classic format.", show_default=False)
    ],
    target: Annotated[
        Path, typer.Argument(help="Where to write the extended log.", show_default=False)
    ],
) -> None:
    """Rewrite a classic log in the extended format, every number exactly as read."""
    from ekfviz.io.classic import read_classic
    from ekfviz.io.extended import format_extended

    try:
        events = list(read_classic(source))
    except InputError as error:
        fail(str(error))
    write_bytes_atomic(target, format_extended(events, precision=None).encode("utf-8"))
    out.print(f"Wrote {target} ({len(events)} events)")
