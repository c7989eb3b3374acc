"""The MRCLAM part of ``make bench``: dataset 6 of the UTIAS MRCLAM datasets (Leung et
al., IJRR 2011), read from the shared reference folder, never copied into the project.

For robots 1, 2 and 3: ``ekfviz calibrate DIR --robot R``, then the replay line it
prints with ``--save`` and ``--report``: wall time, peak memory, .rrd size, landmarks
mapped and inside 3 sigma. And the plain replay of robot 1 with the defaults. Each
replay is run three times; the table gives the median time.
"""

from __future__ import annotations

import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from reference import find_reference

BIN = Path(sys.executable).parent
DATASET = "MRCLAM_Dataset6"
BEGIN, END = "<!-- mrclam:begin -->", "<!-- mrclam:end -->"
REPEATS = 3


def find_dataset() -> Path | None:
    """``$MRCLAM_DATASET``, else the shared reference copy (:func:`find_reference`)."""
    return find_reference(DATASET, "MRCLAM_DATASET")


@dataclass(frozen=True, slots=True)
class Row:
    robot: int
    how: str  # "calibrated" or "defaults"
    calibrate_s: float | None
    wall_s: float
    cpu_s: float
    peak_mb: float
    rrd_mb: float
    mapped: int
    inside: int
    command: str


def _run(command: Sequence[str], folder: Path) -> tuple[float, float, float, str]:
    """Wall seconds, CPU seconds (user + system, all threads), the child's own peak
    resident MB, and its standard output."""
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    out_path, err_path = folder / "stdout.txt", folder / "stderr.txt"
    with out_path.open("w") as out, err_path.open("w") as err:
        start = time.perf_counter()
        process = subprocess.Popen(command, env=env, stdout=out, stderr=err)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{shlex.join(command)} failed:\n{err_path.read_text()}")
    cpu = usage.ru_utime + usage.ru_stime
    return wall, cpu, usage.ru_maxrss / 1024.0, out_path.read_text()


def replay_row(dataset: Path, robot: int, folder: Path, calibrated: bool) -> Row:
    calibrate_s = None
    if calibrated:
        calibrate_s, _, _, out = _run(
            [str(BIN / "ekfviz"), "calibrate", str(dataset), "--robot", str(robot)], folder
        )
        line = next(x for x in out.splitlines() if x.startswith("ekfviz replay"))
        arguments = shlex.split(line)[2:]
    else:
        arguments = [str(dataset), "--robot", str(robot)]
    rrd, report = folder / f"robot{robot}.rrd", folder / f"robot{robot}.json"
    command = [str(BIN / "ekfviz"), "replay", *arguments, "--save", str(rrd),
               "--report", str(report)]  # fmt: skip
    times, cpus = [], []
    peak = 0.0
    for _ in range(REPEATS):
        wall, cpu, peak, _ = _run(command, folder)
        times.append(wall)
        cpus.append(cpu)
    landmarks = json.loads(report.read_text())["landmarks"]
    return Row(
        robot=robot,
        how="calibrated" if calibrated else "defaults",
        calibrate_s=calibrate_s,
        wall_s=statistics.median(times),
        cpu_s=statistics.median(cpus),
        peak_mb=peak,
        rrd_mb=rrd.stat().st_size / 1e6,
        mapped=len(landmarks),
        inside=sum(bool(entry["inside_3sigma"]) for entry in landmarks),
        command="ekfviz replay " + shlex.join(["DIR", *arguments[1:]]),
    )


def mrclam_section(folder: Path) -> str:
    """The MRCLAM section of RESULTS.md, between markers (a note when the data is absent)."""
    dataset = find_dataset()
    lines = [BEGIN, "## Real data: UTIAS MRCLAM dataset 6", ""]
    if dataset is None:
        lines += [
            f"Skipped: {DATASET} was not found (set MRCLAM_DATASET, or put it in"
            " shared/reference/ in a folder above the project).",
            END,
        ]
        return "\n".join(lines)
    rows = [replay_row(dataset, 1, folder, calibrated=False)]
    rows += [replay_row(dataset, robot, folder, calibrated=True) for robot in (1, 2, 3)]
    lines += [
        f"`{DATASET}` (Leung et al., IJRR 2011), robots 1-3: `ekfviz calibrate DIR --robot R`"
        " and the replay line it prints (with `--save` and `--report`), as the issue's"
        f" check does; the plain replay of robot 1 with the defaults. Median of {REPEATS}"
        " replays; end to end as a subprocess (start-up, reading, filter, logging, writing);"
        " *CPU s*: its user + system time over all its threads, which other load on the"
        " machine does not inflate as it does the wall time.",
        "",
        "| robot | noise | calibrate s | replay s | CPU s | peak MB | .rrd MB | mapped"
        " | inside 3σ |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        cal = "" if r.calibrate_s is None else f"{r.calibrate_s:.1f}"
        lines.append(
            f"| {r.robot} | {r.how} | {cal} | {r.wall_s:.2f} | {r.cpu_s:.2f} | {r.peak_mb:.0f}"
            f" | {r.rrd_mb:.2f}"
            f" | {r.mapped} | {r.inside} ({100 * r.inside / max(r.mapped, 1):.0f} %) |"
        )
    calibrated = [r for r in rows if r.how == "calibrated"]
    worst_s = max(r.wall_s for r in rows)
    worst_cpu = max(r.cpu_s for r in rows)
    worst_mb = max(r.rrd_mb for r in rows)
    ok_map = all(r.mapped >= 12 and r.inside >= 0.8 * r.mapped for r in calibrated)
    lines += [
        "",
        "| target | measured | met |",
        "|---|---|---|",
        f"| end to end <= 3 s per robot | {worst_s:.2f} s (slowest) |"
        f" {'yes' if worst_s <= 3 else '**no**'} |",
        f"| CPU <= 3 s per robot | {worst_cpu:.2f} s (most) |"
        f" {'yes' if worst_cpu <= 3 else '**no**'} |",
        f"| recording <= 10 MB per robot | {worst_mb:.2f} MB (largest) |"
        f" {'yes' if worst_mb <= 10 else '**no**'} |",
        f"| calibrated: >= 12 landmarks, >= 80 % inside 3σ | see the table |"
        f" {'yes' if ok_map else '**no**'} |",
        f"Load average when measured: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.",
        "",
        "The replay lines:",
        "",
        *[f"- robot {r.robot}: `{r.command}`" for r in calibrated],
        END,
    ]
    return "\n".join(lines)


def splice(text: str, section: str) -> str:
    """``text`` with the section between the markers that open and close ``section``
    (its first and last lines) replaced, or appended."""
    begin, end = section.splitlines()[0], section.splitlines()[-1]
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        return head + section + rest.split(end, 1)[1]
    return text.rstrip("\n") + "\n\n" + section + "\n"
