"""Where a command's outputs go when the user names none, and the lines that say where
they went, with the command that opens them from the user's shell."""

from __future__ import annotations

import shlex
import shutil
import sys
from pathlib import Path

from ekfviz.core.errors import OutputError
from ekfviz.core.tables import utf8
from ekfviz.io.files import unused_path

RECORDINGS_DIR = Path("recordings")


def default_output(name: str, folder: Path = RECORDINGS_DIR) -> Path:
    """A default output path in ``folder`` (made here if missing), never one that
    already holds a file (see :func:`ekfviz.io.files.unused_path`).

    :raises OutputError: the folder cannot be made
    """
    try:
        folder.mkdir(exist_ok=True)
    except OSError as error:
        raise OutputError(
            f"{folder}: cannot make the folder for recordings ({error.strerror})"
        ) from None
    return unused_path(folder / name)


def saved_line(path: Path) -> str:
    """That a recording was saved at ``path``, with the command that opens it in the
    viewer, quoted for the user's shell (a name with a space, a quote or a line break)."""
    name = utf8(str(path))  # (a name that is not UTF-8: its other bytes as U+FFFD)
    opens = f"{shlex.quote(command_hint('rerun'))} {shlex.quote(name)}"
    return f"Saved {name}; open it with: {opens}"


def command_hint(program: str) -> str:
    """How to run ``program`` (``rerun``, ``ekfviz``) from the user's shell: its bare name
    when the shell finds this installation's, else its path beside this Python (an
    unactivated virtual environment)."""
    beside = Path(sys.executable).parent / program
    found = shutil.which(program)
    if not beside.is_file():
        return program
    if found is not None and Path(found).resolve() == beside.resolve():
        return program
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


def filter_module(spec: str) -> Path | None:
    """The file a ``--filter`` names (``PATH.py`` or ``PATH.py:Class``), an input not to
    write over; None for a built-in filter or an importable module."""
    head = spec.split(":", 1)[0]
    return Path(head) if head.endswith(".py") else None
