"""``ekfviz convert``: a classic log in the extended format."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import (
    ForceOption,
    app,
    check_outputs,
    fail,
    out,
    refuse_overwrite,
    write_bytes_atomic,
)
from ekfviz.core.errors import InputError
from ekfviz.io.paths import real_path, same_file


@app.command()
def convert(
    source: Annotated[
        Path, typer.Argument(help="A log in the classic format.", show_default=False)
    ],
    target: Annotated[
        Path, typer.Argument(help="Where to write the extended log.", show_default=False)
    ],
    force: ForceOption = False,
) -> None:
    """Rewrite a classic log in the extended format, every number exactly as written."""
    from ekfviz.io.convert import classic_to_extended

    check_outputs(("TARGET", target))
    if same_file(target, source) or real_path(target) == real_path(source):
        fail(f"TARGET {target}: is the source itself: give another file")
    refuse_overwrite(force, ("TARGET", target))
    try:
        text, events = classic_to_extended(source)
    except InputError as error:
        fail(str(error))
    write_bytes_atomic(target, text.encode("utf-8"))
    out.print(f"Wrote {target} ({events} events)")
