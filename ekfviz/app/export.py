"""``export``: a recording's estimated (and true) trajectory and its map, as files for evo
and spreadsheets, all written together or none."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.errors import InputError, UsageError
from ekfviz.io.files import check_outputs, write_files_atomic
from ekfviz.io.trajectory import format_landmarks_csv, format_poses_csv, format_tum


@dataclass(frozen=True, slots=True)
class ExportRequest:
    """What to export from a recording: the estimated poses in TUM format (``tum``), the
    true ones (``truth_tum``), the last landmark estimates as CSV, the poses and their
    sigmas as CSV."""

    recording: Path
    tum: Path | None = None
    truth_tum: Path | None = None
    landmarks: Path | None = None
    csv: Path | None = None


def export(request: ExportRequest) -> list[Path]:
    """Write every file asked for, all built before any is written.

    :return: the files written, in the order asked
    :raises UsageError: nothing asked, a file that is no recording of a replay
    :raises InputError: true poses asked of a recording that holds none
    :raises OutputError: an output that cannot be written (none is then)
    """
    from ekfviz import readback

    recording, tum, truth_tum = request.recording, request.tum, request.truth_tum
    landmarks, csv = request.landmarks, request.csv
    if tum is None and truth_tum is None and landmarks is None and csv is None:
        raise UsageError("nothing to export: give --tum, --truth-tum, --landmarks or --csv")
    # every output checked before the recording is read: a folder, a device (/dev/full),
    # two options naming one file or the recording itself are refused in one line
    check_outputs(
        ("--tum", tum), ("--truth-tum", truth_tum), ("--landmarks", landmarks), ("--csv", csv),
        inputs=[recording],
    )  # fmt: skip
    run = readback.read_recorded_run(recording)
    if truth_tum is not None and run.truth is None:
        raise InputError(
            recording, 0, "the recording holds no true poses (replay with --truth FILE.json"
            ' whose "poses" give one per step)',
        )  # fmt: skip
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
    # all of them replaced together, or none (a signal among them left old and new)
    write_files_atomic({path: text.encode("utf-8") for path, text in files})
    return [path for path, _ in files]
