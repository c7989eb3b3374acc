"""Output paths checked before any work: a run must not fail at its very end on its path.

:func:`check_output_path` says in one line what is wrong with a path a command is told to
write (a folder, a missing or unwritable folder, a file where a folder should be) and
creates nothing: no folder, no file left behind.
"""

from __future__ import annotations

import errno
import hashlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path


class OutputPathError(ValueError):
    """An output path that cannot be written, as ``OPTION PATH: what is wrong``."""


def check_output_path(path: Path | str, option_name: str) -> Path:
    """Check that a file can be written at ``path``, before any work starts.

    The file's folder must exist (it is never created here) and take a new file; the path
    must not name a folder. An existing file at ``path`` is fine: it is replaced, whole,
    when the command is done.

    :param option_name: how the user gave the path (``--save``, ``TARGET``), for the message
    :return: ``path`` as a ``Path``
    :raises OutputPathError: naming the option, the path and the problem
    """
    text = str(path)
    path = Path(path)
    where = f"{option_name} {text}".strip()
    if text == "" or text.endswith(os.sep) or path.name in ("", ".", ".."):
        raise OutputPathError(f"{where}: names a folder, expected a file name")
    try:
        return _checked_output_path(path, where)
    except OSError as error:  # a name too long, a loop of links, an unreadable folder...
        reason = error.strerror or type(error).__name__
        raise OutputPathError(f"{where}: cannot be written ({reason})") from None


def _checked_output_path(path: Path, where: str) -> Path:
    """:func:`check_output_path` past its first checks; ``where`` names the path."""
    _check_name_length(path, where)
    if path.is_symlink() and not path.exists():  # a link to nothing, or a loop of links
        try:
            os.stat(path)
        except OSError as error:
            if error.errno == errno.ELOOP:  # (writing "through" it replaced the link)
                raise OutputPathError(f"{where}: a loop of symbolic links") from None
    if path.is_dir():
        raise OutputPathError(f"{where}: is a folder, expected a file name")
    parent = path.parent
    if not parent.exists():
        blocker = _file_ancestor(parent)
        if blocker is not None:
            raise OutputPathError(f"{where}: {blocker} is a file, not a folder")
        raise OutputPathError(f"{where}: the folder {parent} does not exist")
    if not parent.is_dir():
        raise OutputPathError(f"{where}: {parent} is a file, not a folder")
    if path.exists() and not path.is_file():
        raise OutputPathError(f"{where}: exists and is not a regular file")
    try:  # the only sure test of a folder taking a new file: make one, remove it at once
        fd, probe = tempfile.mkstemp(dir=parent, prefix=".ekfviz.", suffix=".probe")
    except OSError as error:
        reason = error.strerror or type(error).__name__
        if error.errno in (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOENT):
            reason = {
                errno.EROFS: "read-only file system",
                errno.ENOENT: "cannot create files there",
            }.get(error.errno or 0, "permission denied")
        raise OutputPathError(f"{where}: cannot write in {parent} ({reason})") from None
    os.close(fd)
    os.unlink(probe)
    return path


def _check_name_length(path: Path, where: str) -> None:
    """Refuse a file name longer than its folder's file system takes (255 bytes on most):
    the run would otherwise fail at its very end, when the file is made."""
    try:
        name_max = os.pathconf(path.parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    size = len(os.fsencode(path.name))
    if name_max > 0 and size > name_max:
        raise OutputPathError(
            f"{where}: the file name is {size} bytes long, expected at most {name_max}"
            " (the longest its folder's file system takes)"
        )


# The longest name whose temporary files beside it (``.NAME.`` with a process id, a tag
# and a suffix, see temporary_prefix) still fit in the 255 bytes of a file name
TEMPORARY_NAME_MAX = 200


def temporary_prefix(path: Path) -> str:
    """The start of the names of the temporary files written beside ``path`` before they
    replace it: ``.NAME.``, or for a name too long to take the rest (near the file
    system's 255 bytes) ``.`` and a digest of it, so that such a file is written too."""
    name = path.name
    if len(os.fsencode(name)) > TEMPORARY_NAME_MAX:
        name = hashlib.sha256(os.fsencode(name)).hexdigest()[:16]
    return f".{name}."


def real_path(path: Path | str) -> Path:
    """``path`` made absolute, its symbolic links followed as far as they go. Never
    raises: a loop of links (which ``Path.resolve`` refuses) is left where it starts."""
    return Path(os.path.realpath(path))


def same_file(a: Path | str, b: Path | str) -> bool:
    """Whether two existing paths name one file (a hard link, a symbolic link, a path
    spelt another way); False where either does not exist or cannot be looked at."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def output_over_input(outputs: dict[str, Path | None], inputs: Iterable[Path | None]) -> str | None:
    """A one-line complaint when an output of a command is one of its inputs (writing it
    would replace the file being read: a log, a truth file, a recording), else None.

    :param outputs: option name -> path given (None: not given)
    :param inputs: the files the command reads (None: not given)
    """
    sources = [path for path in inputs if path is not None]
    for option, path in outputs.items():
        if path is None:
            continue
        for source in sources:
            if same_file(path, source):
                return (
                    f"{option} {path}: is the input {source}, which writing it would replace:"
                    " give another file"
                )
    return None


def _file_ancestor(folder: Path) -> Path | None:
    """The nearest existing ancestor of a missing folder, if it is a file."""
    for ancestor in (folder, *folder.parents):
        if ancestor.exists():
            return None if ancestor.is_dir() else ancestor
    return None


def distinct_paths(paths: dict[str, Path | None]) -> str | None:
    """A one-line complaint when two outputs of one command are the same file, else None.

    :param paths: option name -> path given (None: not given)
    """
    seen: dict[Path, str] = {}
    for option, path in paths.items():
        if path is None:
            continue
        key = real_path(path)
        if key in seen:
            return f"{seen[key]} and {option} are the same file ({path}): give two paths"
        seen[key] = option
    return None


def unused_path(path: Path) -> Path:
    """``path`` if no file is there, else the first free ``STEM-2.SUFFIX``, ``STEM-3``, ...:
    a default output name never replaces an earlier run's file."""
    candidate, k = path, 1
    while candidate.exists():
        k += 1
        candidate = path.with_name(f"{path.stem}-{k}{path.suffix}")
    return candidate


def check_output_folder(path: Path | str, option_name: str) -> Path:
    """Like :func:`check_output_path`, for a folder a command fills with files: an
    existing folder that takes new files, or a new one whose parent exists (it is made
    by the command, once its work is done; not here).

    :raises OutputPathError: naming the option, the path and the problem
    """
    path = Path(path)
    if not path.exists():
        return check_output_path(path, option_name)
    where = f"{option_name} {path}".strip()
    if not path.is_dir():
        raise OutputPathError(f"{where}: exists and is not a folder")
    try:
        fd, probe = tempfile.mkstemp(dir=path, prefix=".ekfviz.", suffix=".probe")
    except OSError as error:
        raise OutputPathError(
            f"{where}: cannot write in it ({error.strerror or type(error).__name__})"
        ) from None
    os.close(fd)
    os.unlink(probe)
    return path
