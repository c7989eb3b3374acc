"""ekfviz's own errors, one family: bad input (in a file, or in what was asked), an output
that cannot be written, a filter that cannot go on. The command line maps each to its
exit code; nothing below it exits."""

from __future__ import annotations

from pathlib import Path


class EkfvizError(Exception):
    """Something ekfviz says in one line and stops for (never a bug of ekfviz's own)."""


class InputError(EkfvizError, ValueError):
    """Bad input, reported as ``FILE:LINE: what was found, what was expected``.

    :param path: the file at fault
    :param line: 1-based line number, or 0 when the fault is not on a line
    :param message: what was found and what was expected
    """

    def __init__(self, path: Path | str, line: int, message: str) -> None:
        self.path = Path(path)
        self.line = line
        self.message = message
        super().__init__(str(self))

    def __reduce__(self) -> tuple[type[InputError], tuple[Path, int, str]]:
        # rebuilt from its three arguments where a worker process hands it back
        return type(self), (self.path, self.line, self.message)

    def __str__(self) -> str:
        where = f"{self.path}:{self.line}" if self.line > 0 else f"{self.path}"
        return f"{where}: {self.message}"


class OutputError(EkfvizError, ValueError):
    """An output path that cannot be written as asked (a folder, a link loop, a full disk)."""


class UsageError(EkfvizError):
    """What a command was asked cannot be done, said whole in one line where no file's line
    is at fault: an option's value, options that exclude each other, a path that is not
    what the command reads (``--bind 1.2.3: expected an IP address``)."""


class FilterError(EkfvizError, ValueError):
    """The filter cannot go on: a non-finite state, a landmark named twice, ...

    Faults confined to one observation (a landmark predicted at zero range, an
    innovation covariance that is not positive definite) are not errors: the
    observation is skipped and the filter's warnings say why.
    """
