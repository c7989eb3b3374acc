"""End-to-end replay of a 200-landmark classic log against the dense textbook filter.

    make bench        (or: .venv/bin/python benchmarks/bench_replay.py)

Times, in one run on one machine with one BLAS thread each:
- ``ekfviz replay LOG --save RUN.rrd`` as a subprocess: process start, imports, reading,
  filtering, logging and writing the recording included;
- the textbook dense filter's arithmetic alone on the same events (no start-up, no I/O).
Prints the ratio and both final poses, and appends nothing anywhere: the numbers go to
stdout for the person who asked.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ekfviz.core.filter import FilterParams
from ekfviz.core.records import Sighting
from ekfviz.io.classic import format_classic, read_classic
from ekfviz.sim.simulate import Noise, classic_controls, simulate

sys.path.insert(0, str(Path(__file__).parent))
from textbook_ekf import TextbookEkfSlam

N_LANDMARKS = 200


def make_log(folder: Path) -> Path:
    """The classic pentagon route among 200 landmarks, all seen at every step."""
    rng = np.random.default_rng(200)
    landmarks = rng.uniform([-4.0, -4.0], [16.0, 20.0], size=(N_LANDMARKS, 2))
    run = simulate(classic_controls(), landmarks, Noise(), seed=200)
    path = folder / "classic200.txt"
    path.write_text(format_classic(run.events, precision=6))
    return path


def time_textbook(log: Path) -> tuple[float, np.ndarray]:
    events = list(read_classic(log))
    first = events[0]
    assert isinstance(first, Sighting)
    params = FilterParams()
    start = time.perf_counter()
    ekf = TextbookEkfSlam(len(first.ids), params.Q, params.R, params.init_pose_sigma)
    ekf.run(events)
    return time.perf_counter() - start, ekf.x[:3]


def time_ekfviz(log: Path, folder: Path) -> tuple[float, np.ndarray, int]:
    report, recording = folder / "report.json", folder / "run.rrd"
    env = dict(os.environ, XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    ekfviz = Path(sys.executable).parent / "ekfviz"
    start = time.perf_counter()
    subprocess.run(
        [str(ekfviz), "replay", str(log), "--save", str(recording), "--report", str(report)],
        check=True,
        env=env,
        stdout=subprocess.DEVNULL,
    )
    elapsed = time.perf_counter() - start
    pose = np.array(json.loads(report.read_text())["final_pose"])
    return elapsed, pose, recording.stat().st_size


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        log = make_log(folder)
        ours, our_pose, rrd_bytes = time_ekfviz(log, folder)
        dense, dense_pose = time_textbook(log)
    print(
        f"200 landmarks, all seen at every step, 59 lines ({os.cpu_count()} cores, 1 BLAS thread)"
    )
    print(f"  ekfviz replay --save, end to end : {ours:8.2f} s  (.rrd {rrd_bytes / 1e6:.1f} MB)")
    print(f"  textbook dense, arithmetic only  : {dense:8.2f} s")
    print(f"  ratio dense / ekfviz             : {dense / ours:8.1f} x")
    print(f"  final pose ekfviz   : {np.array2string(our_pose, precision=6)}")
    print(f"  final pose textbook : {np.array2string(dense_pose, precision=6)}")
    print(f"  largest difference  : {np.abs(our_pose - dense_pose).max():.2e}")


if __name__ == "__main__":
    main()
