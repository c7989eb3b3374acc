"""``ekfviz export``: a recording's trajectories and map as files for evo and spreadsheets."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.app.export import ExportRequest, export
from ekfviz.cli.console import out, plain
from ekfviz.cli.program import app


def _output(help: str) -> object:
    return typer.Option(help=help, show_default=False, dir_okay=False)


Recording = Annotated[
    Path, typer.Argument(help="A recording of `ekfviz replay`.", show_default=False)
]
Tum = Annotated[Path | None, _output("The estimated pose of every step, in TUM format (for evo).")]
TruthTum = Annotated[
    Path | None,
    _output("The true pose of every step, in TUM format (the replay needs true poses)."),
]
LandmarksCsv = Annotated[Path | None, _output("The last landmark estimates as CSV: id,x,y.")]
PosesCsv = Annotated[
    Path | None,
    _output("The estimated poses as CSV: step[,time],x,y,theta and their sigmas."),
]


@app.command(name="export")
def export_command(
    recording: Recording,
    tum: Tum = None,
    truth_tum: TruthTum = None,
    landmarks: LandmarksCsv = None,
    csv: PosesCsv = None,
) -> None:
    """Write a recording's estimated (and true) trajectory and its map for other tools.

    Time stamps are the log's own, in seconds, where it had them, else the step numbers:
    `evo_ape tum truth.tum est.tum` compares the two trajectories.
    """
    for path in export(ExportRequest(recording, tum, truth_tum, landmarks, csv)):
        out.print(plain(f"Wrote {path}"))
