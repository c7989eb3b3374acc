"""The watch part of ``make bench``: from a save of a course module to its run complete in
the viewer, and from Ctrl-C to the end of ``ekfviz watch``.

``ekfviz watch MODULE LOG --connect URL --report REPORT`` runs as a child process, its
recordings sent to Rerun's viewer program run as a gRPC server without a window (``rerun
--port N --save FILE``: it takes every recording as a viewer does). The module is the
course skeleton (``examples/course_skeleton/ekf_slam.py``), copied to a folder of its
own; the log is the course's ``hw2_data.txt`` (``$EKFVIZ_COURSE_LOG``, else
``shared/reference/hw2_data.txt`` in the nearest folder above this file that has one),
else the bundled ``data/classic.txt`` (the table says which).

A *save* writes the module anew (a comment with a counter appended); the run is complete
in the viewer once the report's ``run`` counter has moved on: the watch writes its report
after the run's recording was sent and flushed to every sink. The time of one save is
from just before the write to the report's change (looked at every 2 ms); the median and
the worst of :data:`SAVES` saves are reported, each save made once the run before is
complete. *Ctrl-C* is SIGINT to the watch's process group while it waits for a save, to
its exit (median of :data:`STOPS`).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

BEGIN, END = "<!-- watch:begin -->", "<!-- watch:end -->"
ROOT = Path(__file__).resolve().parents[1]
SKELETON = ROOT / "examples" / "course_skeleton" / "ekf_slam.py"
SAVES = 10
STOPS = 3
TARGET_S = 1.0  # a save to its run complete in the viewer
POLL_S = 0.002
START_TIMEOUT_S = 120.0


@dataclass(frozen=True, slots=True)
class WatchTimes:
    log: str
    saves_s: list[float]
    stops_s: list[float]


def course_log() -> Path:
    """The course's log (see the module), else the bundled classic sample."""
    given = os.environ.get("EKFVIZ_COURSE_LOG")
    if given:
        return Path(given)
    for parent in Path(__file__).resolve().parents:
        candidate = parent / "shared" / "reference" / "hw2_data.txt"
        if candidate.is_file():
            return candidate
    return ROOT / "data" / "classic.txt"


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _run_of(report: Path) -> int:
    try:
        return int(json.loads(report.read_text())["run"])
    except (OSError, ValueError, KeyError):  # not written yet, or being replaced
        return 0


def _wait_for_run(report: Path, run: int, process: subprocess.Popen[bytes]) -> float:
    """Wait until the report says run ``run``; the time it was seen."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while _run_of(report) < run:
        if process.poll() is not None:
            raise RuntimeError(f"ekfviz watch ended (exit {process.returncode})")
        if time.monotonic() > deadline:
            raise RuntimeError(f"run {run} did not come within {START_TIMEOUT_S:g} s")
        time.sleep(POLL_S)
    return time.perf_counter()


def _viewer(folder: Path, port: int) -> subprocess.Popen[bytes]:
    """Rerun's viewer program as a gRPC server writing what it takes to a file."""
    rerun = Path(sys.executable).with_name("rerun")
    server = subprocess.Popen(
        [str(rerun), "--port", str(port), "--save", str(folder / "viewer.rrd")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return server
        except OSError:
            if time.monotonic() > deadline or server.poll() is not None:
                raise RuntimeError("the Rerun server did not start") from None
            time.sleep(0.05)


def time_watch(folder: Path, log: Path) -> WatchTimes:
    """Time :data:`SAVES` saves, then the watch's end at Ctrl-C, :data:`STOPS` times."""
    saves: list[float] = []
    stops: list[float] = []
    module = folder / "ekf_slam.py"
    source = SKELETON.read_text()
    for attempt in range(STOPS):  # the saves timed in the first watch only
        shutil.copy(SKELETON, module)
        report = folder / f"latest{attempt}.json"
        port = _free_port()
        server = _viewer(folder, port)
        watch = subprocess.Popen(
            [sys.executable, "-m", "ekfviz", "watch", str(module), str(log), "--connect",
             f"rerun+http://127.0.0.1:{port}/proxy", "--report", str(report)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
        )  # fmt: skip
        try:
            _wait_for_run(report, 1, watch)
            for k in range(SAVES if attempt == 0 else 0):
                started = time.perf_counter()
                module.write_text(f"{source}\n# save {k}\n")
                saves.append(_wait_for_run(report, k + 2, watch) - started)
            time.sleep(0.5)  # waiting for a save, as a user's watch mostly is
            sent = time.perf_counter()
            os.killpg(watch.pid, signal.SIGINT)
            watch.wait(timeout=60)
            stops.append(time.perf_counter() - sent)
        finally:
            for process in (watch, server):
                if process.poll() is None:
                    os.killpg(process.pid, signal.SIGKILL)
                    process.wait()
    return WatchTimes(log.name, saves, stops)


def watch_section(folder: Path) -> str:
    """The section of RESULTS.md."""
    log = course_log()
    work = folder / "watch"
    work.mkdir(exist_ok=True)
    load = os.getloadavg()[0]  # (other people's work on the machine slows every run)
    times = time_watch(work, log)
    save, worst = statistics.median(times.saves_s), max(times.saves_s)
    stop = statistics.median(times.stops_s)
    verdict = "met" if save <= TARGET_S else "missed"
    return "\n".join([
        BEGIN,
        "## Watch: a save to its run in the viewer",
        "",
        f"`ekfviz watch` of the course skeleton on `{times.log}`, its recordings sent to"
        " Rerun's gRPC server (`--connect`); a save is the module written anew, its run"
        " complete once the report's `run` counter moves (the report is written after"
        " the recording was flushed to the viewer). Medians of the runs; target: a save"
        f" to its run complete within {TARGET_S:g} s ({verdict}). The machine's load"
        f" average when it started: {load:.1f} on {os.cpu_count()} cores.",
        "",
        "| what | median (s) | worst (s) | runs |",
        "|---|---:|---:|---:|",
        f"| save to run complete in the viewer | {save:.3f} | {worst:.3f} |"
        f" {len(times.saves_s)} |",
        f"| Ctrl-C to the watch's exit | {stop:.3f} | {max(times.stops_s):.3f} |"
        f" {len(times.stops_s)} |",
        END,
    ])  # fmt: skip


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        print(watch_section(Path(tmp)))
