"""Every file ekfviz writes, written whole or not at all, to a path checked before any work.

- Output paths: :func:`check_output_path` says in one line what is wrong with a path a
  command is told to write (a folder, a missing or unwritable folder, a file where a
  folder should be, a loop of links) and creates nothing: a run must not fail at its very
  end on its path. Two outputs must be two files, and none may be an input.
- Atomic writes: :func:`write_files_atomic` writes reports, tables, logs and exports
  beside their paths and renames them over the paths together, so that an existing file
  is never left half-written and files that belong together are replaced together.
- A recording's own commit: a recording is written by Rerun's file sink under
  :func:`temporary_beside` and moved over its path by :func:`commit_recording` once it is
  whole; a run cut short goes to :func:`partial_path` rather than replace a file, and
  what runs killed outright left behind is removed (:func:`remove_stale_parts`).

Whatever cannot be written is an :class:`~ekfviz.core.errors.OutputError` naming the
path, the existing file left as it was.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import math
import os
import tempfile
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path

from ekfviz import signals
from ekfviz.core.errors import OutputError


class OutputPathError(OutputError):
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


def check_outputs(*outputs: tuple[str, Path | None], inputs: Iterable[Path | None] = ()) -> None:
    """Check every output path of a command before any work starts (see
    :func:`check_output_path`); two outputs must be two files, and none may be an input
    (writing it would replace the file being read).

    :param outputs: (how the path was given, e.g. ``--save``; the path or None)
    :param inputs: the files the command reads (None: not given)
    :raises OutputPathError: the first path that cannot be written as asked
    """
    for option, path in outputs:
        if path is not None:
            check_output_path(path, option)
    clash = distinct_paths(dict(outputs)) or output_over_input(dict(outputs), inputs)
    if clash is not None:
        raise OutputPathError(clash)
    for option, path in outputs:
        if option == "--save" and path is not None and path.suffix.lower() != ".rrd":
            instead = path.with_suffix(".rrd").name
            raise OutputPathError(f"--save {path}: a recording is a .rrd file (expected a name"
                                  f" ending in .rrd, such as {instead})")  # fmt: skip


def refuse_output_over_input(
    *outputs: tuple[str, Path | None], inputs: Iterable[Path | None]
) -> None:
    """Refuse an output that is one of ``inputs``: for the files known only once the
    input is open (a dataset directory's).

    :raises OutputPathError: naming the output and the input it would replace
    """
    clash = output_over_input(dict(outputs), inputs)
    if clash is not None:
        raise OutputPathError(clash)


def refuse_overwrite(force: bool, *outputs: tuple[str, Path | None]) -> None:
    """Without ``force``, refuse to write over an existing file.

    :param outputs: (how the path was given, e.g. ``--output``; the path or None)
    :raises OutputPathError: naming the first file that exists
    """
    if force:
        return
    for option, path in outputs:
        if path is not None and path.is_file():
            raise OutputPathError(f"{option} {path}: exists; add --force to replace it")


# -- atomic writes ------------------------------------------------------------------------


def json_text(document: object) -> str:
    """A document as ekfviz writes JSON (reports and ``--json``): indented, a non-finite
    number as null (JSON has none; Python's NaN and Infinity are not JSON)."""
    return json.dumps(_finite(document), indent=2, allow_nan=False) + "\n"


def _finite(value: object) -> object:
    """``value`` with every non-finite float in it as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def write_json(path: Path, document: dict[str, object]) -> None:
    """A JSON report (see :func:`json_text`), written whole or not at all."""
    write_bytes_atomic(path, json_text(document).encode("utf-8"))


def write_bytes_atomic(path: Path, content: bytes) -> None:
    """Write beside ``path`` and rename, so an existing file is never left half-written."""
    write_files_atomic({path: content})


def write_files_atomic(contents: dict[Path, bytes]) -> None:
    """Write every file beside its path first, then rename them all: an existing file is
    never left half-written, and files that belong together (a log and its truth) are
    replaced together or not at all.

    A symbolic link's target is written, the link kept. A signal while the files are
    renamed is acted on after the last rename; the :class:`~ekfviz.signals.Interrupted`
    it raises then carries the files written as ``written``.

    :raises OutputError: a file that cannot be written (a full disk, a file-size limit);
        nothing is replaced then
    """
    written: list[tuple[str, Path]] = []  # (the temporary file, its path)
    renamed = False
    try:
        for target, content in contents.items():
            path = real_path(target)  # (resolve() raises on a loop of links)
            written.append((_write_beside(path, content), path))
        with signals.held():  # a signal now: after the last rename (all or none)
            for tmp, path in written:
                os.replace(tmp, path)
            renamed = True
    except BaseException as error:
        for tmp, _ in written:
            Path(tmp).unlink(missing_ok=True)
        if renamed and isinstance(error, signals.Interrupted):  # said by the command line
            error.written = tuple(path for _, path in written)
        raise


def _write_beside(path: Path, content: bytes) -> str:
    """A temporary file beside ``path`` holding ``content``, with the mode ``path`` gets.

    :raises OutputError: it cannot be made or written whole (it is removed then)
    """
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temporary_prefix(path), suffix=".tmp")
    except OSError as error:
        raise OutputError(
            f"{path}: cannot write ({error.strerror}); nothing was replaced"
        ) from None
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(content)
        os.chmod(tmp, _file_mode(path))
    except BaseException as error:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(error, OSError):  # a full disk, a file-size limit: the old files stay
            why = error.strerror or error
            raise OutputError(f"{path}: cannot write ({why}); nothing was replaced") from None
        raise
    return tmp


def _file_mode(path: Path) -> int:
    """The mode a file written at ``path`` should get: the old file's, else the umask's."""
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


# -- a recording's commit -----------------------------------------------------------------


def temporary_beside(target: Path) -> Path:
    """A fresh hidden name in the folder of ``target``: the same file system, so a
    finished file can replace ``target`` atomically with ``os.replace``.

    The name holds this process's id, so that the next run to ``target`` can tell a
    file of a run that died (see :func:`remove_stale_parts`) from one being written.
    """
    remove_stale_parts(target)
    return target.with_name(f"{temporary_prefix(target)}{os.getpid()}.{uuid.uuid4().hex[:8]}.part")


def remove_stale_parts(target: Path) -> list[Path]:
    """Remove the temporary files beside ``target`` of runs whose process is gone (a
    run killed with ``kill -9`` cannot remove its own); those of live processes stay.

    :return: the files removed
    """
    removed: list[Path] = []
    prefix = temporary_prefix(target)
    try:
        names = [entry.name for entry in os.scandir(target.parent or Path("."))]
    except OSError:
        return removed
    for name in names:
        if not (name.startswith(prefix) and name.endswith(".part")):
            continue
        fields = name[len(prefix) : -len(".part")].split(".")
        if len(fields) != 2 or not fields[0].isdigit() or _alive(int(fields[0])):
            continue
        stale = target.with_name(name)
        with contextlib.suppress(OSError):
            stale.unlink()
            removed.append(stale)
    return removed


def _alive(pid: int) -> bool:
    """Whether a process with this id exists (one of another user's counts)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def partial_path(target: Path) -> Path:
    """Where the recording of a run cut short goes when a file is at ``target``:
    ``RUN.partial.rrd`` beside ``RUN.rrd`` (an earlier partial recording there is
    replaced)."""
    return target.with_name(f"{target.stem}.partial{target.suffix or '.rrd'}")


def commit_recording(
    temporary: Path, real: Path, target: Path, *, complete: bool, partial: bool
) -> Path | None:
    """Move a complete recording over its path and a partial one over its path or,
    when a file is there already, beside it (:func:`partial_path`); drop an incomplete
    one.

    :param real: ``target`` with its symbolic links followed: a link's target is
        written, the link kept (moved over the link itself, the file would replace it:
        ``--save /dev/stdout`` replaced the system's link with a recording)
    :return: where the recording was written (``target`` as given when it went there),
        None when it was dropped
    :raises OutputError: the temporary file could not be moved (it is removed then)
    """
    if not complete:
        temporary.unlink(missing_ok=True)
        return None
    beside = partial and real.exists()
    try:
        os.replace(temporary, partial_path(real) if beside else real)
    except OSError as error:  # e.g. a user's filter that cleaned up the folder meanwhile
        temporary.unlink(missing_ok=True)
        raise OutputError(
            f"{target}: the recording could not be saved: its temporary file {temporary.name}"
            f" did not move there ({error.strerror}: removed during the run?)"
        ) from None
    if beside:
        return partial_path(real) if target.is_symlink() else partial_path(target)
    return target


@contextlib.contextmanager
def replaced_whole(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write a file to, moved over ``path`` only
    when the block completes; removed otherwise, leaving an existing file untouched (a
    symbolic link's target is written, the link kept)."""
    path = real_path(path)
    temporary = temporary_beside(path)
    try:
        yield temporary
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
