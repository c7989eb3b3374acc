"""What each compiled extension buys, in ``make bench``: the run whose target it carries,
end to end with the extension and without it, interleaved in one run.

- the filter's kernel of small maps (``ekfviz/filters/_kernel.c``): a 102,000-step
  classic-size log (target: at most 5 s);
- JCBB's search (``ekfviz/association/_search.c``): Victoria Park where the reference
  folder has it (target: at most 10 s), else a simulated id-less loop with clutter.

"Without" runs the same command with the extension's module made unimportable
(``sys.modules[name] = None``), so ekfviz takes its Python reference, as on a machine
without a C compiler. Wall seconds, the median of :data:`REPEATS` pairs A B A B...
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekfviz.io.classic import format_classic
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, Noise, classic_controls, simulate

BIN = Path(sys.executable).parent
BEGIN, END = "<!-- extensions:begin -->", "<!-- extensions:end -->"
REPEATS = 3
LONG_STEPS = 102_000
# the command run with one extension's module made unimportable: its Python reference runs
WITHOUT = "import sys; sys.modules[{module!r}] = None; from ekfviz.__main__ import main; main()"


@dataclass(frozen=True, slots=True)
class ExtensionRow:
    extension: str
    run: str
    target_s: float
    with_s: float
    without_s: float


def _seconds(command: list[str], folder: Path) -> float:
    env = dict(os.environ, CI="1", XDG_CONFIG_HOME=str(folder), XDG_DATA_HOME=str(folder))
    (folder / "run.rrd").unlink(missing_ok=True)
    start = time.perf_counter()
    subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def _pair(module: str, args: list[str], folder: Path) -> tuple[float, float]:
    """Median wall seconds of ``ekfviz ARGS`` with the extension and without it."""
    with_ext, without = [], []
    for _ in range(REPEATS):
        with_ext.append(_seconds([str(BIN / "ekfviz"), *args], folder))
        code = WITHOUT.format(module=module)
        without.append(_seconds([sys.executable, "-c", code, *args], folder))
    return statistics.median(with_ext), statistics.median(without)


def _long_log(folder: Path) -> Path:
    """The classic route again and again, as the speed targets' long log."""
    controls = np.tile(classic_controls(), (LONG_STEPS // 29 + 1, 1))[:LONG_STEPS]
    quiet = Noise(sigma_x=0.05, sigma_y=0.02, sigma_alpha=0.005)
    log = folder / "long.txt"
    run = simulate(controls, CLASSIC_LANDMARKS_XY, quiet, seed=3)
    log.write_text(format_classic(run.events, 4))
    return log


def _association_run(folder: Path, victoria: Path | None) -> tuple[str, list[str]]:
    """Victoria Park's replay, or a simulated id-less loop's with JCBB."""
    if victoria is not None:
        return "Victoria Park", [str(victoria)]
    log = folder / "clutter.txt"
    subprocess.run(
        [str(BIN / "ekfviz"), "simulate", "--scenario", "loop", "--unknown-ids", "--clutter",
         "1", "--laps", "2", "--landmarks", "120", "--seed", "1", "-o", str(log),
         "--truth-out", str(folder / "clutter_truth.json")],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    return "simulated loop, 120 landmarks, no ids", [str(log), "--association", "jcbb"]


def extension_rows(folder: Path, victoria: Path | None) -> list[ExtensionRow]:
    """Each extension's run with it and without it."""
    long_log = _long_log(folder)
    save = ["--save", str(folder / "run.rrd")]
    kernel = _pair("ekfviz.filters._kernel", ["replay", str(long_log), *save], folder)
    name, args = _association_run(folder, victoria)
    search = _pair("ekfviz.association._search", ["replay", *args, *save], folder)
    return [
        ExtensionRow("filter kernel (_kernel.c)", f"{LONG_STEPS:,}-step classic-size log", 5.0,
                     *kernel),
        ExtensionRow("JCBB search (_search.c)", name, 10.0, *search),
    ]  # fmt: skip


def extensions_section(folder: Path, victoria: Path | None) -> str:
    """The section of RESULTS.md."""
    load = os.getloadavg()[0]
    lines = [
        BEGIN,
        "## What each compiled extension buys",
        "",
        "`python benchmarks/bench.py --extensions-only` (`benchmarks/extensions_bench.py`):"
        " the run whose target each extension carries, with it and without it (its module"
        f" unimportable, so its Python reference runs), median wall of {REPEATS}"
        f" interleaved pairs; load average {load:.1f} on 2 cores when it started.",
        "",
        "| extension | run | target | with s | without s | without / with | target without |",
        "|---|---|---:|---:|---:|---:|---|",
    ]
    for row in extension_rows(folder, victoria):
        held = "met" if row.without_s <= row.target_s else "**not met**"
        lines.append(
            f"| {row.extension} | {row.run} | <= {row.target_s:g} s | {row.with_s:.2f} |"
            f" {row.without_s:.2f} | {row.without_s / row.with_s:.2f}x | {held} |"
        )
    lines += [
        "",
        "The readers have no compiled parser: plain decimals (at most 15 digits, no exponent)"
        " are read by numpy as integers in one go and scaled, to the bits `float()` gives;"
        " any other number goes through `float()`.",
        END,
    ]
    return "\n".join(lines)
