"""The ``check`` part of ``make bench``: ``ekfviz check --all`` of course modules, on the
classic sample and on the battery, against the same commands of a clone from before the
diagnosis searched mutations (``--before DIR``: the clone, with its own ``.venv``).

The modules are the course skeleton (``examples/course_skeleton/ekf_slam.py``, which
matches) and copies of it with one mistake each: G transposed (every predict diverges),
R missing from S (every update), S inverted elementwise (its P grows until the state is
invalid), and R tripled (a scaled noise: its factor is fitted at every update). Each
command is run as a child process, wall and CPU seconds, the median of :data:`REPEATS`;
target: at most twice the time of before.
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

ROOT = Path(__file__).resolve().parent.parent
BEGIN, END = "<!-- check:begin -->", "<!-- check:end -->"
REPEATS = 3
SKELETON = (ROOT / "examples" / "course_skeleton" / "ekf_slam.py").read_text()
MODULES: dict[str, tuple[tuple[str, str], ...]] = {
    "skeleton (matches)": (),
    "G transposed": (("P = G @ P @ G.T", "P = G.T @ P @ G"),),
    "R missing from S": (("S = H @ P @ H.T + measure_cov", "S = H @ P @ H.T"),),
    "S inverted elementwise": (("K = np.linalg.solve(S, H @ P).T", "K = P @ H.T @ S**-1"),),
    "R tripled (a scaled noise)": (
        ("S = H @ P @ H.T + measure_cov", "S = H @ P @ H.T + 3 * measure_cov"),
    ),
}


@dataclass(frozen=True, slots=True)
class CheckRow:
    module: str
    log: str
    wall_s: float
    cpu_s: float
    before_wall_s: float | None
    before_cpu_s: float | None

    @property
    def ratio(self) -> float | None:
        return None if self.before_wall_s is None else self.wall_s / self.before_wall_s


def _module(folder: Path, name: str) -> Path:
    text = SKELETON
    for old, new in MODULES[name]:
        text = text.replace(old, new)
    path = folder / name.split(" (")[0].replace(" ", "_") / "ekf_slam.py"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _timed(command: list[str], folder: Path) -> tuple[float, float]:
    """Wall and CPU seconds (the child's user + system) of one run (exit 0 or 1)."""
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True, cwd=folder)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(command)} failed: {done.stderr[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def _median(command: list[str], folder: Path) -> tuple[float, float]:
    runs = [_timed(command, folder) for _ in range(REPEATS)]
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


def check_rows(folder: Path, before: Path | None) -> list[CheckRow]:
    """One row per module and log (the classic sample, the battery), now and before."""
    ekfviz_now = [sys.executable, "-m", "ekfviz"]
    ekfviz_before = None if before is None else [str(before / ".venv" / "bin" / "ekfviz")]
    rows = []
    for name in MODULES:
        path = _module(folder, name)
        for log, data in (("classic", [str(ROOT / "data" / "classic.txt")]), ("battery", [])):
            arguments = ["check", *data, "--filter", str(path), "--all"]
            wall, cpu = _median(ekfviz_now + arguments, folder)
            old_wall = old_cpu = None
            if ekfviz_before is not None:
                old_wall, old_cpu = _median(ekfviz_before + arguments, folder)
            rows.append(CheckRow(name, log, wall, cpu, old_wall, old_cpu))
            print(f"  {name}, {log}: {wall:.2f} s (before {old_wall})", flush=True)
    return rows


def check_section(folder: Path, before: Path | None) -> str:
    """The section of RESULTS.md (between its markers)."""
    rows = check_rows(folder, before)
    lines = [
        BEGIN,
        "## check --all",
        "",
        "`ekfviz check [data/classic.txt] --filter MODULE --all` as a child process (the"
        " battery: no log given), wall and CPU seconds, medians of"
        f" {REPEATS}; *before*: the same command of a clone from before the diagnosis"
        " searched mutations of the named operations (its battery two logs, today's three:"
        " a course module is not run on the third, which it cannot read). Target: at most"
        " twice the time of before.",
        "",
        "| module | log | wall s | CPU s | before wall s | before CPU s | now / before |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        before_wall = "" if row.before_wall_s is None else f"{row.before_wall_s:.2f}"
        before_cpu = "" if row.before_cpu_s is None else f"{row.before_cpu_s:.2f}"
        ratio = "" if row.ratio is None else f"{row.ratio:.2f}x"
        lines.append(f"| {row.module} | {row.log} | {row.wall_s:.2f} | {row.cpu_s:.2f} |"
                     f" {before_wall} | {before_cpu} | {ratio} |")  # fmt: skip
    ratios = [row.ratio for row in rows if row.ratio is not None]
    if ratios:
        worst = max(ratios)
        total = sum(r.wall_s for r in rows) / sum(r.before_wall_s or 0.0 for r in rows)
        lines += ["", f"Largest ratio {worst:.2f}x, all commands together {total:.2f}x:"
                  f" {'met' if worst <= 2.0 else '**not met**'} (at most 2x)."]  # fmt: skip
    lines.append(END)
    return "\n".join(lines) + "\n"
