"""Write the bundled sample: the classic scenario simulated with a fixed seed.

    python -m ekfviz.sim.sample data/

writes ``classic.txt`` (classic log format) and ``classic_truth.json`` (true landmarks
and poses). A test checks that the files in ``data/`` are exactly what this writes.
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict
from pathlib import Path

from ekfviz.io.classic import format_classic
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, Noise, Simulation, classic_controls, simulate

SAMPLE_SEED = 4


def classic_sample(seed: int = SAMPLE_SEED) -> Simulation:
    """The classic run with the classic noise levels."""
    return simulate(classic_controls(), CLASSIC_LANDMARKS_XY, Noise(), seed=seed)


def sample_files(seed: int = SAMPLE_SEED) -> dict[str, str]:
    """File name -> content of the bundled sample."""
    run = classic_sample(seed)
    truth = {
        "scenario": "classic",
        "seed": seed,
        "noise": asdict(Noise()),
        "landmarks": run.landmarks_xy.tolist(),
        "poses": [[round(v, 9) for v in pose] for pose in run.poses_xytheta.tolist()],
    }
    return {
        "classic.txt": format_classic(run.events, precision=4),
        "classic_truth.json": json.dumps(truth, indent=1) + "\n",
    }


def main(argv: list[str]) -> None:
    folder = Path(argv[0]) if argv else Path("data")
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in sample_files().items():
        (folder / name).write_text(content, encoding="utf-8", newline="\n")
        print(f"wrote {folder / name}")


if __name__ == "__main__":
    main(sys.argv[1:])
