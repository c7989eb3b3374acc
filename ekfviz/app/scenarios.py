"""The simulated world as asked (``simulate``, ``consistency``): the scenario and its
loop's size, the true noise where it is not the scenario's, the sensor's misses and
false alarms; each refused in one line where it cannot be.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass
from typing import Any

from ekfviz.core.errors import UsageError
from ekfviz.sim.scenarios import Scenario, ScenarioName
from ekfviz.sim.simulate import Detection, Noise

__all__ = ["LoopSettings", "ScenarioName", "SensingSettings", "TrueNoiseSettings"]

# bounds of what a simulation is asked for: beyond them the run is not a bigger study but
# numbers that overflow (a sigma of 1e300), a Poisson draw numpy refuses, or memory
MAX_TRUE_SIGMA = 1e6
MAX_CLUTTER = 1000.0
MAX_STEPS = 10_000_000
MAX_LANDMARKS = 100_000
MAX_LAPS = 10_000


def refuse_too_long(steps: int, laps: int) -> None:
    """Refuse a simulated run of more than :data:`MAX_STEPS` controls: ``--steps`` and
    ``--laps`` each within bounds multiply past them (memory).

    :raises UsageError: saying how many that makes
    """
    if steps * laps > MAX_STEPS:
        raise UsageError(f"--laps {laps} of {steps:,} controls make {steps * laps:,}, more than"
                         f" a simulated run takes ({MAX_STEPS:,})")  # fmt: skip


@dataclass(frozen=True, slots=True)
class LoopSettings:
    """The loop scenario's size and sensor (None: the scenario's own)."""

    steps: int | None = None
    landmarks: int | None = None
    max_range: float | None = None
    fov: float | None = None

    def world(self, scenario: ScenarioName, seed: int) -> Scenario:
        """The scenario asked for.

        :raises UsageError: a loop's setting given for another scenario
        """
        from ekfviz.sim import scenarios

        options: dict[str, Any] = {
            "steps": self.steps, "landmarks": self.landmarks, "max_range": self.max_range,
            "fov_deg": self.fov,
        }  # fmt: skip
        given = {name: value for name, value in options.items() if value is not None}
        if scenario in (ScenarioName.CLASSIC, ScenarioName.EDGE):
            if given:
                flags = (f"--{name.removesuffix('_deg').replace('_', '-')}" for name in given)
                raise UsageError(f"{', '.join(flags)}: only for --scenario loop")
            return scenarios.classic() if scenario is ScenarioName.CLASSIC else scenarios.edge()
        return scenarios.loop(seed=seed, **given)


@dataclass(frozen=True, slots=True)
class TrueNoiseSettings:
    """The simulator's noise where it is not the scenario's (None: the scenario's)."""

    sigma_x: float | None = None
    sigma_y: float | None = None
    sigma_alpha: float | None = None
    sigma_bearing: float | None = None
    sigma_range: float | None = None

    @property
    def given(self) -> tuple[float | None, float | None, float | None, float | None, float | None]:
        return (self.sigma_x, self.sigma_y, self.sigma_alpha, self.sigma_bearing,
                self.sigma_range)  # fmt: skip

    def of(self, world: Scenario) -> Noise:
        """The scenario's own noise, with the values given instead."""
        defaults = astuple(world.noise)
        return Noise(*(d if g is None else g for g, d in zip(self.given, defaults, strict=True)))


@dataclass(frozen=True, slots=True)
class SensingSettings:
    """The simulated sensor's ids, false alarms (mean per scan) and misses."""

    unknown_ids: bool = False
    clutter: float = 0.0
    detection_probability: float = 1.0

    def detection(self) -> Detection:
        """The detection asked for.

        :raises UsageError: a probability outside [0, 1], false alarms in a log with ids
        """
        probability = self.detection_probability
        if not 0.0 <= probability <= 1.0:
            raise UsageError(f"--detection-probability: {probability:g} is not between 0 and 1")
        if self.clutter > 0 and not self.unknown_ids:
            raise UsageError(
                "--clutter: only with --unknown-ids (a log with ids names no false alarms)"
            )
        return Detection(self.unknown_ids, self.clutter, probability)
