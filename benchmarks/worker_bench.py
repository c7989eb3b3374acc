"""The worker part of ``make bench``: a user's filter in its worker process against the
same filter imported into ekfviz's process, end to end through the runner.

The filter is ``examples/my_filter.py:MyFilter`` (a dense protocol class, as users
write them). Both ways run the same events through :func:`ekfviz.runner.replay.replay`
(state checks, derived observations, batches; no recording), timed from the first event
to the last (the worker's start and the module's import are reported apart).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.params import FilterParams
from ekfviz.core.records import LogEvent
from ekfviz.filters.spec import load_filter, load_in_process
from ekfviz.runner.replay import replay

BEGIN, END = "<!-- worker:begin -->", "<!-- worker:end -->"
FILTER = str(Path(__file__).resolve().parent.parent / "examples" / "my_filter.py") + ":MyFilter"
REPEATS = 3


@dataclass(frozen=True, slots=True)
class WorkerRow:
    n: int
    seen: int
    events: int
    in_process_s: float
    worker_s: float
    start_s: float

    @property
    def ratio(self) -> float:
        return self.worker_s / self.in_process_s


def _timed(events: Sequence[LogEvent], make: object) -> float:
    started = time.perf_counter()
    for _ in replay(events, FilterParams(), make_filter=make, name="MyFilter"):  # type: ignore[arg-type]
        pass
    return time.perf_counter() - started


def worker_rows(worlds: Sequence[tuple[int, int, list[LogEvent]]]) -> list[WorkerRow]:
    """One row per (N, landmarks seen per step, events): medians of :data:`REPEATS`."""
    in_process = load_in_process(FILTER)
    rows = []
    for n, seen, events in worlds:
        local = statistics.median(_timed(events, in_process) for _ in range(REPEATS))
        remote, starts = [], []
        for _ in range(REPEATS):
            started = time.perf_counter()
            factory = load_filter(FILTER)  # starts the worker and imports the module
            starts.append(time.perf_counter() - started)
            remote.append(_timed(events, factory))
            factory.close()  # type: ignore[attr-defined]
        rows.append(WorkerRow(n, seen, len(events), local, statistics.median(remote),
                              statistics.median(starts)))  # fmt: skip
    return rows


def worker_section(worlds: Sequence[tuple[int, int, list[LogEvent]]]) -> str:
    rows = worker_rows(worlds)
    lines = [
        BEGIN,
        "## A user's filter in its worker",
        "",
        f"`{Path(FILTER).name}` through the runner (state checks, derived observations,"
        " batches; no recording): in ekfviz's process (imported) against its worker"
        " process (the state crossing as raw buffers every event). Seconds from the first"
        f" event to the last, median of {REPEATS}; the worker's start (an interpreter,"
        " numpy, the module's import) apart. Target: at most 1.2x at N = 300.",
        "",
        "| N | seen a step | events | in process s | worker s | worker / in process |"
        " worker start s | verdict |",
        "|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        verdict = "" if row.n < 300 else ("met" if row.ratio <= 1.2 else "**missed**")
        lines.append(
            f"| {row.n} | {row.seen} | {row.events} | {row.in_process_s:.3f} |"
            f" {row.worker_s:.3f} | {row.ratio:.2f}x | {row.start_s:.3f} | {verdict} |"
        )
    lines.append(END)
    return "\n".join(lines)
