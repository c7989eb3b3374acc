"""The smoother part of ``make bench``: GTSAM's iSAM2 and the batch optimum beside the EKF.

End to end, as a user runs them (``ekfviz replay LOG --filter F --truth T --save RUN.rrd``
as a subprocess: process start, imports, reading, the filter, the recording), on the
bundled samples: the classic sample with ``ekf`` and ``isam2`` (target: iSAM2 at most 2x
the EKF), and the loop sample (1000 steps, 200 landmarks) with ``isam2`` (at most 60 s)
and ``batch`` (at most 30 s), with the loop's true noise. Each run is repeated; the table
gives the median wall time, the CPU time and, with truth, how consistent each filter was.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

BIN = Path(sys.executable).parent
DATA = Path(__file__).resolve().parents[1] / "data"
BEGIN, END = "<!-- smoother:begin -->", "<!-- smoother:end -->"
LOOP_NOISE = ("--sigma-x", "0.01935", "--sigma-y", "0.009675", "--sigma-alpha", "0.001935",
              "--init-pose-sigma", "0.01", "0.01", "0.005")  # fmt: skip


@dataclass(frozen=True, slots=True)
class Row:
    log: str
    filter: str
    wall_s: float
    cpu_s: float
    rrd_mb: float
    inside: str  # landmarks inside 3 sigma
    nees_inside: float | None


def _replay(log: str, filter_name: str, extra: Sequence[str], folder: Path, repeats: int) -> Row:
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    recording, report = folder / f"{log}-{filter_name}.rrd", folder / "report.json"
    command = [str(BIN / "ekfviz"), "replay", str(DATA / f"{log}.txt"), "--truth",
               str(DATA / f"{log}_truth.json"), "--filter", filter_name, "--save",
               str(recording), "--report", str(report), *extra]  # fmt: skip
    walls, cpus = [], []
    for _ in range(repeats):
        before = os.times()
        started = time.perf_counter()
        subprocess.run(command, env=env, check=True, capture_output=True)
        walls.append(time.perf_counter() - started)
        after = os.times()
        cpus.append(
            after.children_user + after.children_system
            - before.children_user - before.children_system
        )  # fmt: skip
    found = json.loads(report.read_text())
    landmarks = found["landmarks"]
    inside = sum(bool(entry.get("inside_3sigma")) for entry in landmarks)
    nees = found.get("consistency", {}).get("nees", {})
    return Row(
        log=log,
        filter=filter_name,
        wall_s=statistics.median(walls),
        cpu_s=statistics.median(cpus),
        rrd_mb=recording.stat().st_size / 1e6,
        inside=f"{inside}/{len(landmarks)}",
        nees_inside=nees.get("fraction_inside"),
    )


def smoother_section(folder: Path, quick: bool = False) -> str:
    """The section of RESULTS.md, between its markers."""
    print("smoothers: classic", flush=True)
    classic = [_replay("classic", name, (), folder, 1 if quick else 3) for name in ("ekf", "isam2")]
    print("smoothers: loop", flush=True)
    loop = [
        _replay("loop", name, LOOP_NOISE, folder, 1)
        for name in (("ekf", "batch") if quick else ("ekf", "isam2", "batch"))
    ]
    ratio = classic[1].wall_s / classic[0].wall_s
    lines = [
        BEGIN,
        "## Smoothers: GTSAM's iSAM2 and the batch optimum",
        "",
        "`ekfviz replay LOG --truth T --filter F --save RUN.rrd` as a subprocess on the bundled"
        " samples (median of 3 on classic, 1 on loop; CPU time is the child's user + system)."
        " The loop runs with its true noise.",
        "",
        "| log | filter | wall s | CPU s | .rrd MB | landmarks in 3σ | NEES steps in 95% |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for row in classic + loop:
        nees = "-" if row.nees_inside is None else f"{row.nees_inside:.1%}"
        lines.append(
            f"| {row.log} | {row.filter} | {row.wall_s:.2f} | {row.cpu_s:.2f} | {row.rrd_mb:.1f}"
            f" | {row.inside} | {nees} |"
        )
    by_name = {row.filter: row for row in loop}
    checks = [
        ("iSAM2 on the classic sample at most 2x the EKF end to end", f"{ratio:.2f}x",
         ratio <= 2.0),
    ]  # fmt: skip
    if "isam2" in by_name:
        wall = by_name["isam2"].wall_s
        checks.append(("iSAM2 on the loop sample at most 60 s", f"{wall:.1f} s", wall <= 60.0))
    wall = by_name["batch"].wall_s
    checks.append(("batch on the loop sample at most 30 s", f"{wall:.1f} s", wall <= 30.0))
    lines += ["", "| target | measured | met |", "|---|---|---|"]
    lines += [f"| {what} | {value} | {'yes' if ok else '**no**'} |" for what, value, ok in checks]
    lines.append(END)
    return "\n".join(lines)
