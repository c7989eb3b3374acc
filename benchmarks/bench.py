"""ekfviz's benchmarks, in one run on one machine: ``make bench`` (not part of ``make test``).

    .venv/bin/python benchmarks/bench.py [--quick] [--out benchmarks/RESULTS.md]

1. The core (``EkfSlam.predict`` and ``observe``, sequential updates) against the dense
   textbook filter of ``textbook_ekf.py`` for N = 6, 50, 200, 1000, 2000 landmarks, all
   of them or 10 of them observed per step; both sides with one BLAS thread. Where the
   compiled kernel of small maps runs, the core is timed without it too.
2. The memory-bandwidth bound: one read-and-write pass over an array the size of P,
   and the core's time per observed landmark as a multiple of it.
3. End to end: ``ekfviz replay LOG --save RUN.rrd`` as a subprocess (process start,
   imports, reading, filtering, logging and writing included) with wall time, peak
   resident memory and ``.rrd`` size, for the classic sample, a simulated loop of 10,000
   steps among 300 landmarks, a classic-size log of 100,000 steps and the classic route
   among 200 landmarks; the dense filter's arithmetic on the same classic-format files.
4. Where a long replay's time goes: reading, the filter, the batches and checks, and
   the logging (in the main thread, and the CPU of Rerun's own threads with it).
5. The interpreter plus ``import rerun, numpy, typer``, which every replay pays, and the
   import of the compiled kernel.
6. Real data (``mrclam_bench.py``): MRCLAM dataset 6, all five robots, calibrated and
   replayed beside the defaults against the targets of real data; skipped with a note when the
   dataset is not found. ``--mrclam-only`` runs just this and replaces its section of RESULTS.md.
7. Smoothers (``smoother_bench.py``): GTSAM's iSAM2 and the batch optimum against the EKF,
   end to end on the bundled samples; ``--smoother-only`` runs just this.
8. Association (``association_bench.py``): the Victoria Park run end to end (time,
   landmarks, RMSE against GPS read back from the recording) and simulated id-less
   two-lap runs with clutter judged against the association's targets; ``--association-only`` runs
   just this.
9. Start-up (``startup_bench.py``): replay, check, compare and consistency on the classic
   sample, each one's start-up (to its first event) and wrap-up (after its last) apart,
   beside ``import rerun, numpy, typer`` in the same run; ``--startup-only`` runs just this.
10. Scaling (``scaling_bench.py``): end-to-end time and peak memory against the log's
   length (10,000 to 1,000,000 classic-size steps) and the map's size (N = 10 ... 2000,
   10 observed), drawn as ``scaling_length.png`` and ``scaling_map.png`` beside
   RESULTS.md; ``--scaling-only`` runs just this (the 1,000,000-step run alone takes a
   few minutes; ``--quick`` leaves it out).
11. Targets (``targets_bench.py``): the three speed targets measured together in
   one run (the classic sample against the imports, a 102,000-step log, Victoria Park);
   ``--targets-only`` runs just this.
12. The sandbox (``sandbox_bench.py``): a submission's worker started in its sandbox
   against without it, and ``grade`` of 30 submissions with and without the sandbox;
   ``--sandbox-only`` runs just this.
13. Watch (``watch_bench.py``): ``ekfviz watch`` of the course skeleton, from a save to
   its run complete in the viewer (the median of 10 saves, target 1 s), and from Ctrl-C
   to its end; ``--watch-only`` runs just this.
14. Instructions (``instructions_bench.py``): the instructions each of the targets'
   replays executes, counted by Valgrind, now and (``--before CLONE``) before: a
   difference of a few per cent that wall time on a shared machine cannot tell;
   ``--instructions-only`` runs just this (about half an hour; not part of a whole run).

It prints the tables and writes them, with the machine, the date and the command, to
``benchmarks/RESULTS.md``. Timings are medians (bounds: best) of repeated runs; where
the dense filter would take minutes, it is timed on a few steps or estimated from its
parts (one predict and one landmark update), as the table says.
"""

from __future__ import annotations

import os

