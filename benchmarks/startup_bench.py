"""The start-up part of ``make bench``: each command's start-up and wrap-up on the classic
sample, against the interpreter importing rerun, numpy and typer, in one run.

A command runs as a child process (``python -c HOOK ARGS``: the ``ekfviz`` entry point
with the built-in filter's ``predict``, ``observe`` and ``drive`` wrapped so that each
call appends its start and end times to a file, in whatever process it runs). *Start-up*
is from the spawn to the first call's start (interpreter, imports, options, reading, the
recording opened), *work* from there to the last call's end, *wrap-up* from there to
the child's exit (the last events and layout sent, the recording flushed and closed,
reports and tables printed). Wall times are medians of ``REPEATS`` runs; *CPU* is the
child's user + system time (its own and its children's), which the other load on the
machine inflates less than the wall time.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

BEGIN, END = "<!-- startup:begin -->", "<!-- startup:end -->"
ROOT = Path(__file__).resolve().parents[1]
FILTER = f"{ROOT / 'examples' / 'my_filter.py'}:MyFilter"
REPEATS = 5
TARGET_S = 0.15  # the classic replay end to end within the imports + this

# Runs the command line as the `ekfviz` script does, the built-in filter's steps timed.
HOOK = """
import os, sys, time
from ekfviz.filters.ekf import EkfSlam
marks = os.environ["EKFVIZ_BENCH_MARKS"]
state = {"pid": None, "fd": -1}
def mark(tag):
    if state["pid"] != os.getpid():  # a forked worker writes too, through its own fd
        state["pid"] = os.getpid()
        state["fd"] = os.open(marks, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
    os.write(state["fd"], f"{tag} {time.time():.6f}\\n".encode())
def timed(method):
    def wrapper(self, *args, **kwargs):
        mark("start")
        try:
            return method(self, *args, **kwargs)
        finally:
            mark("end")
    return wrapper
for name in ("predict", "observe", "drive"):
    if hasattr(EkfSlam, name):
        setattr(EkfSlam, name, timed(getattr(EkfSlam, name)))
sys.argv = ["ekfviz", *sys.argv[1:]]
from ekfviz.__main__ import main
main()
"""


def commands(folder: Path) -> list[tuple[str, list[str]]]:
    """(name, arguments) of the commands timed, all on the bundled classic sample."""
    sample = str(ROOT / "data" / "classic.txt")
    return [
        ("replay", ["replay", sample, "--save", str(folder / "replay.rrd")]),
        ("check", ["check", sample, "--filter", FILTER]),
        (
            "compare",
            [
                "compare",
                sample,
                "--filter",
                "ekf",
                "--filter",
                FILTER,
                "--workers",
                "1",
                "--save",
                str(folder / "compare.rrd"),
            ],
        ),
        (
            "consistency",
            [
                "consistency",
                "--runs",
                "10",
                "--workers",
                "1",
                "--save",
                str(folder / "consistency.rrd"),
            ],
        ),
    ]


@dataclass(frozen=True, slots=True)
class StartupRow:
    """Medians over the repeats, seconds."""

    name: str
    wall_s: float
    cpu_s: float
    startup_s: float
    work_s: float
    wrapup_s: float


def _once(arguments: Sequence[str], folder: Path) -> tuple[float, float, float, float, float]:
    """(wall, cpu, start-up, work, wrap-up) of one run of ``ekfviz ARGUMENTS``."""
    marks = folder / "marks.txt"
    marks.unlink(missing_ok=True)
    env = dict(
        os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder),
        EKFVIZ_BENCH_MARKS=str(marks),
    )  # fmt: skip
    start = time.time()
    process = subprocess.Popen(
        [sys.executable, "-c", HOOK, *arguments],
        env=env, cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    assert process.stderr is not None
    errors = process.stderr.read()
    _, status, usage = os.wait4(process.pid, 0)
    end = time.time()
    code = os.waitstatus_to_exitcode(status)
    if code not in (0, 1):  # check exits 1 at a divergence: still a complete run
        raise RuntimeError(f"ekfviz {' '.join(arguments)} exited {code}:\n{errors.decode()}")
    times = [line.split() for line in marks.read_text().splitlines()]
    first = min(float(t) for tag, t in times if tag == "start")
    last = max(float(t) for tag, t in times if tag == "end")
    cpu = usage.ru_utime + usage.ru_stime
    return end - start, cpu, first - start, last - first, end - last


def imports_s(repeats: int = REPEATS) -> tuple[float, float]:
    """Median wall and CPU seconds of ``python -c "import rerun, numpy, typer"``."""
    walls, cpus = [], []
    for _ in range(repeats):
        start = time.time()
        process = subprocess.Popen([sys.executable, "-c", "import rerun, numpy, typer"])
        _, _, usage = os.wait4(process.pid, 0)
        walls.append(time.time() - start)
        cpus.append(usage.ru_utime + usage.ru_stime)
    return statistics.median(walls), statistics.median(cpus)


def startup_rows(folder: Path, repeats: int = REPEATS) -> tuple[list[StartupRow], float, float]:
    """Each command's row, and the imports' wall and CPU seconds, interleaved in one run
    (a command, then the imports, and again) so that both see the same load."""
    runs: dict[str, list[tuple[float, float, float, float, float]]] = {}
    walls, cpus = [], []
    for _ in range(repeats):
        for name, arguments in commands(folder):
            runs.setdefault(name, []).append(_once(arguments, folder))
        wall, cpu = imports_s(1)
        walls.append(wall)
        cpus.append(cpu)
    rows = [
        StartupRow(name, *(statistics.median(r[i] for r in results) for i in range(5)))
        for name, results in runs.items()
    ]
    for row in rows:
        print(
            f"  {row.name}: {row.wall_s:.2f} s (CPU {row.cpu_s:.2f} s): start-up"
            f" {row.startup_s:.2f} s, work {row.work_s:.3f} s, wrap-up {row.wrapup_s:.2f} s",
            flush=True,
        )
    return rows, statistics.median(walls), statistics.median(cpus)


def startup_section(folder: Path, repeats: int = REPEATS) -> str:
    """The start-up section of RESULTS.md, between its markers."""
    rows, wall, cpu = startup_rows(folder, repeats)
    load = os.getloadavg()[0]
    lines = [
        BEGIN,
        "## Start-up and wrap-up",
        "",
        "Each command on the bundled classic sample (`data/classic.txt`, 59 lines) as a"
        ' child process, beside `python -c "import rerun, numpy, typer"` in the same run'
        f" (interleaved, median of {repeats}). *Start-up*: from the spawn to the built-in"
        " filter's first step (interpreter, imports, options, reading, the recording"
        " opened); *work*: from there to its last step; *wrap-up*: from there to the exit"
        " (the last events and the layout sent, the recording flushed, reports and tables"
        " printed). *CPU*: user + system seconds of the child and its own children."
        " `check` runs `examples/my_filter.py:MyFilter` against the reference; `compare`"
        " the built-in filter and that one (`--workers 1`); `consistency` 10 runs of the"
        " classic scenario (`--workers 1`), which imports Rerun only to record the averaged"
        " curves, after its runs: its wrap-up holds that import.",
        "",
        "| command | wall s | CPU s | start-up s | work s | wrap-up s | wall - imports s |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| `{r.name}` | {r.wall_s:.2f} | {r.cpu_s:.2f} | {r.startup_s:.2f} | {r.work_s:.3f}"
        f" | {r.wrapup_s:.2f} | {r.wall_s - wall:+.2f} |"
        for r in rows
    ]
    lines += [
        f"| `import rerun, numpy, typer` | {wall:.2f} | {cpu:.2f} |  |  |  |  |",
        "",
    ]
    replay = next(r for r in rows if r.name == "replay")
    over = replay.wall_s - wall
    met = "met" if over <= TARGET_S else "**not met**"
    lines += [
        "| target | measured | |",
        "|---|---|---|",
        f"| classic replay end to end <= imports + {TARGET_S:.2f} s | imports + {over:.2f} s"
        f" ({replay.wall_s:.2f} s against {wall:.2f} s; CPU {replay.cpu_s:.2f} s against"
        f" {cpu:.2f} s) | {met} |",
        "",
        f"Load average when measured: {load:.1f} on {os.cpu_count()} cores.",
        END,
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        print(startup_section(Path(tmp), int(sys.argv[1]) if len(sys.argv) > 1 else REPEATS))
