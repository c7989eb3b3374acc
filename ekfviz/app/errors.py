"""The errors a use case ends with, as its front ends see them: ekfviz's own family (see
:mod:`ekfviz.core.errors`), a replay cut short, and the interrupts of SIGINT and SIGTERM.

:func:`in_family` is the one place where the errors of lower layers that are not of the
family (they carry more than a line for their other callers) join it.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from ekfviz import signals
from ekfviz.core.errors import EkfvizError, FilterError, InputError, OutputError, UsageError
from ekfviz.filters.spec import FilterSpecError
from ekfviz.signals import Interrupted, Terminated
from ekfviz.studies.executors import ExecutorError

__all__ = [
    "EkfvizError",
    "FilterError",
    "InputError",
    "Interrupted",
    "OutputError",
    "RunStopped",
    "Terminated",
    "UsageError",
    "in_family",
    "stopped_study",
    "written_before",
]


class RunStopped(EkfvizError):
    """A replay cut short by bad input, a filter that cannot go on, SIGINT or SIGTERM.

    :ivar reason: why and where, as its recording's last line says it
    :ivar kept: whether the recording of everything before it was kept
    :ivar saved_to: where that recording was saved, if it was (set by the use case)
    :ivar left: the ``--save`` file left as it was, if any (set by the use case)
    :ivar exit_code: 130 for SIGINT, 143 for SIGTERM (as a shell reports them), else 2
    :ivar line: the whole line to say, where the stop came outside the replay itself
    """

    def __init__(self, reason: str, cause: BaseException, kept: bool) -> None:
        super().__init__(reason)
        self.reason = reason
        self.kept = kept
        self.saved_to: Path | None = None
        self.left: Path | None = None
        self.line: str | None = None
        if isinstance(cause, KeyboardInterrupt):
            self.exit_code = 130  # 128 + SIGINT, as a shell reports it
        elif isinstance(cause, signals.Terminated):
            self.exit_code = 143  # 128 + SIGTERM
        else:
            self.exit_code = 2

    def __str__(self) -> str:
        """The reason, and what was kept where."""
        if self.line is not None:
            return self.line
        where = ""
        if self.kept and self.saved_to is not None:
            where = f"; the recording of everything before it is saved in {self.saved_to}"
            if self.left is not None and self.saved_to != self.left:
                where += f" ({self.left} is left as it was)"
        elif self.left is not None and self.left.exists():
            where = f"; {self.left} is left as it was"
        return f"{self.reason}{where}"


def written_before(written: Sequence[Path], not_written: Sequence[Path | None]) -> str:
    """What a command stopped while it wrote its outputs kept: those ``written`` (whole),
    and those not (an existing one left as it was)."""
    rest = [str(path) for path in not_written if path is not None]
    said = f"{', '.join(map(str, written))} written whole before it" if written else ""
    left = f"{', '.join(rest)} not written (an existing file left as it was)" if rest else ""
    return "; ".join(part for part in (said, left) if part) or "nothing was written"


def stopped_study(done: int, total: int, what: str, outputs: Sequence[Path | None]) -> str:
    """What an interrupted study kept: the runs done of all, and that no output was
    written (each is written whole at the end), an existing one left as it was."""
    existing = [str(path) for path in outputs if path is not None and path.exists()]
    kept = f" ({', '.join(existing)} left as it was)" if existing else ""
    return f"{done} of {total} {what} done, the rest cancelled; nothing was saved{kept}"


@contextmanager
def in_family() -> Iterator[None]:
    """Raise the errors of the filter's loading (a ``--filter`` that cannot be loaded) and
    of the study executors (a Dask cluster that cannot be reached) as members of the
    family, their one line kept."""
    try:
        yield
    except FilterSpecError as error:
        raise FilterError(str(error)) from error
    except ExecutorError as error:
        raise UsageError(str(error)) from error