# both sides single-threaded, here and in the subprocesses
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["OMP_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"

import argparse
import datetime
import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import ekfviz
from ekfviz.core.batch import PREDICT, UPDATE, BatchBuilder
from ekfviz.core.params import FilterParams, UpdateMode
from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.filters.ekf import HAVE_KERNEL, KERNEL_MAX_DIM, EkfSlam
from ekfviz.io.classic import format_classic, read_classic
from ekfviz.runner.batches import BATCH_EVENTS
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, Noise, classic_controls, simulate

sys.path.insert(0, str(Path(__file__).parent))
from association_bench import association_section
from mrclam_bench import mrclam_section, splice
from sandbox_bench import sandbox_section
from scaling_bench import scaling_section
from smoother_bench import smoother_section
from startup_bench import startup_section
from textbook_ekf import TextbookEkfSlam
from watch_bench import watch_section
from worker_bench import worker_section

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
SIZES = (6, 50, 200, 1000, 2000)
SEEN = 10  # landmarks observed per step in the partial case


# -- timing helpers ----------------------------------------------------------------------


def best_of(run: Callable[[], object], repeats: int) -> float:
    """Smallest wall time of ``repeats`` calls, in seconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def one_pass_bound(dim: int, repeats: int = 7) -> float:
    """Seconds for one read-and-write pass over a dim x dim float64 array (best of)."""
    array = np.ones((dim, dim))
    return best_of(lambda: np.multiply(array, 1.0, out=array), repeats)


def dgemm_flops() -> float:
    """Floating-point operations per second of a square matrix product (one thread)."""
    a, b = np.ones((1500, 1500)), np.ones((1500, 1500))
    return 2 * 1500**3 / best_of(lambda: a @ b, 5)


# -- core against dense ------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class World:
    """The first sighting of all N landmarks, then (control, sighting) steps."""

    n: int
    first: Sighting
    steps: list[tuple[Control, Sighting]]

    @property
    def seen(self) -> int:
        return len(self.steps[0][1].ids)


def make_world(n: int, seen: int | None, steps: int, seed: int = 1) -> World:
    """N landmarks around a robot driving a circle, all seen at the start; then all, or
    ``seen`` of them (a different random choice each step), per step."""
    rng = np.random.default_rng(seed)
    if n == 6:
        landmarks_xy, controls = CLASSIC_LANDMARKS_XY, np.tile(classic_controls(), (2, 1))
    else:
        landmarks_xy = rng.uniform(-25.0, 25.0, size=(n, 2))
        controls = np.tile([[1.0, 0.1]], (steps, 1))
    run = simulate(controls[:steps], landmarks_xy, Noise(), seed=seed)
    first = run.events[0]
    assert isinstance(first, Sighting)
    pairs: list[tuple[Control, Sighting]] = []
    for control, sighting in zip(run.events[1::2], run.events[2::2], strict=True):
        assert isinstance(control, Control) and isinstance(sighting, Sighting)
        if seen is not None and seen < n:
            pick = rng.choice(n, size=seen, replace=False)
            sighting = Sighting(sighting.line, sighting.ids[pick], sighting.z[pick])
        pairs.append((control, sighting))
    return World(n, first, pairs)


def time_core(
    world: World, params: FilterParams, compiled: bool = True
) -> tuple[list[float], list[float]]:
    """Seconds per step of predict + observe, and of appending the state after each of
    the two to a batch as a replay does (the batch built every ``BATCH_EVENTS`` events,
    its share counted at every step)."""
    ekf = EkfSlam(params, compiled=compiled)
    ekf.observe(world.first.ids, world.first.z)
    filtering, recording = [], []
    builder = BatchBuilder()
    for control, sighting in world.steps:
        start = time.perf_counter()
        ekf.predict(control.d, control.alpha)
        middle = time.perf_counter()
        builder.add(ekf.state_parts(), event=1, step=1, kind=PREDICT, control=(control.d, 0.0))
        after_predict = time.perf_counter()
        observations = ekf.observe(sighting.ids, sighting.z)
        after_update = time.perf_counter()
        builder.add(ekf.state_parts(), event=2, step=1, kind=UPDATE, observations=observations)
        if len(builder) >= BATCH_EVENTS:
            builder.build()
        end = time.perf_counter()
        filtering.append((middle - start) + (after_update - after_predict))
        recording.append((after_predict - middle) + (end - after_update))
    return filtering, recording


def dense_filter(world: World) -> TextbookEkfSlam:
    params = FilterParams()
    dense = TextbookEkfSlam(world.n, params.Q, params.R, params.init_pose_sigma)
    dense.initialise(world.first.z)
    return dense


def time_dense_steps(world: World, steps: int) -> list[float]:
    """Seconds per step of the dense filter, measured on the first ``steps`` steps."""
    dense = dense_filter(world)
    times = []
    for control, sighting in world.steps[:steps]:
        start = time.perf_counter()
        dense.predict(control.d, control.alpha)
        dense.update(sighting.z, (sighting.ids - 1).tolist())
        times.append(time.perf_counter() - start)
    return times


_PARTS: dict[int, tuple[float, float]] = {}


def time_dense_parts(world: World) -> tuple[float, float]:
    """Seconds of one dense predict and of one dense single-landmark update (per N)."""
    if world.n in _PARTS:
        return _PARTS[world.n]
    dense = dense_filter(world)
    control, sighting = world.steps[0]
    start = time.perf_counter()
    dense.predict(control.d, control.alpha)
    predict = time.perf_counter() - start
    start = time.perf_counter()
    dense.update(sighting.z[:1], [int(sighting.ids[0]) - 1])
    _PARTS[world.n] = predict, time.perf_counter() - start
    return _PARTS[world.n]


@dataclass(frozen=True, slots=True)
class CoreRow:
    n: int
    seen: int
    core_ms: float
    batch_ms: float
    dense_ms: float
    dense_basis: str
    bound_ms: float
    mode: str = "sequential"
    numpy_ms: float | None = None  # the core without the compiled kernel, where it runs

    @property
    def ratio(self) -> float:
        return self.dense_ms / self.core_ms

    @property
    def per_landmark_over_bound(self) -> float:
        return self.core_ms / self.seen / self.bound_ms


def core_rows(quick: bool) -> list[CoreRow]:
    rows: list[CoreRow] = []
    sizes = SIZES[:3] if quick else SIZES
    for n in sizes:
        for seen in (n,) if n <= SEEN else (n, SEEN):
            rows.append(core_row(n, seen, quick))
            print(f"  core N={n:5d} seen {seen:5d}: {rows[-1].core_ms:10.3f} ms/step", flush=True)
    for n in (1000, 2000) if not quick else ():
        rows.append(core_row(n, SEEN, quick, UpdateMode.JOINT))
        print(f"  core N={n:5d} seen {SEEN:5d} joint: {rows[-1].core_ms:10.3f} ms/step", flush=True)
    return rows


_DENSE: dict[tuple[int, int], tuple[float, str]] = {}  # (N, observed) -> seconds, how


def core_row(n: int, seen: int, quick: bool, mode: UpdateMode = UpdateMode.SEQUENTIAL) -> CoreRow:
    all_seen = seen == n
    big = n >= 1000
    core_steps = (2 if n == 2000 else 3) if (big and all_seen) else (10 if big else 29)
    world = make_world(n, None if all_seen else seen, max(core_steps, 10 if quick else 20))
    params = FilterParams(update=mode)
    # the classic: the whole route, many times over, for a stable median
    runs = [time_core(world, params) for _ in range(20 if n == 6 else 1)]
    core = statistics.median(statistics.median(filtering) for filtering, _ in runs)
    batched = statistics.median(statistics.median(recording) for _, recording in runs)
    numpy_ms = None
    if HAVE_KERNEL and 3 + 2 * n < KERNEL_MAX_DIM and mode is UpdateMode.SEQUENTIAL:
        numpy_runs = [time_core(world, params, False) for _ in range(20 if n == 6 else 1)]
        numpy_ms = 1e3 * statistics.median(statistics.median(f) for f, _ in numpy_runs)
    if (n, seen) in _DENSE:
        dense, basis = _DENSE[n, seen]
    elif n <= 200:
        dense_steps = 3 if (n == 200 and all_seen) else 20
        dense = statistics.median(time_dense_steps(world, dense_steps))
        basis = f"measured, {dense_steps} steps"
        if n == 6:
            dense = statistics.median(
                [statistics.median(time_dense_steps(world, 29)) for _ in range(20)]
            )
            basis = "measured, 20 x 29 steps"
    elif n == 1000 and not all_seen and not quick:
        dense = statistics.median(time_dense_steps(world, 1))
        basis = "measured, 1 step"
    else:
        predict, update = time_dense_parts(world)
        dense = predict + seen * update
        basis = f"estimated: 1 predict + {seen} x 1 update"
    _DENSE[n, seen] = dense, basis
    bound = one_pass_bound(3 + 2 * n)
    return CoreRow(
        n=n,
        seen=seen,
        core_ms=1e3 * core,
        batch_ms=1e3 * batched,
        dense_ms=1e3 * dense,
        dense_basis=basis,
        bound_ms=1e3 * bound,
        mode=mode.value,
        numpy_ms=numpy_ms,
    )


# -- end to end --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class EndToEnd:
    name: str
    lines: int
    wall_s: float
    peak_mb: float
    rrd_mb: float
    dense_s: float | None  # the dense filter's arithmetic on the same file, if classic


def run_replay(log: Path, folder: Path, extra: Sequence[str] = ()) -> tuple[float, float, float]:
    """Wall seconds, peak resident MB and .rrd MB of ``ekfviz replay LOG --save``."""
    recording = folder / f"{log.stem}.rrd"
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    command = [str(BIN / "ekfviz"), "replay", str(log), "--save", str(recording), *extra]
    errors = folder / "stderr.txt"
    with errors.open("w") as stderr:
        start = time.perf_counter()
        process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=stderr)
        _, status, usage = os.wait4(process.pid, 0)  # this child's own peak memory
        wall = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{errors.read_text()}")
    return wall, usage.ru_maxrss / 1024.0, recording.stat().st_size / 1e6


def dense_on_file(log: Path) -> float:
    """Seconds of the dense filter's arithmetic over a classic log (no start-up, no I/O)."""
    events = list(read_classic(log))
    first = events[0]
    assert isinstance(first, Sighting)
    params = FilterParams()
    start = time.perf_counter()
    TextbookEkfSlam(len(first.ids), params.Q, params.R, params.init_pose_sigma).run(events)
    return time.perf_counter() - start


def make_logs(folder: Path, quick: bool) -> list[tuple[str, Path, bool]]:
    """(name, log, classic format) of the end-to-end cases, written to ``folder``."""
    logs: list[tuple[str, Path, bool]] = [
        ("classic sample (data/classic.txt)", ROOT / "data" / "classic.txt", True)
    ]
    steps = 1000 if quick else 10_000
    loop = folder / "loop.txt"
    subprocess.run(
        [str(BIN / "ekfviz"), "simulate", "--scenario", "loop", "--steps", str(steps),
         "--landmarks", "300", "--seed", "1", "-o", str(loop),
         "--truth-out", str(folder / "loop_truth.json")],
        check=True, stdout=subprocess.DEVNULL,
        env=dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder)),
    )  # fmt: skip
    logs.append((f"loop, {steps:,} steps x 300 landmarks", loop, False))
    # the classic route again and again; the truth a quieter robot than the filter assumes,
    # so that it stays among the six landmarks for all those laps
    long_steps = 10_000 if quick else 100_000
    controls = np.tile(classic_controls(), (long_steps // 29 + 1, 1))[:long_steps]
    quiet = Noise(sigma_x=0.05, sigma_y=0.02, sigma_alpha=0.005)
    long_log = folder / "classic_long.txt"
    long_log.write_text(
        format_classic(simulate(controls, CLASSIC_LANDMARKS_XY, quiet, seed=3).events, 4)
    )
    logs.append((f"classic size, {long_steps:,} steps", long_log, True))
    rng = np.random.default_rng(200)  # the former bench_replay.py
    landmarks = rng.uniform([-4.0, -4.0], [16.0, 20.0], size=(200, 2))
    wide = folder / "classic200.txt"
    wide.write_text(format_classic(simulate(classic_controls(), landmarks, seed=200).events, 6))
    logs.append(("classic route, 200 landmarks all seen", wide, True))
    return logs


def end_to_end(folder: Path, quick: bool) -> list[EndToEnd]:
    rows = []
    for name, log, classic in make_logs(folder, quick):
        lines = sum(1 for _ in log.open())
        repeats = 3 if lines < 1000 else 1
        results = [run_replay(log, folder) for _ in range(repeats)]
        wall = statistics.median(r[0] for r in results)
        peak = max(r[1] for r in results)
        rrd = results[-1][2]
        dense = dense_on_file(log) if classic else None
        rows.append(EndToEnd(name, lines, wall, peak, rrd, dense))
        print(f"  {name}: {wall:.2f} s, {peak:.0f} MB, .rrd {rrd:.1f} MB", flush=True)
    return rows


# Recording sizes of an earlier ekfviz (commit 9b3d7d7, before recordings were made
# smaller), same commands:
# bytes of the bundled samples replayed with their truth, MB of the 100,000-step log.
# data/loop.txt was regenerated since (seed 0, a noise header): its number is 9b3d7d7's
# code run on the current sample (7,791,198 bytes on the sample of then).
SIZE_BEFORE = {"classic": 475_318, "loop": 7_027_991}
LONG_RRD_MB_BEFORE = 287.0


@dataclass(frozen=True, slots=True)
class Size:
    """A recording's size now and before, and where its bytes go."""

    name: str
    bytes_now: int
    bytes_before: int


def sample_sizes(folder: Path) -> list[Size]:
    """`ekfviz replay data/<sample>.txt --truth data/<sample>_truth.json --save`."""
    sizes = []
    for stem, before in SIZE_BEFORE.items():
        truth = ROOT / "data" / f"{stem}_truth.json"
        recording = folder / f"sample_{stem}.rrd"
        subprocess.run(
            [str(BIN / "ekfviz"), "replay", str(ROOT / "data" / f"{stem}.txt"), "--truth",
             str(truth), "--save", str(recording)],
            check=True, stdout=subprocess.DEVNULL,
            env=dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder)),
        )  # fmt: skip
        sizes.append(Size(f"data/{stem}.txt with truth", recording.stat().st_size, before))
    return sizes


