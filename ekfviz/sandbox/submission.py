"""A submission's files, surveyed within bounds and copied into a private folder.

A sandboxed worker never sees the caller's files: what it may read of a submission is a
copy, made here before it starts and shown read-only at the submission's own path
(:class:`~ekfviz.sandbox.bwrap.Mount`). The survey reads no file's content and stops at
the first bound it passes, so that a submission of a million folders or a sparse file of
gigabytes costs ekfviz nothing: at most :data:`MAX_FILES` entries, :data:`MAX_BYTES` of
files in all, :data:`MAX_DEPTH` folders deep. A symbolic link is copied as the file it
names only where that file is inside the submission (one that leads out is refused, never
followed). In a folder, a file with hard links outside the folder is refused (its
content may be another's); a submission that is one file is that file, however linked.
Numpy only.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

MAX_FILES = 200  # files and folders of one submission
MAX_BYTES = 8 << 20  # bytes of its files in all
MAX_DEPTH = 16  # folders inside folders
MAX_SCANNED = 10_000  # entries looked at (of a --filter's folder, most are not taken)
_SKIPPED = ("__pycache__", ".git", ".ipynb_checkpoints")


class SubmissionRefused(Exception):
    """A submission that is not copied: over a bound, or a link that leads out; one line."""


@dataclass(frozen=True, slots=True)
class Submission:
    """What of the caller's files a sandboxed filter sees.

    :param root: the folder copied, shown at this same path
    :param only: the one file of ``root`` copied (None: the folder's files)
    :param python_only: of the folder, its ``.py`` files and the folders with an
        ``__init__.py`` (a filter given by ``--filter``, beside other files of the
        caller's), not every file (a submission's folder, all its own)
    """

    root: str
    only: str | None = None
    python_only: bool = False


@dataclass(frozen=True, slots=True)
class Survey:
    """A submission's files and folders within the bounds: each file as (its path in the
    submission, the real path of its content), each folder by its path in it."""

    files: tuple[tuple[str, str], ...]
    folders: tuple[str, ...]
    size: int


def survey(submission: Submission, name: str | None = None) -> Survey:
    """The files of ``submission`` to copy, without reading one.

    :param name: how messages name it (default: ``root``)
    :raises SubmissionRefused: over a bound, a link that leads out, a hard-linked file
    """
    root = Path(submission.root)
    said = name or str(root)
    files: list[tuple[str, str]] = []
    folders: list[str] = []
    size = 0
    pending: list[tuple[str, int]] = [("", 0)]
    scanned = 0
    while pending:
        folder, depth = pending.pop()
        names = _names(root, folder, said) if folder or not submission.only else [submission.only]
        for name in names:
            scanned += 1
            if scanned > MAX_SCANNED:
                raise SubmissionRefused(f"{said}: more than {MAX_SCANNED} entries to look at")
            if name in _SKIPPED:
                continue
            relative = f"{folder}/{name}" if folder else name
            kind, real = _kind(root, relative, said)
            if kind == "other" or (submission.python_only and not _python(kind, real, name)):
                continue
            if len(files) + len(folders) >= MAX_FILES:
                raise SubmissionRefused(
                    f"{said}: more than {MAX_FILES} files and folders (a submission holds"
                    " its module and the files it needs)"
                )
            if kind == "folder":
                if depth + 1 > MAX_DEPTH:
                    raise SubmissionRefused(f"{said}: folders more than {MAX_DEPTH} deep")
                folders.append(relative)
                pending.append((relative, depth + 1))
                continue
            size += os.stat(real).st_size  # (a sparse file: what it would read)
            if size > MAX_BYTES:
                raise SubmissionRefused(
                    f"{said}: more than {MAX_BYTES >> 20} MiB of files (a submission holds"
                    " its module and the files it needs)"
                )
            files.append((relative, real))
    if not submission.only:
        _linked_only_inside(files, said)
    return Survey(tuple(files), tuple(folders), size)


def _linked_only_inside(files: list[tuple[str, str]], said: str) -> None:
    """Refuse a folder's file with hard links outside the folder: its links (the inode's
    count) must all be among the folder's own files."""
    seen: dict[tuple[int, int], int] = {}
    links: dict[tuple[int, int], tuple[int, str]] = {}
    for relative, real in files:
        info = os.lstat(real)
        key = (info.st_dev, info.st_ino)
        seen[key] = seen.get(key, 0) + 1
        links[key] = (info.st_nlink, relative)
    for key, (count, relative) in links.items():
        if count > seen[key]:
            raise SubmissionRefused(
                f"{said}: {relative} has hard links outside the submission (its content may"
                " be another's)"
            )


def _names(root: Path, folder: str, said: str) -> Iterator[str]:
    """The names in a folder of the submission, as they come (never all read first)."""
    try:
        with os.scandir(root / folder) as entries:
            for entry in entries:
                yield entry.name
    except OSError as error:
        raise SubmissionRefused(f"{said}: cannot be read ({error.strerror})") from None


