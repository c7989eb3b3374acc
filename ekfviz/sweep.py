"""Parameter sweeps: the same log replayed with filter parameters varied around a baseline.

No rerun, no typer: the variants are built from ``--vary`` texts or a preset, replayed in
parallel over the machine's cores (each worker reads the log itself) and summarised; the
command line prints and records them.

A value in ``--vary NAME=V1,V2,...`` is absolute (``0.5``) or a factor of the baseline
(``x10`` multiplies, ``/10`` divides). Several ``--vary`` options form a grid, or are
varied one at a time around the baseline.
"""

from __future__ import annotations

import itertools
import math
import os
import re
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ekfviz.core.consistency import Consistency, reading
from ekfviz.core.evaluation import Evaluation, evaluate
from ekfviz.core.filter import FilterParams
from ekfviz.core.records import EventRecord
from ekfviz.core.replay import replay
from ekfviz.core.truth import GroundTruth
from ekfviz.io.extended import read_log

VARIABLE = ("sigma_x", "sigma_y", "sigma_alpha", "sigma_bearing", "sigma_range")
_VALUE = re.compile(r"(?P<op>[x*/]?)(?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")


class SweepError(ValueError):
    """A ``--vary`` or preset that cannot be used, with a one-line reason."""


@dataclass(frozen=True, slots=True)
class Change:
    """One value of a varied parameter: absolute, or a factor of the baseline."""

    name: str
    op: str  # "" absolute, "x" multiply, "/" divide
    number: float

    def apply(self, baseline: float) -> float:
        if self.op == "x":
            return baseline * self.number
        if self.op == "/":
            return baseline / self.number
        return self.number

    @property
    def label(self) -> str:
        """Readable, e.g. ``sigma_x x10``, ``sigma_x /10``, ``sigma_x=0.5``."""
        number = f"{self.number:g}"
        return f"{self.name} {self.op}{number}" if self.op else f"{self.name}={number}"

    @property
    def key(self) -> str:
        """Safe in an entity path, e.g. ``sigma_x-x10``, ``sigma_x-div10``, ``sigma_x-0.5``."""
        op = {"x": "x", "/": "div", "": ""}[self.op]
        return f"{self.name}-{op}{self.number:g}"


def parse_vary(text: str) -> list[Change]:
    """Parse ``NAME=V1,V2,...`` (``NAME`` with ``-`` or ``_``).

    :raises SweepError: naming the option and what was expected
    """
    name, sep, values = text.partition("=")
    name = name.strip().replace("-", "_")
    if not sep or not values.strip():
        raise SweepError(f"--vary {text}: expected NAME=V1,V2,... (e.g. sigma_x=x10,/10)")
    if name not in VARIABLE:
        raise SweepError(
            f"--vary {text}: unknown parameter {name!r}, expected one of {', '.join(VARIABLE)}"
        )
    changes = []
    for value in values.split(","):
        found = _VALUE.fullmatch(value.strip())
        negative = _VALUE.fullmatch(value.strip().replace("-", "", 1))
        if found is None and negative is not None:
            raise SweepError(
                f"--vary {text}: {value.strip()!r} is negative: a sigma (or a factor of one)"
                " must be positive"
            )
        if found is None:
            raise SweepError(
                f"--vary {text}: found {value.strip()!r}, expected a number (0.5) or a factor"
                " of the baseline (x10, /10)"
            )
        op = "x" if found["op"] == "*" else found["op"]
        number = float(found["number"])
        if not math.isfinite(number) or (op == "/" and number == 0.0):
            raise SweepError(f"--vary {text}: {value.strip()!r} is not a usable value")
        changes.append(Change(name, op, number))
    return changes


@dataclass(frozen=True, slots=True)
class Variant:
    """Filter parameters to replay with, and how they differ from the baseline."""

    label: str
    key: str
    params: FilterParams
    changes: tuple[Change, ...] = ()


