"""What a use case tells its front end while it runs: notes, warnings and progress.

A use case prints nothing itself. The command line hands it a :class:`Reporter` that
prints notes on standard output, holds warnings until the input has been read whole
(an error then stands alone) and draws progress bars where standard error is a
terminal; a program using the use cases can hand it :class:`Silent`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Protocol, TypeVar

from ekfviz.io.text import ProgressCallback


class Reporter(Protocol):
    """The front end's ear (see the module)."""

    def note(self, text: str) -> None:
        """A line for the user about what was chosen or done (said at once)."""

    def warn(self, text: str) -> None:
        """Something that does not stop the command (a reader's, a filter's)."""

    def reading(
        self, name: str, total_bytes: int
    ) -> AbstractContextManager[ProgressCallback | None]:
        """A progress bar over the bytes of an input being read, called with the sum read
        so far; None where none is shown."""

    def counting(self, what: str, total: int) -> AbstractContextManager[Callable[[], None]]:
        """A progress bar over ``total`` units of work (``what``: "12 variants"), called
        once a unit is done."""


class Silent:
    """A :class:`Reporter` that keeps everything to itself: the notes and warnings are
    kept in :attr:`notes` and :attr:`warnings`, and no progress is shown."""

    def __init__(self) -> None:
        self.notes: list[str] = []
        self.warnings: list[str] = []

    def note(self, text: str) -> None:
        self.notes.append(text)

    def warn(self, text: str) -> None:
        self.warnings.append(text)

    def reading(
        self, name: str, total_bytes: int
    ) -> AbstractContextManager[ProgressCallback | None]:
        return _nothing(None)

    def counting(self, what: str, total: int) -> AbstractContextManager[Callable[[], None]]:
        return _nothing(_done)


def _done() -> None:
    """A unit of work done, shown nowhere."""


T = TypeVar("T")


@contextmanager
def _nothing(value: T) -> Iterator[T]:
    yield value
