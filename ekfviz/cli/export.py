"""``ekfviz export``: a recording's trajectories and map as files for evo and spreadsheets."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import app, check_outputs, fail, out, plain, write_files_atomic
from ekfviz.io.trajectory import format_landmarks_csv, format_poses_csv, format_tum


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


@app.command()
def export(
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
    if tum is None and truth_tum is None and landmarks is None and csv is None:
        fail("nothing to export: give --tum, --truth-tum, --landmarks or --csv")
    # every output checked before the recording is read: a folder, a device (/dev/full),
    # two options naming one file or the recording itself are refused in one line
    check_outputs(
        ("--tum", tum), ("--truth-tum", truth_tum), ("--landmarks", landmarks), ("--csv", csv),
        inputs=[recording],
    )  # fmt: skip
    files = _files(recording, tum, truth_tum, landmarks, csv)
    # all of them replaced together, or none (a signal among them left old and new)
    write_files_atomic({path: text.encode("utf-8") for path, text in files})
    for path, _ in files:
        out.print(plain(f"Wrote {path}"))


def _files(
    recording: Path,
    tum: Path | None,
    truth_tum: Path | None,
    landmarks: Path | None,
    csv: Path | None,
) -> list[tuple[Path, str]]:
    """Every file asked for and its text, all built before any is written."""
    from ekfviz import readback

    try:
        run = readback.read_recorded_run(recording)
    except readback.NotARecordingError as error:
        fail(str(error))
    if truth_tum is not None and run.truth is None:
        fail(
            f"{recording}: the recording holds no true poses (replay with --truth FILE.json"
            ' whose "poses" give one per step)'
        )
    files: list[tuple[Path, str]] = []
    if tum is not None:
        files.append((tum, format_tum(run.estimate.stamps, run.estimate.poses_xytheta)))
    if truth_tum is not None and run.truth is not None:
        files.append((truth_tum, format_tum(run.truth.stamps, run.truth.poses_xytheta)))
    if landmarks is not None:
        files.append((landmarks, format_landmarks_csv(run.landmark_ids, run.landmarks_xy)))
    if csv is not None:
        estimate = run.estimate
        poses = format_poses_csv(
            estimate.steps, estimate.seconds, estimate.poses_xytheta, run.sigmas_xytheta
        )
        files.append((csv, poses))
    return files
