"""The speed targets, measured in one run on one machine (``bench.py --targets-only``).

1. The classic sample replayed end to end (``ekfviz replay data/classic.txt --save``)
   against ``python -c "import rerun, numpy, typer"``, interleaved, medians of five:
   target, the replay within the imports + 0.15 s.
2. A classic-size log of 102,000 steps (the classic route again and again, as the
   end-to-end bench makes its 100,000-step one) end to end, the median of three runs
   (each one given), and the same events in the extended format (ekfviz's own format,
   held to the classic log's target): target, at most 5 s on a
   quiet two-core machine and at most twice its reading plus the filter (measured in a
   process of their own: the log read into events, then ``predict`` and ``observe`` of
   the built-in filter, nothing recorded); the recording at most 50 MB.
3. Victoria Park end to end, the median of three runs, with its landmark count and GPS
   RMSE read back from the recording (``association_bench.victoria_run``): target, at
   most 10 s, RMSE 3.52 m.

Wall and CPU (the child's user + system, Rerun's threads included) are both given: on a
loaded machine the wall time is the one that suffers.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
BEGIN = "<!-- targets: begin -->"
END = "<!-- targets: end -->"
LONG_STEPS = 102_000
REPEATS = 5
LONG_REPEATS = 3  # the long log and Victoria Park, each run in turn

# the log read and the filter run alone, in a process of their own: seconds of each
_READ_AND_FILTER = """
import sys, time
t0 = time.perf_counter()
from ekfviz.filters.ekf import EkfSlam
from ekfviz.core.records import Control
from ekfviz.sources import read_log
t1 = time.perf_counter()
events = list(read_log(__import__("pathlib").Path(sys.argv[1])))
t2 = time.perf_counter()
ekf = EkfSlam()
for event in events:
    if isinstance(event, Control):
        ekf.predict(event.d, event.alpha)
    else:
        ekf.observe(event.ids, event.z)
t3 = time.perf_counter()
print(t2 - t1, t3 - t2)
"""


@dataclass(frozen=True, slots=True)
class Timed:
    wall_s: float
    cpu_s: float


def _env(folder: Path) -> dict[str, str]:
    return dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))


def timed(command: list[str], folder: Path) -> Timed:
    """Wall and CPU seconds of a child process (it must succeed)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, env=_env(folder), capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return Timed(wall, cpu)


def _spread(runs: list[Timed]) -> str:
    """Every run's wall time, in the order they ran."""
    return ", ".join(f"{run.wall_s:.2f}" for run in runs)


def _median(runs: list[Timed]) -> Timed:
    return Timed(
        statistics.median(r.wall_s for r in runs), statistics.median(r.cpu_s for r in runs)
    )


