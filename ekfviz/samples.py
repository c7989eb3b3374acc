"""The bundled sample data: how each file in ``data/`` is made by ``ekfviz simulate``.

    python -m ekfviz.samples data        (or: make sample)

regenerates them byte for byte; a test checks that ``data/`` holds exactly this.
"""

from __future__ import annotations

import sys
from pathlib import Path

# file stem -> the arguments of `ekfviz simulate` that write <stem>.txt and <stem>_truth.json
SAMPLES: dict[str, list[str]] = {
    "classic": ["--scenario", "classic", "--seed", "2", "--precision", "4"],
    # the classic format's corner cases (bearings across +-pi, a start heading nearly pi,
    # a turn of over pi) for `ekfviz check`'s battery; replay with --init-pose 4 -2 3.136593
    "edge": ["--scenario", "edge", "--seed", "2", "--precision", "6"],
    # landmarks first seen mid-run, lines of known and new ones, some behind the robot (the
    # extended format, for `ekfviz check`'s battery; a course module cannot read it)
    "midrun": [
        "--scenario",
        "loop",
        "--seed",
        "3",
        "--steps",
        "24",
        "--landmarks",
        "24",
        "--max-range",
        "20",
        "--fov",
        "360",
        "--precision",
        "6",
    ],
    # the loop scenario as `ekfviz simulate --scenario loop` gives it by default (seed 0)
    "loop": ["--scenario", "loop", "--precision", "4"],
    # id-less scans with clutter and misses, for --association (see README)
    "scans": [
        "--scenario",
        "loop",
        "--seed",
        "1",
        "--landmarks",
        "120",
        "--unknown-ids",
        "--clutter",
        "1",
        "--detection-probability",
        "0.9",
        "--precision",
        "4",
    ],
}


def simulate_arguments(folder: Path, stem: str) -> list[str]:
    """The full ``ekfviz simulate`` command line (without the program) for one sample."""
    return [
        "simulate",
        *SAMPLES[stem],
        "-o",
        str(folder / f"{stem}.txt"),
        "--truth-out",
        str(folder / f"{stem}_truth.json"),
    ]


BATTERY = ("classic", "edge", "midrun")


def write_battery(folder: Path) -> list[tuple[Path, Path, tuple[float, float, float] | None]]:
    """``ekfviz check``'s battery written into ``folder``, as ``make sample`` writes those
    files: (log, truth, the filter's initial pose where it is not the origin) per log."""
    import contextlib
    import io

    from ekfviz.cli import load
    from ekfviz.cli.common import OUT_STREAM
    from ekfviz.sim.scenarios import EDGE_START

    app = load(("simulate",))  # in `check` or `grade`, only their own command is loaded
    logs: list[tuple[Path, Path, tuple[float, float, float] | None]] = []
    to_stderr = OUT_STREAM.to_stderr
    OUT_STREAM.to_stderr = True  # the simulator's own lines are nobody's output here
    try:
        for stem in BATTERY:
            with (
                contextlib.redirect_stderr(io.StringIO()),
                contextlib.redirect_stdout(io.StringIO()),
            ):
                app(simulate_arguments(folder, stem), standalone_mode=False)
            start = EDGE_START if stem == "edge" else None
            logs.append((folder / f"{stem}.txt", folder / f"{stem}_truth.json", start))
    finally:
        OUT_STREAM.to_stderr = to_stderr
    return logs


def main(argv: list[str]) -> None:
    from ekfviz.cli import app

    folder = Path(argv[0]) if argv else Path("data")
    folder.mkdir(parents=True, exist_ok=True)
    for stem in SAMPLES:
        app(simulate_arguments(folder, stem), standalone_mode=False)


if __name__ == "__main__":
    main(sys.argv[1:])