def bytes_by_entity(recording: Path, top: int = 12) -> list[tuple[str, float]]:
    """MB of each entity's chunks as the file holds them, largest first: where a
    recording's bytes go (`rerun rrd stats` gives the totals only).

    Each chunk is written as Rerun does, an Arrow IPC stream (schema, row ids, time
    columns, data) compressed as one LZ4 block: within a few bytes of its message in
    the file.
    """
    from collections import Counter

    import pyarrow as pa  # type: ignore[import-untyped]
    from rerun.chunk import RrdReader

    reader = RrdReader(recording)
    sizes: Counter[str] = Counter()
    for chunk in reader.stream(store=reader.recordings()[0]):
        batch = chunk.to_record_batch()
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, batch.schema) as writer:
            writer.write_batch(batch)
        compressed = pa.compress(sink.getvalue(), codec="lz4_raw", asbytes=True)
        sizes[chunk.entity_path] += len(compressed)
    return [(entity, size / 1e6) for entity, size in sizes.most_common(top)]


@dataclass(frozen=True, slots=True)
class Memory:
    """Peak resident memory of a replay of the first ``steps`` steps of the long log."""

    steps: int
    log_mb: float
    core_mb: float  # reading, filter, batches and consistency; no recording
    end_to_end_mb: float  # `ekfviz replay --save`
    rrd_mb: float


