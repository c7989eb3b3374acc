"""The scaling part of ``make bench``: how a replay's time and memory grow with the log's
length and with the map's size, drawn as two PNG plots beside RESULTS.md.

- *Length*: the classic route driven again and again among its six landmarks (the
  classic size), 10,000, 100,000 and 1,000,000 steps (the last is long: it runs once,
  as every case here does, and ``--quick`` leaves it out).
- *Map size*: N = 10 ... 2000 landmarks around a robot driving a circle, all seen at the
  start, then 10 of them (a random choice) at each of ``MAP_STEPS`` steps.

Each case is ``ekfviz replay LOG --save RUN.rrd`` as a child process, default settings:
wall time, CPU (user + system, the child's own threads included), its peak resident
memory and the recording's size.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.io.classic import format_classic
from ekfviz.io.extended import format_extended
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, Noise, classic_controls, simulate

BEGIN, END = "<!-- scaling:begin -->", "<!-- scaling:end -->"
HERE = Path(__file__).resolve().parent
BIN = Path(sys.executable).parent
LENGTHS = (10_000, 100_000, 1_000_000)
MAP_SIZES = (10, 50, 200, 500, 1000, 2000)
MAP_SEEN = 10
MAP_STEPS = 200
LENGTH_PLOT = "scaling_length.png"
MAP_PLOT = "scaling_map.png"


@dataclass(frozen=True, slots=True)
class ScalingRow:
    """One replay: its size (steps or landmarks) and what it cost."""

    size: int
    lines: int
    wall_s: float
    cpu_s: float
    peak_mb: float
    rrd_mb: float


# `ekfviz replay` run by a small Python that reports its child's peak memory and CPU: the
# peak of a child forked from this (larger) process would count the pages it shares
CHILD_COST = """
import json, resource, subprocess, sys, time
start = time.perf_counter()
subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL)
wall = time.perf_counter() - start
usage = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps([wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0]))
"""


def replay_cost(log: Path, folder: Path) -> tuple[float, float, float, float]:
    """Wall s, CPU s, peak resident MB and .rrd MB of ``ekfviz replay LOG --save``."""
    recording = folder / "scaling.rrd"
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    command = [str(BIN / "ekfviz"), "replay", str(log), "--save", str(recording)]
    done = subprocess.run(
        [sys.executable, "-c", CHILD_COST, *command],
        env=env, capture_output=True, text=True,
    )  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr}")
    wall, cpu, peak = json.loads(done.stdout)
    size = recording.stat().st_size / 1e6
    recording.unlink()
    return wall, cpu, peak, size


def classic_size_log(steps: int, path: Path) -> Path:
    """The classic route, ``steps`` steps among the classic six landmarks, to ``path``.

    The truth is a quieter robot than the filter assumes, so that it stays among the six
    landmarks for all those laps (as the end-to-end section's 100,000-step log)."""
    controls = np.tile(classic_controls(), (steps // 29 + 1, 1))[:steps]
    quiet = Noise(sigma_x=0.05, sigma_y=0.02, sigma_alpha=0.005)
    path.write_text(
        format_classic(simulate(controls, CLASSIC_LANDMARKS_XY, quiet, seed=3).events, 4)
    )
    return path


def map_size_log(n: int, path: Path, seed: int = 1) -> Path:
    """N landmarks around a circle drive, all seen at the start, then ``MAP_SEEN`` a step."""
    rng = np.random.default_rng(seed)
    landmarks_xy = rng.uniform(-25.0, 25.0, size=(n, 2))
    controls = np.tile([[1.0, 0.1]], (MAP_STEPS, 1))
    run = simulate(controls, landmarks_xy, Noise(), seed=seed)
    events: list[LogEvent] = [run.events[0]]
    for control, sighting in zip(run.events[1::2], run.events[2::2], strict=True):
        assert isinstance(control, Control) and isinstance(sighting, Sighting)
        pick = np.sort(rng.choice(n, size=min(MAP_SEEN, n), replace=False))
        events += [control, Sighting(sighting.line, sighting.ids[pick], sighting.z[pick])]
    path.write_text(format_extended(events, 6))  # the classic format sees all of them
    return path


def _rows(
    sizes: Sequence[int], make: Callable[[int, Path], Path], folder: Path, unit: str
) -> list[ScalingRow]:
    rows = []
    for size in sizes:
        log = make(size, folder / f"scaling_{size}.log")
        lines = sum(1 for _ in log.open())
        wall, cpu, peak, rrd = replay_cost(log, folder)
        log.unlink()
        rows.append(ScalingRow(size, lines, wall, cpu, peak, rrd))
        print(
            f"  {size:,} {unit}: {wall:.2f} s (CPU {cpu:.2f} s), {peak:.0f} MB, .rrd {rrd:.1f} MB",
            flush=True,
        )
    return rows


def plot(rows: Sequence[ScalingRow], xlabel: str, title: str, path: Path) -> None:
    """Time (wall and CPU) and peak memory against size, log-log, side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = [r.size for r in rows]
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.loglog(x, [r.wall_s for r in rows], "o-", label="wall")
    left.loglog(x, [r.cpu_s for r in rows], "s--", label="CPU (user + system)")
    left.set_ylabel("end to end (s)")
    left.legend()
    right.loglog(x, [r.peak_mb for r in rows], "o-", label="peak resident memory")
    right.loglog(x, [r.rrd_mb for r in rows], "s--", label=".rrd size")
    right.set_ylabel("MB")
    right.legend()
    for axes in (left, right):
        axes.set_xlabel(xlabel)
        axes.grid(True, which="both", alpha=0.3)
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def _table(rows: Sequence[ScalingRow], head: str) -> list[str]:
    lines = [
        f"| {head} | log lines | wall s | CPU s | peak MB | .rrd MB | wall us per line |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r.size:,} | {r.lines:,} | {r.wall_s:.2f} | {r.cpu_s:.2f} | {r.peak_mb:.0f}"
        f" | {r.rrd_mb:.1f} | {1e6 * r.wall_s / r.lines:.0f} |"
        for r in rows
    ]
    return lines


def scaling_section(folder: Path, quick: bool, plots: Path = HERE) -> str:
    """Run both curves, draw them into ``plots`` and return the section of RESULTS.md."""
    lengths = LENGTHS[:2] if quick else LENGTHS
    print("scaling: log length", flush=True)
    by_length = _rows(lengths, classic_size_log, folder, "steps")
    print("scaling: map size", flush=True)
    by_map = _rows(MAP_SIZES, map_size_log, folder, "landmarks")
    plot(by_length, "steps (classic size: 6 landmarks)", "Replay cost against log length",
         plots / LENGTH_PLOT)  # fmt: skip
    plot(by_map, f"landmarks N ({MAP_SEEN} observed per step, {MAP_STEPS} steps)",
         "Replay cost against map size", plots / MAP_PLOT)  # fmt: skip
    load = os.getloadavg()[0]
    lines = [
        BEGIN,
        "## Scaling: log length and map size",
        "",
        "`ekfviz replay LOG --save RUN.rrd` as a child process, default settings, each case"
        " run once: wall time, CPU (user + system, Rerun's threads included), the child's"
        " peak resident memory and the recording's size. Written by"
        " `benchmarks/scaling_bench.py` (`make bench`).",
        "",
        "**Log length**: the classic route driven again and again among its six landmarks.",
        "",
        f"![Replay cost against log length]({LENGTH_PLOT})",
        "",
        *_table(by_length, "steps"),
        "",
        f"**Map size**: N landmarks around a robot driving a circle, all seen at the start,"
        f" then {MAP_SEEN} of them (a random choice) at each of {MAP_STEPS} steps.",
        "",
        f"![Replay cost against map size]({MAP_PLOT})",
        "",
        *_table(by_map, "landmarks"),
        "",
        f"Load average when measured: {load:.1f} on {os.cpu_count()} cores.",
        END,
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        print(scaling_section(Path(tmp), "--quick" in sys.argv))
