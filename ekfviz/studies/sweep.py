"""Parameter sweeps: the same log replayed with filter parameters varied around a baseline.

A sweep is a study (:mod:`ekfviz.studies.runs`) of one filter under several parameter sets.

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
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from ekfviz.core.errors import UsageError
from ekfviz.core.params import FilterParams
from ekfviz.io.text import MAX_MAGNITUDE
from ekfviz.studies.runs import VARIABLE, RunSpec

MAX_VARIANTS = 1000  # variants a sweep runs: each is a whole replay

_VALUE = re.compile(r"(?P<op>[x*/]?)(?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")


class SweepError(UsageError):
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


def build_variants(
    baseline: FilterParams, varies: Sequence[Sequence[Change]], *, one_at_a_time: bool
) -> list[RunSpec]:
    """The baseline first, then a grid of the varied values or each value on its own."""
    variants = [RunSpec("baseline", "baseline", baseline)]
    combinations: Iterable[tuple[Change, ...]]
    if one_at_a_time or len(varies) == 1:
        count = sum(len(changes) for changes in varies)
        combinations = [(change,) for changes in varies for change in changes]
    else:  # the grid counted before it is made: five lists of 100 are 10^10 variants
        count = math.prod(len(changes) for changes in varies)
        combinations = itertools.product(*varies)
    if count > MAX_VARIANTS:
        raise SweepError(
            f"--vary asks for {count:,} variants, more than a sweep runs ({MAX_VARIANTS:,}):"
            " vary fewer values, or one at a time (--one-at-a-time)"
        )
    seen: dict[str, FilterParams] = {"baseline": baseline}
    for combination in combinations:
        names = [change.name for change in combination]
        if len(set(names)) != len(names):
            raise SweepError(f"--vary names {names[0]} twice in one variant")
        values: dict[str, Any] = {c.name: _checked(c, c.apply(getattr(baseline, c.name)))
                                  for c in combination}  # fmt: skip
        params = replace(baseline, **values)
        key = "_".join(change.key for change in combination)
        if key in seen:
            if seen[key] != params:  # two values that print alike: one would be lost
                raise SweepError(
                    f"--vary: {', '.join(c.label for c in combination)} names two values"
                    " that print alike (6 significant digits): give values that differ there"
                )
            continue
        seen[key] = params
        variants.append(
            RunSpec(
                ", ".join(change.label for change in combination), key, params, changes=combination
            )
        )
    return variants


def _checked(change: Change, value: float) -> float:
    """A varied sigma as the filter takes it, as ``replay`` checks its options: finite,
    at most 1e18, and positive for the measurement's (R must be invertible)."""
    if not math.isfinite(value) or value > MAX_MAGNITUDE:  # as every number read
        raise SweepError(f"--vary {change.label}: gives {change.name} = {value:g}, expected at"
                         f" most {MAX_MAGNITUDE:g}")  # fmt: skip
    if change.name in ("sigma_bearing", "sigma_range") and value <= 0.0:
        raise SweepError(f"--vary {change.label}: gives {change.name} = {value:g}, expected a"
                         " positive sigma (R must be invertible)")  # fmt: skip
    return value


def tuning_preset(baseline: FilterParams) -> list[RunSpec]:
    """The classic tuning study: each noise parameter x10 and /10, one at a time (11)."""
    varies = [[Change(name, "x", 10.0), Change(name, "/", 10.0)] for name in VARIABLE]
    return build_variants(baseline, varies, one_at_a_time=True)