CORE_ONLY = """
import sys
from pathlib import Path
from ekfviz.evaluation.consistency import Consistency
from ekfviz.runner.replay import replay
from ekfviz.io.extended import read_log
consistency = Consistency()
for batch in replay(read_log(Path(sys.argv[1]))):
    consistency.add(batch)
# VmHWM, not ru_maxrss: that counts what the process held before exec, as bench's fork
print(next(int(line.split()[1]) / 1024.0 for line in open("/proc/self/status")
           if line.startswith("VmHWM")))
"""
# `ekfviz replay` run by a small Python, so that its peak is not that of this process
END_TO_END_PEAK = """
import resource, subprocess, sys
subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL)
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0)
"""


def memory_rows(folder: Path, long_log: Path) -> list[Memory]:
    """Peak memory against the log's length: the long log and its first tenth."""
    lines = long_log.read_text().splitlines(keepends=True)
    short_log = folder / "classic_tenth.txt"
    short_log.write_text("".join(lines[: len(lines) // 10 + 1]))
    rows = []
    for log in (short_log, long_log):
        core = subprocess.run(
            [sys.executable, "-c", CORE_ONLY, str(log)],
            check=True, capture_output=True, text=True,
        )  # fmt: skip
        recording = folder / "memory.rrd"
        env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
        end_to_end = subprocess.run(
            [sys.executable, "-c", END_TO_END_PEAK, str(BIN / "ekfviz"), "replay", str(log),
             "--save", str(recording)],
            check=True, capture_output=True, text=True, env=env,
        )  # fmt: skip
        peak, rrd = float(end_to_end.stdout), recording.stat().st_size / 1e6
        steps = (sum(1 for _ in log.open()) - 1) // 2
        rows.append(Memory(steps, log.stat().st_size / 1e6, float(core.stdout), peak, rrd))
        print(f"  {steps:,} steps: core {float(core.stdout):.0f} MB, end to end {peak:.0f} MB")
    return rows


@dataclass(frozen=True, slots=True)
class Phases:
    """Where the time of a replay with a recording goes, in one process (seconds)."""

    name: str
    events: int
    read_s: float  # the log into events
    filter_s: float  # predict and observe alone, no batches
    core_s: float  # the replay: filter, batches and covariance checks
    logging_s: float  # Recorder.log, finish and the flush, in the main thread
    rerun_cpu_s: float  # CPU of Rerun's own threads (encoding, writing) meanwhile

    @property
    def logging_over_filter(self) -> float:
        return self.logging_s / self.filter_s


PHASES = """
import json, sys, time
from pathlib import Path
import rerun as rr
from ekfviz.filters.ekf import EkfSlam
from ekfviz.core.records import Control
from ekfviz.runner.replay import replay
from ekfviz.io.extended import read_log
from ekfviz.viz.recorder import Recorder
start = time.perf_counter()
events = list(read_log(Path(sys.argv[1])))
read = time.perf_counter() - start
ekf = EkfSlam()
start = time.perf_counter()
for event in events:
    if isinstance(event, Control):
        ekf.predict(event.d, event.alpha)
    else:
        ekf.observe(event.ids, event.z)
filtering = time.perf_counter() - start
rec = rr.RecordingStream("ekfviz", recording_id="bench")
rec.save(sys.argv[2])
recorder = Recorder(rec)
logging = 0.0
start, cpu, main_cpu = time.perf_counter(), time.process_time(), time.thread_time()
for batch in replay(events):
    begin = time.perf_counter()
    recorder.log(batch)
    logging += time.perf_counter() - begin
begin = time.perf_counter()
recorder.finish()
rec.flush(timeout_sec=600.0)
rec.disconnect()
logging += time.perf_counter() - begin
total = time.perf_counter() - start
rerun_cpu = (time.process_time() - cpu) - (time.thread_time() - main_cpu)
print(json.dumps([len(events), read, filtering, total - logging, logging, rerun_cpu]))
"""


def phase_rows(folder: Path, logs: Sequence[tuple[str, Path]]) -> list[Phases]:
    """Reading, filter, batches and logging of each log, timed apart in a child process."""
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    rows = []
    for name, log in logs:
        out = subprocess.run(
            [sys.executable, "-c", PHASES, str(log), str(folder / "phases.rrd")],
            check=True, capture_output=True, text=True, env=env,
        )  # fmt: skip
        events, *seconds = json.loads(out.stdout)
        rows.append(Phases(name, int(events), *seconds))
        print(f"  {name}: {rows[-1]}", flush=True)
    return rows


def kernel_import_us() -> float | None:
    """Microseconds of ``import ekfviz.filters._kernel`` (``-X importtime``), if built."""
    if not HAVE_KERNEL:
        return None
    out = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", "import ekfviz.filters._kernel"],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    # "import time: self [us] | cumulative | imported package"
    return next(
        float(line.split("|")[0].split(":")[1])
        for line in out.stderr.splitlines()
        if line.rstrip().endswith("ekfviz.filters._kernel")
    )


def startup() -> tuple[float, float]:
    """Median wall seconds of the bare interpreter, and of it importing rerun, numpy, typer."""

    def run(code: str) -> float:
        times = []
        for _ in range(5):
            start = time.perf_counter()
            subprocess.run([sys.executable, "-c", code], check=True)
            times.append(time.perf_counter() - start)
        return statistics.median(times)

    return run("pass"), run("import rerun, numpy, typer")


# -- the report --------------------------------------------------------------------------


def machine() -> list[str]:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
        memory = next(
            int(line.split()[1]) // 1024**2
            for line in Path("/proc/meminfo").read_text().splitlines()
            if line.startswith("MemTotal")
        )
    except (OSError, StopIteration):
        memory = 0
    blas = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
    return [
        f"- **machine**: {cpu}, {os.cpu_count()} cores, {memory} GiB, {platform.system()}"
        f" {platform.release()}",
        f"- **software**: Python {platform.python_version()}, numpy {np.__version__}"
        f" ({blas.get('name')} {blas.get('version')}), ekfviz {ekfviz.__version__},"
        " one BLAS thread (OPENBLAS/OMP/MKL_NUM_THREADS=1) on both sides",
        "- **compiled kernel** (`ekfviz/filters/_kernel.c`): "
        + (
            f"built; predict runs in it at any size, the sequential update below state"
            f" dimension {KERNEL_MAX_DIM} (N <= {(KERNEL_MAX_DIM - 4) // 2} landmarks)"
            if HAVE_KERNEL
            else "**not built** (no C compiler at install): numpy throughout"
        ),
        f"- **date**: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- **command**: `make bench` (`{Path(sys.executable).name} benchmarks/bench.py"
        f"{' ' + ' '.join(sys.argv[1:]) if sys.argv[1:] else ''}`)",
    ]


def verdict(ok: bool) -> str:
    return "met" if ok else "**not met**"


def report(
    rows: list[CoreRow],
    e2e: list[EndToEnd],
    memory: list[Memory],
    phases: list[Phases],
    sizes: list[Size],
    long_entities: list[tuple[str, float]],
    interpreter_s: float,
    imports_s: float,
    kernel_us: float | None,
    flops: float,
    quick: bool,
) -> str:
    lines = ["# ekfviz benchmarks", ""]
    if quick:
        lines += ["**Quick run** (`--quick`): smaller cases, not the reference numbers.", ""]
    lines += [*machine(), ""]
    lines += [
        "## Core against the dense textbook filter",
        "",
        "Milliseconds per step (one predict and one observation line). *Core*: `EkfSlam`"
        " (sequential updates unless said); *+ batch*: what appending the state after each"
        " of the two events to a batch adds, as the replay does; *without kernel*: the core"
        " with `compiled=False`, numpy throughout, where the compiled kernel would run."
        " *Dense*:"
        " `benchmarks/textbook_ekf.py`. *Bound*: one read-and-write pass over an array the"
        " size of P, this run; *per landmark / bound*: core time per step divided by the"
        " landmarks observed, over the bound.",
        "",
        "| N | observed | core ms | + batch ms | without kernel ms | dense ms | dense timed"
        " | dense / core | bound ms | per landmark / bound |",
        "|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|",
    ]
    for r in rows:
        mode = "" if r.mode == "sequential" else f" ({r.mode})"
        dense = f"{r.dense_ms:.3f}" if r.dense_ms < 10 else f"{r.dense_ms:,.0f}"
        ratio = f"{r.ratio:.1f}" if r.ratio < 10 else f"{r.ratio:,.0f}"
        numpy_ms = "" if r.numpy_ms is None else f"{r.numpy_ms:.3f}"
        lines.append(
            f"| {r.n} | {r.seen}{mode} | {r.core_ms:.3f} | {r.batch_ms:.3f} | {numpy_ms}"
            f" | {dense} | {r.dense_basis} | {ratio}x | {r.bound_ms:.3f}"
            f" | {r.per_landmark_over_bound:.2f} |"
        )
    joint = [r for r in rows if r.mode == "joint"]
    lines += [
        "",
        f"A square matrix product runs at {flops / 1e9:.1f} GFLOP/s here (one thread). The"
        " arithmetic bound of a joint update's rank-2m change of P, 4 m n^2 flops (m"
        " landmarks, n = 3 + 2N), against the joint update's whole step:"
        + "".join(
            f" N = {r.n}: {4 * r.seen * (3 + 2 * r.n) ** 2 / flops * 1e3:.2f} ms, step"
            f" {r.core_ms / (4 * r.seen * (3 + 2 * r.n) ** 2 / flops * 1e3):.2f} x that;"
            for r in joint
        ).rstrip(";")
        + "."
        if joint
        else "",
        "",
        "## End to end",
        "",
        "`ekfviz replay LOG --save RUN.rrd` as a subprocess, default settings: wall time"
        " (median of 3 for the short logs), the child's peak resident memory, the recording's"
        " size. *Dense*: `TextbookEkfSlam.run` on the same events, arithmetic only (no"
        " start-up, reading or logging), for the classic-format logs.",
        "",
        "| log | lines | wall s | peak MB | .rrd MB | dense arithmetic s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for e in e2e:
        dense = "" if e.dense_s is None else f"{e.dense_s:.2f}"
        lines.append(
            f"| {e.name} | {e.lines:,} | {e.wall_s:.2f} | {e.peak_mb:.0f} | {e.rrd_mb:.1f}"
            f" | {dense} |"
        )
    kernel = (
        "the compiled kernel was not built"
        if kernel_us is None
        else f"importing the compiled kernel takes {kernel_us:.0f} us (`-X importtime`)"
    )
    lines += [
        "",
        f"Interpreter alone: {interpreter_s:.2f} s; interpreter + `import rerun, numpy, typer`:"
        f" {imports_s:.2f} s (median of 5), paid by every replay; {kernel}.",
        "",
    ]
    if phases:
        lines += [
            "## Where a long replay's time goes",
            "",
            "One child process per log: *read*: the log into events; *filter*: `predict` and"
            " `observe` alone; *batches and checks*: what `replay()` adds to them as"
            " `ekfviz replay` runs it (each event's state appended to its batch, the batches"
            " built, the covariance checks); *logging*: `Recorder.log` (which holds the"
            " events and sends them every few thousand), `finish` and the flush to"
            " the .rrd file in the main thread; *Rerun threads*: the CPU time Rerun's own"
            " threads (encoding, compression, writing) spent meanwhile, on the second core.",
            "",
            "| log | events | read s | filter s | batches and checks s | logging s"
            " | Rerun threads CPU s | logging per event us | logging / filter"
            " | logging / (filter + batches) |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {p.name} | {p.events:,} | {p.read_s:.2f} | {p.filter_s:.2f}"
            f" | {p.core_s - p.filter_s:.2f} | {p.logging_s:.2f} | {p.rerun_cpu_s:.2f}"
            f" | {1e6 * p.logging_s / p.events:.1f} | {p.logging_over_filter:.2f}"
            f" | {p.logging_s / p.core_s:.2f} |"
            for p in phases
        ]
        lines += [
            "",
            "Logging costs a fixed amount per event and per landmark it draws; the filter's"
            " cost grows with the map. Where the compiled kernel makes a step of a small map"
            " cost a few microseconds, logging is the larger part.",
            "",
        ]
    lines += [
        "## Targets",
        "",
        "| target | measured | |",
        "|---|---|---|",
    ]
    by = {(r.n, r.seen, r.mode): r for r in rows}
    targets: list[tuple[str, str, bool]] = []
    if (r6 := by.get((6, 6, "sequential"))) is not None:
        both = r6.dense_ms / (r6.core_ms + r6.batch_ms)
        targets.append(
            ("N = 6: >= 3x faster per step than dense",
             f"{r6.ratio:.1f}x ({both:.1f}x with the batches)", r6.ratio >= 3)
        )  # fmt: skip
    if (r1000 := by.get((1000, SEEN, "sequential"))) is not None:
        targets.append(
            ("N = 1000, 10 observed: >= 250x faster than dense", f"{r1000.ratio:,.0f}x",
             r1000.ratio >= 250)
        )  # fmt: skip
    for seen in (2000, SEEN):
        if (r2000 := by.get((2000, seen, "sequential"))) is not None:
            targets.append(
                (f"N = 2000, {seen} observed: per landmark <= 1.5 x one-pass bound",
                 f"{r2000.per_landmark_over_bound:.2f} x", r2000.per_landmark_over_bound <= 1.5)
            )  # fmt: skip
    if e2e and not quick:
        classic, loop, long = e2e[0], e2e[1], e2e[2]
        targets += [
            ("classic sample end to end: <= 1.2 s", f"{classic.wall_s:.2f} s",
             classic.wall_s <= 1.2),
            ("loop 10,000 x 300 end to end: <= 30 s", f"{loop.wall_s:.1f} s", loop.wall_s <= 30),
            ("loop 10,000 x 300: peak memory <= 1 GB", f"{loop.peak_mb:.0f} MB",
             loop.peak_mb <= 1000),
            ("loop 10,000 x 300: .rrd <= 250 MB", f"{loop.rrd_mb:.0f} MB", loop.rrd_mb <= 250),
            ("100,000-step classic-size log end to end: <= 20 s", f"{long.wall_s:.1f} s",
             long.wall_s <= 20),
            ("100,000-step classic-size log: .rrd <= 50 MB", f"{long.rrd_mb:.1f} MB",
             long.rrd_mb <= 50),
        ]  # fmt: skip
    targets += [
        (f"{size.name}: .rrd >= 3x smaller than at 9b3d7d7",
         f"{size.bytes_before / size.bytes_now:.2f}x", size.bytes_before >= 3 * size.bytes_now)
        for size in sizes
    ]  # fmt: skip
    for name, measured, ok in targets:
        lines.append(f"| {name} | {measured} | {verdict(ok)} |")
    lines += [
        "",
        "What a default recording holds (see `ekfviz/viz/recorder.py`): at every event the"
        " robot frame and its predicted or updated ellipse (a transform of one static unit"
        " circle), at every update the observations (arrows in the robot frame), the text"
        " line, the trajectory and the pose sigmas of the step; the landmarks and their"
        " ellipses of a small map (up to 32) wherever some landmark moved by over 2 % of its"
        " ellipse's size, of a larger one at every update the observed landmarks' ellipses"
        " and every 25 steps the whole map's; the end exactly. `--detail` logs every"
        " landmark and ellipse at every update.",
        "",
    ]
    if sizes or long_entities:
        lines += [
            "## Recording size",
            "",
            "`ekfviz replay LOG --truth TRUTH --save RUN.rrd` of the bundled samples, against"
            " the same command in an earlier ekfviz (commit 9b3d7d7, whose recordings were"
            f" larger: the 100,000-step log gave {LONG_RRD_MB_BEFORE:.0f} MB).",
            "",
            "| recording | 9b3d7d7 bytes | now bytes | smaller by |",
            "|---|---:|---:|---:|",
        ]
        lines += [
            f"| {size.name} | {size.bytes_before:,} | {size.bytes_now:,}"
            f" | {size.bytes_before / size.bytes_now:.2f}x |"
            for size in sizes
        ]
        if long_entities:
            lines += [
                "",
                "Where the bytes of the 100,000-step recording go, MB per entity as in the"
                " file (each chunk an Arrow IPC stream: schema, row ids, both timelines and"
                " data, LZ4-compressed):",
                "",
                "| entity | MB |",
                "|---|---:|",
            ]
            lines += [f"| `{entity}` | {mb:.1f} |" for entity, mb in long_entities]
        lines.append("")
    if memory:
        lines += [
            "## Memory against the length of the log",
            "",
            "Peak resident memory replaying the classic-size log and its first tenth. *Core*:"
            " reading, filter, batches and the consistency count in a child process, no"
            " recording. *End to end*: `ekfviz replay --save`. The core streams; what grows"
            " end to end is Rerun's .rrd writer, which keeps an index entry per chunk for the"
            " file's footer.",
            "",
            "| steps | log MB | core peak MB | end-to-end peak MB | .rrd MB |",
            "|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {m.steps:,} | {m.log_mb:.1f} | {m.core_mb:.0f} | {m.end_to_end_mb:.0f}"
            f" | {m.rrd_mb:.1f} |"
            for m in memory
        ]
    return "\n".join(lines)


def worker_worlds(quick: bool) -> list[tuple[int, int, list[LogEvent]]]:
    """The events of the worker section: the classic world (N = 6) and N = 300, 10 seen."""
    worlds = []
    for n, seen, steps in ((6, 6, 58), (300, 10, 10 if quick else 40)):
        world = make_world(n, seen, steps)
        events: list[LogEvent] = [world.first]
        for control, sighting in world.steps:
            events += [control, sighting]
        worlds.append((n, seen, events))
    return worlds


def _write_section(out: Path, section: str) -> None:
    """Put ``section`` in place of its old text in ``out`` (or at its end), and print it."""
    old = out.read_text() if out.exists() else ""
    out.write_text(splice(old, section))
    print(section)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--quick", action="store_true", help="small cases, for a smoke test")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "RESULTS.md")
    parser.add_argument(
        "--mrclam-only", action="store_true", help="only the MRCLAM section of RESULTS.md"
    )
    parser.add_argument(
        "--smoother-only", action="store_true", help="only the smoother section of RESULTS.md"
    )
    parser.add_argument(
        "--worker-only", action="store_true", help="only the worker section of RESULTS.md"
    )
    parser.add_argument(
        "--startup-only", action="store_true", help="only the start-up section of RESULTS.md"
    )
    parser.add_argument(
        "--scaling-only",
        action="store_true",
        help="only the scaling section (and its plots) of RESULTS.md",
    )
    parser.add_argument(
        "--targets-only",
        action="store_true",
        help="only the section of the speed targets (classic start-up, 102,000 steps,"
        " Victoria Park), in one run",
    )
    parser.add_argument(
        "--check-only", action="store_true", help="only the check --all section of RESULTS.md"
    )
    parser.add_argument(
        "--before",
        type=Path,
        default=None,
        help="a clone from before (with its own .venv) to time check --all and the targets against",
    )
    parser.add_argument(
        "--association-only",
        action="store_true",
        help="only the association section (Victoria Park, simulated clutter) of RESULTS.md",
    )
    parser.add_argument(
        "--sandbox-only", action="store_true", help="only the sandbox section of RESULTS.md"
    )
    parser.add_argument(
        "--watch-only", action="store_true", help="only the watch section of RESULTS.md"
    )
    parser.add_argument(
        "--instructions-only",
        action="store_true",
        help="only the section of the instructions each replay executes (Valgrind), now and"
        " --before",
    )
    parser.add_argument(
        "--extensions-only",
        action="store_true",
        help="only the section of what each compiled extension buys",
    )
    args = parser.parse_args(argv)
    started = time.perf_counter()
    if args.worker_only:
        section = worker_section(worker_worlds(args.quick))
        _write_section(args.out, section)
        return
    if args.check_only:
        from check_bench import check_section

        with tempfile.TemporaryDirectory() as tmp:
            section = check_section(Path(tmp), args.before)
        _write_section(args.out, section)
        return
    if args.instructions_only:
        from association_bench import find_dataset
        from instructions_bench import instructions_section
        from mrclam_bench import find_dataset as find_mrclam

        with tempfile.TemporaryDirectory() as tmp:
            section = instructions_section(Path(tmp), args.before, find_mrclam(), find_dataset())
        _write_section(args.out, section)
        return
    if args.extensions_only:
        from association_bench import find_dataset
        from extensions_bench import extensions_section

        with tempfile.TemporaryDirectory() as tmp:
            section = extensions_section(Path(tmp), find_dataset())
        _write_section(args.out, section)
        return
    if args.targets_only:
        from association_bench import find_dataset
        from mrclam_bench import find_dataset as find_mrclam
        from targets_bench import targets_section

        with tempfile.TemporaryDirectory() as tmp:
            section = targets_section(Path(tmp), find_dataset(), args.before, find_mrclam())
        _write_section(args.out, section)
        return
    if (
        args.mrclam_only
        or args.smoother_only
        or args.association_only
        or args.startup_only
        or args.scaling_only
        or args.sandbox_only
        or args.watch_only
    ):
        with tempfile.TemporaryDirectory() as tmp:
            if args.watch_only:
                section = watch_section(Path(tmp))
            elif args.sandbox_only:
                section = sandbox_section(Path(tmp), args.quick)
            elif args.startup_only:
                section = startup_section(Path(tmp))
            elif args.scaling_only:
                section = scaling_section(Path(tmp), args.quick, args.out.parent)
            elif args.association_only:
                section = association_section(Path(tmp), args.quick)
            else:
                make = mrclam_section if args.mrclam_only else smoother_section
                section = make(Path(tmp))
        _write_section(args.out, section)
        return
    # end to end first: a child's peak resident memory counts the pages it shares with
    # this process when forked, so this process must still be small
    print("end to end", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        e2e = end_to_end(Path(tmp), args.quick)
        print("memory against log length", flush=True)
        memory = memory_rows(Path(tmp), Path(tmp) / "classic_long.txt")
        print("recording sizes", flush=True)
        sizes = sample_sizes(Path(tmp))
        long_entities = bytes_by_entity(Path(tmp) / "classic_long.rrd")
        print("where the time goes", flush=True)
        phases = phase_rows(
            Path(tmp),
            [(e2e[1].name, Path(tmp) / "loop.txt"), (e2e[2].name, Path(tmp) / "classic_long.txt")],
        )
        print("MRCLAM dataset 6", flush=True)
        mrclam = mrclam_section(Path(tmp))
        smoothers = smoother_section(Path(tmp), args.quick)
        print("association: Victoria Park, simulated clutter", flush=True)
        association = association_section(Path(tmp), args.quick)
        print("start-up and wrap-up of four commands", flush=True)
        startups = startup_section(Path(tmp))
        print("the speed targets in one run", flush=True)
        from association_bench import find_dataset
        from mrclam_bench import find_dataset as find_mrclam
        from targets_bench import targets_section

        targets = targets_section(Path(tmp), find_dataset(), args.before, find_mrclam())
        scaling = scaling_section(Path(tmp), args.quick, args.out.parent)
        print("the sandbox of user code", flush=True)
        sandbox = sandbox_section(Path(tmp), args.quick)
        print("watch: a save to its run in the viewer", flush=True)
        watch = watch_section(Path(tmp))
        print("check --all", flush=True)
        from check_bench import check_section

        checks = check_section(Path(tmp), args.before)
        print("what each compiled extension buys", flush=True)
        from extensions_bench import extensions_section

        extensions = extensions_section(Path(tmp), find_dataset())
    print("core against dense (one BLAS thread)", flush=True)
    rows = core_rows(args.quick)
    flops = dgemm_flops()
    interpreter_s, imports_s = startup()
    text = report(
        rows, e2e, memory, phases, sizes, long_entities, interpreter_s, imports_s,
        kernel_import_us(), flops, args.quick,
    )  # fmt: skip
    print("a user's filter in its worker", flush=True)
    workers = worker_section(worker_worlds(args.quick))
    text = splice(splice(splice(splice(text, mrclam), smoothers), association), workers)
    text = splice(splice(splice(splice(text, startups), scaling), targets), sandbox)
    text = splice(splice(splice(text, checks), watch), extensions)
    args.out.write_text(text)
    print()
    print(text)
    print(f"(benchmarks took {time.perf_counter() - started:.0f} s; written to {args.out})")


if __name__ == "__main__":
    main()
