"""The sandbox part of ``make bench``: what running each user's filter in its sandbox costs.

1. Start: a worker started, the course skeleton imported and the worker ended, in the
   sandbox and without it, interleaved; the difference of the medians is the sandbox's
   start cost per submission (target: at most 0.2 s). What ekfviz asks of the
   interpreter once per command (its probe and a trial start) is reported apart.
2. A class: ``ekfviz grade`` of 30 copies of the course skeleton on the battery, with the
   sandbox and with ``--no-sandbox``, interleaved; the ratio of the medians (target: at
   most 1.3x).
"""

from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

BEGIN, END = "<!-- sandbox:begin -->", "<!-- sandbox:end -->"
SKELETON = Path(__file__).resolve().parent.parent / "examples" / "course_skeleton" / "ekf_slam.py"
START_TARGET_S = 0.2
GRADE_TARGET = 1.3


def start_seconds(sandbox: bool) -> float:
    """Seconds to start a worker, import the skeleton in it and end it."""
    from ekfviz.sandbox.host import WorkerOptions
    from ekfviz.sandbox.remote import LoadedWorker, Target

    started = time.perf_counter()
    loaded = LoadedWorker(Target(str(SKELETON), None, None), WorkerOptions(echo=False,
                                                                           sandbox=sandbox),
                          "filter ekf_slam.py")  # fmt: skip
    loaded.process.close()
    return time.perf_counter() - started


def once_seconds() -> float:
    """What a command pays once to use the sandbox: the interpreter's probe, a trial."""
    from ekfviz.sandbox import bwrap

    started = time.perf_counter()
    bwrap.check(None)
    return time.perf_counter() - started


def grade_seconds(folder: Path, sandbox: bool) -> float:
    """Wall seconds of ``ekfviz grade FOLDER`` (two worker processes)."""
    command = [sys.executable, "-m", "ekfviz", "grade", str(folder), "--workers", "2"]
    env = {**os.environ, "CI": "1"}
    started = time.perf_counter()
    done = subprocess.run(command + ([] if sandbox else ["--no-sandbox"]), capture_output=True,
                          text=True, env=env, check=False)  # fmt: skip
    seconds = time.perf_counter() - started
    if done.returncode != 0 or "30 match" not in done.stdout:
        raise RuntimeError(f"grade failed: {done.stderr[-500:]}")
    return seconds


def sandbox_section(tmp: Path, quick: bool) -> str:
    """The sandbox's costs, as a section of RESULTS.md."""
    once = once_seconds()
    starts: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(5 if quick else 15):
        for sandbox in (False, True):
            starts[sandbox].append(start_seconds(sandbox))
    plain, boxed = (statistics.median(starts[s]) for s in (False, True))
    folder = tmp / "class"
    folder.mkdir(exist_ok=True)
    for index in range(30):
        shutil.copy(SKELETON, folder / f"student{index:02d}.py")
    grades: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(1 if quick else 3):
        for sandbox in (False, True):
            grades[sandbox].append(grade_seconds(folder, sandbox))
    without, within = (statistics.median(grades[s]) for s in (False, True))
    cost, ratio = boxed - plain, within / without
    lines = [
        BEGIN,
        "## The sandbox of user code",
        "",
        "A worker started, the course skeleton imported, the worker ended: in the sandbox"
        " and without it, interleaved, median of"
        f" {len(starts[True])}; and `ekfviz grade` of 30 copies of the skeleton on the"
        f" battery (two worker processes), median of {len(grades[True])}. Once per command,"
        f" ekfviz asks the interpreter what it needs and tries the sandbox: {once:.3f} s.",
        "",
        "| measure | without | in the sandbox | cost | target | verdict |",
        "|---|---:|---:|---:|---:|---|",
        f"| start of one submission's worker | {plain:.3f} s | {boxed:.3f} s | {cost:+.3f} s"
        f" | <= {START_TARGET_S} s | {'met' if cost <= START_TARGET_S else '**missed**'} |",
        f"| grade of 30 submissions | {without:.1f} s | {within:.1f} s | {ratio:.2f}x"
        f" | <= {GRADE_TARGET}x | {'met' if ratio <= GRADE_TARGET else '**missed**'} |",
        END,
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        print(sandbox_section(Path(scratch), "--quick" in sys.argv))
