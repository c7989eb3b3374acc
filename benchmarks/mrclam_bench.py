"""The MRCLAM part of ``make bench``: dataset 6 of the UTIAS MRCLAM datasets (Leung et
al., IJRR 2011), read from the shared reference folder, never copied into the project.

For every robot of the dataset (five: tuning on three and judging on all five is how
misses stayed unseen): ``ekfviz calibrate DIR --robot R`` (wall and CPU time), then the
replay line it prints with ``--save`` and ``--report``, and the plain replay with the
defaults beside it: wall and CPU time, peak memory, .rrd size, landmarks mapped and
inside 3 sigma, mean landmark error (truth frame and after the best rigid alignment),
the mean 3-sigma semi-major axis, NEES and NIS inside their bounds and the reading of
both. Each replay is run three times; the table gives the median time.
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

from ekfviz.io.mrclam import robots_in

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
    calibrate_cpu_s: float | None
    wall_s: float
    cpu_s: float
    peak_mb: float
    rrd_mb: float
    mapped: int
    inside: int
    mean_error: float
    aligned_error: float
    semi_major: float
    nees_inside: float | None
    nis_inside: float | None
    verdict: str
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
    calibrate_s = calibrate_cpu = None
    if calibrated:
        calibrate_s, calibrate_cpu, _, out = _run(
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
    document = json.loads(report.read_text())
    landmarks = document["landmarks"]
    summary = document["summary"]
    consistency = document["consistency"]
    return Row(
        robot=robot,
        how="calibrated" if calibrated else "defaults",
        calibrate_s=calibrate_s,
        calibrate_cpu_s=calibrate_cpu,
        mean_error=summary["mean_error"],
        aligned_error=summary["aligned_mean_error"],
        semi_major=summary["mean_semi_major_3sigma"],
        nees_inside=consistency["nees"]["fraction_inside"],
        nis_inside=consistency["nis"]["fraction_inside"],
        verdict=consistency["verdict"] or "-",
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
    rows = []
    robots = robots_in(dataset)
    for robot in robots:
        rows.append(replay_row(dataset, robot, folder, calibrated=False))
        rows.append(replay_row(dataset, robot, folder, calibrated=True))
    lines += [
        f"`{DATASET}` (Leung et al., IJRR 2011), all {len(robots)} robots: `ekfviz calibrate"
        " DIR --robot R` and the replay line it prints (with `--save` and `--report`),"
        " beside the plain replay with the defaults. Median of"
        f" {REPEATS} replays; end to end as a subprocess (start-up, reading, filter, logging,"
        " writing); *CPU s*: user + system time over all threads, which other load on the"
        " machine does not inflate as it does the wall time. *err*: mean landmark error in"
        " the truth's frame; *aligned*: after the best rigid alignment of the map to the"
        " truth; *3σ axis*: mean semi-major axis of the landmarks' 3-sigma ellipses (a map"
        " inside 3σ because its ellipses are huge shows here); NEES and NIS: share inside"
        " their 95 % bounds; *reading*: both together.",
        "",
        "| robot | noise | calibrate s (CPU) | replay s | CPU s | .rrd MB | mapped | inside 3σ"
        " | err m | aligned m | 3σ axis m | NEES in | NIS in | reading |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]

    def share(x: float | None) -> str:
        return "-" if x is None else f"{x:.0%}"

    for r in rows:
        cal = "" if r.calibrate_s is None else f"{r.calibrate_s:.1f} ({r.calibrate_cpu_s:.1f})"
        lines.append(
            f"| {r.robot} | {r.how} | {cal} | {r.wall_s:.2f} | {r.cpu_s:.2f} | {r.rrd_mb:.2f}"
            f" | {r.mapped} | {r.inside} ({100 * r.inside / max(r.mapped, 1):.0f} %)"
            f" | {r.mean_error:.2f} | {r.aligned_error:.2f} | {r.semi_major:.2f}"
            f" | {share(r.nees_inside)} | {share(r.nis_inside)} | {r.verdict} |"
        )
    calibrated = [r for r in rows if r.how == "calibrated"]
    plain = {r.robot: r for r in rows if r.how == "defaults"}
    worst_s = max(r.wall_s for r in rows)
    worst_cpu = max(r.cpu_s for r in rows)
    worst_mb = max(r.rrd_mb for r in rows)
    worst_cal = max(r.calibrate_s or 0.0 for r in calibrated)
    worst_cal_cpu = max(r.calibrate_cpu_s or 0.0 for r in calibrated)

    def met(ok: bool) -> str:
        return "yes" if ok else "**no**"

    per_robot = [
        (r.robot, r.mean_error <= 0.5, r.mean_error <= 1.1 * plain[r.robot].mean_error,
         r.inside >= 0.8 * r.mapped, r.semi_major < 1.5)
        for r in calibrated
    ]  # fmt: skip
    lines += [
        "",
        "| target | measured | met |",
        "|---|---|---|",
        f"| end to end <= 3 s per replay | {worst_s:.2f} s (slowest) | {met(worst_s <= 3)} |",
        f"| CPU <= 3 s per replay | {worst_cpu:.2f} s (most) | {met(worst_cpu <= 3)} |",
        f"| recording <= 10 MB per robot | {worst_mb:.2f} MB (largest) | {met(worst_mb <= 10)} |",
        f"| calibrate <= 30 s per robot | {worst_cal:.1f} s, CPU {worst_cal_cpu:.1f} s (slowest)"
        f" | {met(worst_cal <= 30)} |",
        *(
            f"| robot {robot}: calibrated error <= 0.5 m, <= 1.1x the defaults', >= 80 %"
            f" inside 3σ, 3σ axis < 1.5 m | see the table | {met(a)}, {met(b)}, {met(c)},"
            f" {met(d)} |"
            for robot, a, b, c, d in per_robot
        ),
        "",
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