def long_logs(folder: Path, steps: int = LONG_STEPS) -> tuple[Path, Path]:
    """A log of ``steps`` controls, the classic route again and again (a quieter robot
    than the filter assumes keeps it among the six landmarks), in the classic format and
    the same events in the extended one (ekfviz's own: ``ekfviz simulate`` writes it)."""
    from ekfviz.io.classic import format_classic
    from ekfviz.io.extended import format_extended
    from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, Noise, classic_controls, simulate

    controls = np.tile(classic_controls(), (steps // 29 + 1, 1))[:steps]
    quiet = Noise(sigma_x=0.05, sigma_y=0.02, sigma_alpha=0.005)
    run = simulate(controls, CLASSIC_LANDMARKS_XY, quiet, seed=7)
    classic, extended = folder / f"classic_{steps}.txt", folder / f"extended_{steps}.txt"
    classic.write_text(format_classic(run.events, 4))
    extended.write_text(format_extended(run.events, 4))
    return classic, extended


def targets_section(folder: Path, victoria: Path | None) -> str:
    """The section of RESULTS.md: each target, what this run measured, met or not."""
    ekfviz = str(BIN / "ekfviz")
    imports, replays = [], []
    for _ in range(REPEATS):  # interleaved: the same load for both
        imports.append(timed([sys.executable, "-c", "import rerun, numpy, typer"], folder))
        classic = [ekfviz, "replay", str(ROOT / "data" / "classic.txt"), "--save"]
        replays.append(timed([*classic, str(folder / "classic.rrd")], folder))
    imp, rep = _median(imports), _median(replays)

    log, extended_log = long_logs(folder)
    rrd = folder / "long.rrd"
    long_runs, extended_runs = [], []
    for _ in range(LONG_REPEATS):  # in turn: the same load for both
        long_runs.append(timed([ekfviz, "replay", str(log), "--save", str(rrd)], folder))
        extended = [ekfviz, "replay", str(extended_log), "--save", str(folder / "ext.rrd")]
        extended_runs.append(timed(extended, folder))
    long_run, extended_run = _median(long_runs), _median(extended_runs)
    size_mb = rrd.stat().st_size / 1e6
    done = subprocess.run(
        [sys.executable, "-c", _READ_AND_FILTER, str(log)],
        env=_env(folder), capture_output=True, text=True, check=True,
    )  # fmt: skip
    read_s, filter_s = (float(v) for v in done.stdout.split())

    rows = [
        ("classic sample end to end <= imports + 0.15 s",
         f"{rep.wall_s:.2f} s against {imp.wall_s:.2f} s (+{rep.wall_s - imp.wall_s:.2f} s);"
         f" CPU {rep.cpu_s:.2f} s against {imp.cpu_s:.2f} s (+{rep.cpu_s - imp.cpu_s:.2f} s)",
         rep.wall_s <= imp.wall_s + 0.15),
        (f"{LONG_STEPS:,}-step classic-size log end to end <= 5 s",
         f"{long_run.wall_s:.2f} s wall ({_spread(long_runs)}), {long_run.cpu_s:.2f} s CPU",
         long_run.wall_s <= 5.0),
        ("... <= 2 x (reading + filter)",
         f"{long_run.wall_s:.2f} s against 2 x ({read_s:.2f} + {filter_s:.2f}) ="
         f" {2 * (read_s + filter_s):.2f} s",
         long_run.wall_s <= 2 * (read_s + filter_s)),
        ("... recording <= 50 MB", f"{size_mb:.1f} MB", size_mb <= 50.0),
        ("... the same events as an extended log <= 5 s",
         f"{extended_run.wall_s:.2f} s wall ({_spread(extended_runs)}),"
         f" {extended_run.cpu_s:.2f} s CPU",
         extended_run.wall_s <= 5.0),
    ]  # fmt: skip
    if victoria is not None:
        from association_bench import victoria_run

        vps = [victoria_run(victoria, folder) for _ in range(LONG_REPEATS)]
        vp = sorted(vps, key=lambda run: run.wall_s)[len(vps) // 2]  # the median run
        walls = [Timed(run.wall_s, run.cpu_s) for run in vps]
        rows += [
            ("Victoria Park end to end <= 10 s",
             f"{vp.wall_s:.2f} s wall ({_spread(walls)}), {vp.cpu_s:.2f} s CPU",
             vp.wall_s <= 10.0),
            ("... GPS RMSE unchanged (3.52 m; 2.86 m without the jump), landmarks (290)",
             f"{vp.rmse_m:.2f} m; {vp.without_jump_m:.2f} m; {vp.landmarks} landmarks",
             round(vp.rmse_m, 2) == 3.52 and vp.landmarks == 290),
        ]  # fmt: skip
    load = os.getloadavg()[0]
    lines = [
        BEGIN,
        "## The speed targets, in one run",
        "",
        f"`python benchmarks/bench.py --targets-only` (`benchmarks/targets_bench.py`);"
        f" load average {load:.1f} on {os.cpu_count()} cores when it started. Wall: medians"
        " of five for the classic sample and the imports (interleaved), of"
        f" {LONG_REPEATS} for the long log and Victoria Park (every run in brackets);"
        " CPU: the child's user + system, Rerun's threads included.",
        "",
        "| target | measured | |",
        "|---|---|---|",
        *(f"| {t} | {m} | {'met' if ok else '**not met**'} |" for t, m, ok in rows),
    ]
    if victoria is None:
        lines += ["", "Victoria Park skipped: the dataset was not found."]
    lines.append(END)
    return "\n".join(lines)
