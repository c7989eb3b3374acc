"""The classic log (the course's format): ``<id> <bearing> <range> ...`` observation
lines and ``<d> <alpha>`` control lines, its first line naming every landmark.

The fallback of detection: any path that no other format claims is read as a classic
log, whose reader then says what is wrong with it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.records import AnyEvent
from ekfviz.io.classic import read_classic
from ekfviz.io.extended import LogNoise, read_log_noise
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.sources.base import Source, register


@register
@dataclass(frozen=True, slots=True)
class ClassicSource(Source):
    """A classic log file."""

    kind = "classic"
    description = "a classic log file"
    names_every_landmark = True
    ids_only = True

    path: Path

    @classmethod
    def detect(cls, path: Path) -> bool:
        return not path.is_dir()

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        return read_classic(self.path, progress, warn)

    def stated_noise(self) -> LogNoise:
        return read_log_noise(self.path)  # a "# noise:" comment reads in either format