def build_variants(
    baseline: FilterParams, varies: Sequence[Sequence[Change]], *, one_at_a_time: bool
) -> list[Variant]:
    """The baseline first, then a grid of the varied values or each value on its own."""
    variants = [Variant("baseline", "baseline", baseline)]
    combinations: list[tuple[Change, ...]]
    if one_at_a_time or len(varies) == 1:
        combinations = [(change,) for changes in varies for change in changes]
    else:
        combinations = list(itertools.product(*varies))
    seen = {"baseline"}
    for combination in combinations:
        names = [change.name for change in combination]
        if len(set(names)) != len(names):
            raise SweepError(f"--vary names {names[0]} twice in one variant")
        values: dict[str, Any] = {c.name: c.apply(getattr(baseline, c.name)) for c in combination}
        params = replace(baseline, **values)
        key = "_".join(change.key for change in combination)
        if key in seen:
            continue
        seen.add(key)
        variants.append(
            Variant(", ".join(change.label for change in combination), key, params, combination)
        )
    return variants


def tuning_preset(baseline: FilterParams) -> list[Variant]:
    """The classic tuning study: each noise parameter x10 and /10, one at a time (11)."""
    varies = [[Change(name, "x", 10.0), Change(name, "/", 10.0)] for name in VARIABLE]
    return build_variants(baseline, varies, one_at_a_time=True)


@dataclass(frozen=True, slots=True)
class VariantRun:
    """One variant replayed: every record, and the final evaluation with consistency."""

    variant: Variant
    records: tuple[EventRecord, ...]
    evaluation: Evaluation


def run_variant(path: Path, variant: Variant, truth: GroundTruth | None) -> VariantRun:
    """Replay the log at ``path`` with one variant's parameters."""
    consistency = Consistency(truth)
    records = []
    for record in replay(read_log(path), variant.params):
        consistency.add(record)
        records.append(record)
    return VariantRun(variant, tuple(records), evaluate(records[-1], truth, consistency))


def run_variants(
    path: Path,
    variants: Sequence[Variant],
    truth: GroundTruth | None,
    workers: int | None = None,
    done: Callable[[VariantRun], None] | None = None,
) -> list[VariantRun]:
    """Replay every variant over ``workers`` processes; results in the variants' order."""
    workers = min(len(variants), workers or os.cpu_count() or 1)
    if workers <= 1:
        runs = []
        for variant in variants:
            runs.append(run_variant(path, variant, truth))
            if done is not None:
                done(runs[-1])
        return runs
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(run_variant, path, variant, truth) for variant in variants]
        for future in futures:
            if done is not None:
                done(future.result())
        return [future.result() for future in futures]


@dataclass(frozen=True, slots=True)
class Summary:
    """What the sweep table says of one variant."""

    label: str
    parameters: dict[str, float]
    mean_error: float | None
    max_error: float | None
    mean_mahalanobis: float | None
    inside: int | None
    landmarks: int
    final_pose: list[float]
    from_baseline: float
    mean_nis: float | None
    nis_inside: float | None
    reading: str


def summarise(run: VariantRun, baseline: VariantRun) -> Summary:
    """The row of one variant, compared with the baseline's final pose."""
    evaluation = run.evaluation
    errors = [r.euclidean for r in evaluation.landmarks if r.euclidean is not None]
    distances = [r.mahalanobis for r in evaluation.landmarks if r.mahalanobis is not None]
    nis = [
        float(r.observations.nis[np.isfinite(r.observations.nis)].sum())
        for r in run.records
        if r.observations is not None and np.isfinite(r.observations.nis).any()
    ]
    consistency = evaluation.consistency
    count = consistency.nis if consistency is not None else None
    inside = sum(bool(r.inside_3sigma) for r in evaluation.landmarks) if distances else None
    return Summary(
        label=run.variant.label,
        parameters={name: getattr(run.variant.params, name) for name in VARIABLE},
        mean_error=float(np.mean(errors)) if errors else None,
        max_error=float(np.max(errors)) if errors else None,
        mean_mahalanobis=float(np.mean(distances)) if distances else None,
        inside=inside,
        landmarks=len(evaluation.landmarks),
        final_pose=[float(v) for v in evaluation.pose],
        from_baseline=float(np.hypot(*(evaluation.pose[:2] - baseline.evaluation.pose[:2]))),
        mean_nis=float(np.mean(nis)) if nis else None,
        nis_inside=count.fraction_inside if count is not None and count.total else None,
        reading=reading(consistency, inside, len(distances)),
    )
