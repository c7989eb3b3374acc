"""Instructions a replay executes, now and before (``bench.py --instructions-only``).

Wall time on a shared two-core machine spreads by 10-30 % from one run to the next; the
number of instructions a process executes barely moves (a few parts in a thousand), so
it tells a change of a few per cent that wall time cannot. Each replay runs once under
Valgrind's callgrind (``valgrind --tool=callgrind``, every thread counted: Rerun's
encoder included), this checkout's and, with ``--before CLONE``, the clone's at the same
time (one core each): the classic sample, the 102,000-step classic-size log of the speed
targets (``targets_bench.long_logs``), and MRCLAM robot 1 and Victoria Park where the
reference folder has them. Under Valgrind a run is some 50 times slower: the whole
section takes about half an hour.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from targets_bench import LONG_STEPS, long_logs

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
BEGIN, END = "<!-- instructions:begin -->", "<!-- instructions:end -->"
_COLLECTED = re.compile(r"Collected\s*:\s*(\d+)")


@dataclass(frozen=True, slots=True)
class Counted:
    run: str
    now: int
    before: int | None


def _counting(ekfviz: str, args: list[str], folder: Path) -> subprocess.Popen[str]:
    """``ekfviz ARGS --save`` started under callgrind, its recording in a folder of its
    own (removed with it)."""
    own = Path(tempfile.mkdtemp(dir=folder))
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(own), XDG_DATA_HOME=str(own))
    command = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
               ekfviz, *args, "--save", str(own / "run.rrd")]  # fmt: skip
    return subprocess.Popen(
        command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )


def _collected(process: subprocess.Popen[str]) -> int:
    """The instructions callgrind counted in a process it ran (which must succeed)."""
    _, stderr = process.communicate()
    found = _COLLECTED.search(stderr)
    if process.returncode != 0 or found is None:
        raise RuntimeError(f"{' '.join(map(str, process.args))} failed:\n{stderr[-2000:]}")
    return int(found.group(1))


def count(run: str, args: list[str], folder: Path, before: Path | None) -> Counted:
    """The instructions of ``ekfviz ARGS`` now, and before (at the same time) where given."""
    now = _counting(str(BIN / "ekfviz"), args, folder)
    was = None if before is None else _counting(str(before / ".venv/bin/ekfviz"), args, folder)
    return Counted(run, _collected(now), None if was is None else _collected(was))


def instructions_section(
    folder: Path, before: Path | None, mrclam: Path | None, victoria: Path | None
) -> str:
    """The section of RESULTS.md: each replay's instructions, now and before."""
    if shutil.which("valgrind") is None:
        raise RuntimeError("the instruction counts need valgrind (apt install valgrind)")
    classic, _ = long_logs(folder, LONG_STEPS)
    runs = [
        ("the classic sample", ["replay", str(ROOT / "data" / "classic.txt")]),
        (f"the {LONG_STEPS:,}-step classic-size log", ["replay", str(classic)]),
    ]
    if mrclam is not None:
        runs.append(("MRCLAM robot 1", ["replay", str(mrclam), "--robot", "1"]))
    if victoria is not None:
        runs.append(("Victoria Park", ["replay", str(victoria)]))
    return _table([count(name, args, folder, before) for name, args in runs], before)


def _table(rows: list[Counted], before: Path | None) -> str:
    lines = [
        BEGIN,
        "## Instructions, now and before",
        "",
        "`python benchmarks/bench.py --instructions-only --before CLONE`"
        " (`benchmarks/instructions_bench.py`): each `ekfviz ... --save RUN.rrd` once under"
        " `valgrind --tool=callgrind`, every thread counted, this checkout's and the clone's"
        " at the same time. *Before*: a clone from before the event batches, the filter's"
        " named operations and the application layer. Billions of instructions.",
        "",
        "| replay | now | before | now / before |",
        "|---|---:|---:|---:|",
    ]
    for row in rows:
        was = "" if row.before is None else f"{row.before / 1e9:.3f}"
        ratio = "" if row.before is None else f"{row.now / row.before:.3f}"
        lines.append(f"| {row.run} | {row.now / 1e9:.3f} | {was} | {ratio} |")
    if before is None:
        lines += ["", "(No clone from before was given.)"]
    return "\n".join([*lines, END, ""])
