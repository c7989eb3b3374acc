"""The bundled sample data: how each file in ``data/`` is made by ``ekfviz simulate``.

    python -m ekfviz.samples data        (or: make sample)

regenerates them byte for byte; a test checks that ``data/`` holds exactly what the
command line writes from :func:`simulate_arguments`.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ekfviz.app.scenarios import LoopSettings, ScenarioName, SensingSettings
from ekfviz.app.simulate import SimulateRequest, simulate

Sample = dict[str, str | int | float | bool]

# file stem -> the options of `ekfviz simulate` that write <stem>.txt and <stem>_truth.json
SAMPLES: dict[str, Sample] = {
    "classic": {"scenario": "classic", "seed": 2, "precision": 4},
    # the classic format's corner cases (bearings across +-pi, a start heading nearly pi,
    # a turn of over pi) for `ekfviz check`'s battery; replay with --init-pose 4 -2 3.136593
    "edge": {"scenario": "edge", "seed": 2, "precision": 6},
    # landmarks first seen mid-run, lines of known and new ones, some behind the robot (the
    # extended format, for `ekfviz check`'s battery; a course module cannot read it)
    "midrun": {
        "scenario": "loop",
        "seed": 3,
        "steps": 24,
        "landmarks": 24,
        "max_range": 20.0,
        "fov": 360.0,
        "precision": 6,
    },
    # the loop scenario as `ekfviz simulate --scenario loop` gives it by default (seed 0)
    "loop": {"scenario": "loop", "precision": 4},
    # id-less scans with clutter and misses, for --association (see README)
    "scans": {
        "scenario": "loop",
        "seed": 1,
        "landmarks": 120,
        "unknown_ids": True,
        "clutter": 1.0,
        "detection_probability": 0.9,
        "precision": 4,
    },
}


def simulate_arguments(folder: Path, stem: str) -> list[str]:
    """The full ``ekfviz simulate`` command line (without the program) for one sample."""
    arguments = ["simulate"]
    for name, value in SAMPLES[stem].items():
        flag = "--" + name.replace("_", "-")
        if value is True:
            arguments.append(flag)
        else:
            arguments += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    return [*arguments, "-o", str(folder / f"{stem}.txt"),
            "--truth-out", str(folder / f"{stem}_truth.json")]  # fmt: skip


def sample_request(folder: Path, stem: str, *, force: bool = False) -> SimulateRequest:
    """The simulation of one sample, written into ``folder``."""
    options = SAMPLES[stem]
    return SimulateRequest(
        output=folder / f"{stem}.txt",
        truth_out=folder / f"{stem}_truth.json",
        scenario=ScenarioName(str(options["scenario"])),
        seed=int(options.get("seed", 0)),
        precision=int(options["precision"]),
        loop=LoopSettings(
            steps=int(options["steps"]) if "steps" in options else None,
            landmarks=int(options["landmarks"]) if "landmarks" in options else None,
            max_range=float(options["max_range"]) if "max_range" in options else None,
            fov=float(options["fov"]) if "fov" in options else None,
        ),
        sensing=SensingSettings(
            unknown_ids=bool(options.get("unknown_ids", False)),
            clutter=float(options.get("clutter", 0.0)),
            detection_probability=float(options.get("detection_probability", 1.0)),
        ),
        force=force,
    )


BATTERY = ("classic", "edge", "midrun")


def write_battery(folder: Path) -> list[tuple[Path, Path, tuple[float, float, float] | None]]:
    """``ekfviz check``'s battery written into ``folder``, as ``make sample`` writes those
    files: (log, truth, the filter's initial pose where it is not the origin) per log."""
    from ekfviz.sim.scenarios import EDGE_START

    logs: list[tuple[Path, Path, tuple[float, float, float] | None]] = []
    for stem in BATTERY:
        written = simulate(sample_request(folder, stem))
        log, truth = written.files
        logs.append((log, truth, EDGE_START if stem == "edge" else None))
    return logs


def main(argv: list[str]) -> None:
    folder = Path(argv[0]) if argv else Path("data")
    folder.mkdir(parents=True, exist_ok=True)
    for stem in SAMPLES:
        for line in simulate(sample_request(folder, stem, force=True)).lines[:1]:
            print(line)


if __name__ == "__main__":
    main(sys.argv[1:])
