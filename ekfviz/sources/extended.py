"""The extended log: one event a line, a keyword first (``control``, ``observe``,
``scan``), maybe after a timestamp; see :mod:`ekfviz.io.extended`.

Its ``scan`` lines are id-less: the association decides which landmark each is. Its
``# noise:`` header states the run's noise (the command line reads it as defaults).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.records import AnyEvent
from ekfviz.io.extended import LogNoise, is_extended, read_extended, read_log_noise
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.sources.base import Source, register


@register
@dataclass(frozen=True, slots=True)
class ExtendedSource(Source):
    """An extended log file."""

    kind = "extended"
    description = "an extended log file"

    path: Path

    @classmethod
    def detect(cls, path: Path) -> bool:
        return path.is_file() and is_extended(path)

    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        return read_extended(self.path, progress, warn)

    def stated_noise(self) -> LogNoise:
        return read_log_noise(self.path)
