"""The sandbox part of ``make bench``: what running each user's filter in its sandbox costs.

1. Start: a worker started (in the sandbox, the submission's private copy made first),
   the course skeleton imported and the worker ended, in the sandbox and without it,
   interleaved; the difference of the medians is the sandbox's start cost per
   submission (target: at most 0.2 s). What ekfviz asks of the interpreter once per
   command (its probe and a trial start) is reported apart.
2. A class: ``ekfviz grade`` of 30 copies of the course skeleton on the battery, with the
   sandbox and with ``--no-sandbox``, interleaved; the ratio of the medians (target: at
   most 1.3x).

Each is timed on the wall clock and in CPU seconds (of this process and every process
it waited for: the workers, their sandboxes): on a machine shared with other work the
wall clock says more of the others than of ekfviz.
"""

from __future__ import annotations

import os
import resource
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


def _cpu() -> float:
    """CPU seconds of this process and of every process it waited for."""
    own, waited = (resource.getrusage(who) for who in (resource.RUSAGE_SELF,
                                                        resource.RUSAGE_CHILDREN))  # fmt: skip
    return own.ru_utime + own.ru_stime + waited.ru_utime + waited.ru_stime


def start_seconds(sandbox: bool) -> tuple[float, float]:
    """Wall and CPU seconds to start a worker, import the skeleton in it and end it."""
    from ekfviz.sandbox.options import WorkerOptions
    from ekfviz.sandbox.remote import Target, WorkerFactory

    started, cpu = time.perf_counter(), _cpu()
    options = WorkerOptions(echo=False, sandbox=sandbox)
    WorkerFactory(Target(str(SKELETON), None, None), options, "filter ekf_slam.py").close()
    return time.perf_counter() - started, _cpu() - cpu


def once_seconds() -> float:
    """What a command pays once to use the sandbox: the interpreter's probe, a trial."""
    from ekfviz.sandbox import bwrap

    started = time.perf_counter()
    bwrap.check(None)
    return time.perf_counter() - started


def grade_seconds(folder: Path, sandbox: bool) -> tuple[float, float]:
    """Wall and CPU seconds of ``ekfviz grade FOLDER`` (two worker processes)."""
    command = [sys.executable, "-m", "ekfviz", "grade", str(folder), "--workers", "2"]
    process = subprocess.Popen(command + ([] if sandbox else ["--no-sandbox"]),
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                               env={**os.environ, "CI": "1"})  # fmt: skip
    started = time.perf_counter()
    assert process.stdout is not None
    said = process.stdout.read().decode()
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - started
    if os.waitstatus_to_exitcode(status) != 0 or "30 match" not in said:
        raise RuntimeError(f"grade failed: {said[-500:]}")
    return seconds, usage.ru_utime + usage.ru_stime


def _medians(found: list[tuple[float, float]]) -> tuple[float, float]:
    return statistics.median(w for w, _ in found), statistics.median(c for _, c in found)


def sandbox_section(tmp: Path, quick: bool) -> str:
    """The sandbox's costs, as a section of RESULTS.md."""
    once = once_seconds()
    starts: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    for _ in range(5 if quick else 15):
        for sandbox in (False, True):
            starts[sandbox].append(start_seconds(sandbox))
    folder = tmp / "class"
    folder.mkdir(exist_ok=True)
    for index in range(30):
        shutil.copy(SKELETON, folder / f"student{index:02d}.py")
    grades: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    for _ in range(1 if quick else 3):
        for sandbox in (False, True):
            grades[sandbox].append(grade_seconds(folder, sandbox))
    (plain, plain_cpu), (boxed, boxed_cpu) = _medians(starts[False]), _medians(starts[True])
    (without, without_cpu), (within, within_cpu) = _medians(grades[False]), _medians(grades[True])
    cost, ratio = boxed - plain, within / without
    load = os.getloadavg()[0]
    lines = [
        BEGIN,
        "## The sandbox of user code",
        "",
        "A worker started (in the sandbox: the submission's private copy made first), the"
        " course skeleton imported, the worker ended: in the sandbox and without it,"
        f" interleaved, median of {len(starts[True])}; and `ekfviz grade` of 30 copies of"
        f" the skeleton on the battery (two worker processes), median of {len(grades[True])}."
        f" Wall clock, and CPU seconds of every process. Once per command, ekfviz asks the"
        f" interpreter what it needs and tries the sandbox: {once:.3f} s. Load average"
        f" at the end: {load:.1f} on {os.cpu_count()} cores.",
        "",
        "| measure | without | in the sandbox | cost | target | verdict |",
        "|---|---:|---:|---:|---:|---|",
        f"| start of one submission's worker, wall | {plain:.3f} s | {boxed:.3f} s |"
        f" {cost:+.3f} s | <= {START_TARGET_S} s |"
        f" {'met' if cost <= START_TARGET_S else '**missed**'} |",
        f"| start of one submission's worker, CPU | {plain_cpu:.3f} s | {boxed_cpu:.3f} s |"
        f" {boxed_cpu - plain_cpu:+.3f} s | | |",
        f"| grade of 30 submissions, wall | {without:.1f} s | {within:.1f} s | {ratio:.2f}x"
        f" | <= {GRADE_TARGET}x | {'met' if ratio <= GRADE_TARGET else '**missed**'} |",
        f"| grade of 30 submissions, CPU | {without_cpu:.1f} s | {within_cpu:.1f} s |"
        f" {within_cpu / without_cpu:.2f}x | | |",
        END,
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        print(sandbox_section(Path(scratch), "--quick" in sys.argv))