def _python(kind: str, real: str, name: str) -> bool:
    """Whether a filter given by ``--filter`` may import it: a ``.py`` file, or a folder
    that is a package."""
    if kind == "folder":
        return os.path.isfile(os.path.join(real, "__init__.py"))
    return name.endswith(".py")


def _kind(root: Path, relative: str, said: str) -> tuple[str, str]:
    """``file``, ``folder`` or ``other`` (a FIFO, a socket: not copied), and the real path
    of its content; a link is what it names, where that is inside the submission."""
    path = str(root / relative)
    real = path
    if os.path.islink(path):
        real = os.path.realpath(path)
        if not real.startswith(os.path.realpath(root) + os.sep):
            raise SubmissionRefused(
                f"{said}: {relative} is a symbolic link that leads out of the submission"
            )
    try:
        info = os.lstat(real)
    except OSError as error:
        raise SubmissionRefused(f"{said}: {relative}: {error.strerror}") from None
    if stat.S_ISDIR(info.st_mode):
        return "folder", real
    if not stat.S_ISREG(info.st_mode):
        return "other", real
    return "file", real


def copy(submission: Submission, found: Survey, into: str | None = None) -> str:
    """A private folder (mode 0700) holding ``found``'s files as ``submission`` has them,
    read-only; the caller removes it (:func:`remove`).

    :param into: a private folder made before to hold the copy, emptied first (it keeps
        its path: a sandbox that shows it already shows the new copy)
    :raises SubmissionRefused: a file changed under the copy (grew past the bound)
    """
    folder = into if into is not None else private_folder()
    if into is not None:
        _empty(into)
    try:
        for relative in found.folders:
            os.makedirs(os.path.join(folder, relative), exist_ok=True)
        left = MAX_BYTES
        for relative, real in found.files:
            left -= _copy_file(real, os.path.join(folder, relative), left)
        for relative, _ in found.files:
            os.chmod(os.path.join(folder, relative), 0o444)
        for relative in (*found.folders, ""):
            os.chmod(os.path.join(folder, relative), 0o555)
    except BaseException:
        remove(folder)
        raise
    return folder


def _copy_file(source: str, target: str, left: int) -> int:
    """Copy at most ``left`` bytes of ``source`` (a real path: no link followed); the
    bytes copied."""
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK  # (a FIFO put there since: no wait)
    with open(os.open(source, flags), "rb") as reading, open(target, "xb") as writing:
        data = reading.read(left + 1)
        if len(data) > left:
            raise SubmissionRefused(f"{source}: grew past {MAX_BYTES >> 20} MiB while copied")
        writing.write(data)
    return len(data)


def _empty(folder: str) -> None:
    """Remove what a private copy holds, the folder itself kept (made writable)."""
    for current, _, _ in os.walk(folder):
        os.chmod(current, 0o700)
    for entry in os.scandir(folder):
        if entry.is_dir(follow_symlinks=False):
            shutil.rmtree(entry.path)
        else:
            os.unlink(entry.path)


# A private copy's folder: the prefix, then the process that made it
COPY_PREFIX = "ekfviz-submission-"
# a copy whose process no longer runs is removed once it is this old (a copy just made
# is never taken for another's, whatever became of the process number in its name)
ORPHAN_AGE_S = 60.0


def private_folder() -> str:
    """A new private folder (mode 0700) for a submission's copy, named after this
    process. The first of a process removes the copies left by processes no longer
    running (stopped by SIGKILL, say, before they could remove their own)."""
    _remove_orphans_once()
    return tempfile.mkdtemp(prefix=f"{COPY_PREFIX}{os.getpid()}-")


@functools.cache
def _remove_orphans_once() -> None:
    remove_orphans(tempfile.gettempdir())


def remove_orphans(parent: str) -> list[str]:
    """Remove the private copies in ``parent`` that this user's processes made, that no
    process running now owns (its number is in the name) and that were last changed
    :data:`ORPHAN_AGE_S` ago or more; the folders removed."""
    removed = []
    settled = time.time() - ORPHAN_AGE_S
    with contextlib.suppress(OSError), os.scandir(parent) as entries:
        for entry in entries:
            if not entry.name.startswith(COPY_PREFIX):
                continue
            number = entry.name[len(COPY_PREFIX) :].split("-", 1)[0]
            if not number.isdigit() or _running(int(number)):
                continue  # named without its process, or its process still runs
            with contextlib.suppress(OSError):
                info = entry.stat(follow_symlinks=False)
                if (
                    stat.S_ISDIR(info.st_mode)
                    and info.st_uid == os.getuid()
                    and info.st_mtime <= settled
                ):
                    remove(entry.path)
                    removed.append(entry.path)
    return removed


def _running(pid: int) -> bool:
    """Whether a process numbered ``pid`` runs (another user's too)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove(folder: str) -> None:
    """Remove a private copy (its folders made writable first); never raises."""
    for current, _, _ in os.walk(folder):
        with contextlib.suppress(OSError):
            os.chmod(current, 0o700)
    shutil.rmtree(folder, ignore_errors=True)
