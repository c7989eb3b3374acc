"""A simulated run in memory (:mod:`ekfviz.sim`): its events and the truth behind them.

Not found from a path: code that simulates builds one (``SimulatedSource(run)``) and
replays it as any source, without writing a log first. Its truth knows every true pose,
one per step, and, for id-less scans, which landmark each measurement is.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.core.records import AnyEvent
from ekfviz.core.truth import GroundTruth
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.sources.base import OwnTruth, Source

if TYPE_CHECKING:  # the simulator is imported by what simulates, not by every source
    from ekfviz.sim.simulate import Simulation


@dataclass(frozen=True, slots=True)
class SimulatedSource(Source):
    """A simulated run; ``path`` only names it (nothing is read there)."""

    kind = "simulated"
    description = "a simulated run"

    run: Simulation
    path: Path = Path("simulated")

    @classmethod
    def detect(cls, path: Path) -> bool:
        return False  # made in memory, never found on disk

    @property
    def files(self) -> list[Path]:
        return []

    @property
    def progress_paths(self) -> list[Path]:
        return []

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        events = self.run.scan_events if self.run.scan_events is not None else self.run.events
        return iter(events)

    def own_truth(self, warn: WarningCallback) -> OwnTruth | None:
        truth = GroundTruth(
            ids=self.run.landmark_ids,
            landmarks_xy=self.run.landmarks_xy,
            poses_xytheta=self.run.poses_xytheta,
            scan_ids=self.run.scan_ids,
        )
        return OwnTruth(truth, [])
