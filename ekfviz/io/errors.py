"""The one error type every reader raises for bad input."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
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
