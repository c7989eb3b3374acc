"""Inputs that come through a pipe: a log on standard input (``-``) or from a process
substitution (``ekfviz replay <(zcat run.txt.gz)``, which names ``/dev/fd/63``).

A pipe can be read once, and ekfviz reads an input by its path, some of them more than
once: the log's format is told from its first line before its events are read, the
run's information hashes it, a study replays it once per filter. So a pipe given as an
input (a log, its truth) is read to its end as the command line is read, before the
command starts, into an anonymous temporary file that then takes the pipe's place under
the same descriptor number: on Linux, opening ``/dev/fd/N`` (``/dev/stdin`` is
``/dev/fd/0``) opens the file that descriptor holds, so every later open of the path the
user gave reads the whole input again, from its start, and every message still names
that path. The file has no name on disk and
is gone when ekfviz exits, however it exits.

Elsewhere (``/dev/fd/N`` is a duplicate of the descriptor, sharing its offset) nothing
is read ahead and the readers refuse a pipe as before.
"""

from __future__ import annotations

import fcntl
import os
import re
import stat
import sys
import tempfile

from ekfviz import signals
from ekfviz.core.errors import UsageError

STDIN = "-"  # the argument that means standard input
STDIN_PATH = "/dev/stdin"  # what it is replaced with: the path the readers open
MAX_PIPED_BYTES = 2 << 30  # a pipe that gives more is refused (``yes | ekfviz replay -``)
_BLOCK = 1 << 20
_DESCRIPTOR_PATH = re.compile(r"/(?:dev|proc/self)/fd/([0-9]+)")


class PipedInputError(UsageError):
    """A piped input that cannot be read ahead: the message names it as given."""


def read_ahead(path: str, stdin_taken: bool = False, limit: int = MAX_PIPED_BYTES) -> str:
    """The path to read an input given as ``path`` by: :data:`STDIN_PATH` for ``-``, the
    path itself otherwise; where it names a pipe (``-``, ``/dev/stdin``, ``/dev/fd/N``),
    the pipe read to its end into a file in its place first (see the module).

    :param stdin_taken: another input of the command is standard input already
    :raises PipedInputError: ``-`` given twice or on a terminal, a pipe of more than
        ``limit`` bytes, a temporary file that cannot hold what the pipe gave
    :raises signals.Interrupted: SIGINT or SIGTERM while a pipe is read
    """
    if path == STDIN:
        if stdin_taken:
            raise PipedInputError(f"{STDIN}: standard input is given twice; it can be read once")
        if os.isatty(0):
            raise PipedInputError(
                f"{STDIN}: standard input is a terminal, expected a log piped in"
                " (zcat log.txt.gz | ekfviz replay -)"
            )
        path = STDIN_PATH
    fd = _descriptor(path)
    if fd is not None and sys.platform.startswith("linux") and _is_readable_pipe(fd):
        with signals.interruptible():  # a pipe that never ends: Ctrl-C stops the wait
            _spool(fd, path, limit)
    return path


def _descriptor(path: str) -> int | None:
    """The descriptor a path opens (``/dev/fd/N``, ``/proc/self/fd/N``, ``/dev/stdin``)."""
    if path == STDIN_PATH:
        return 0
    match = _DESCRIPTOR_PATH.fullmatch(path)
    return int(match.group(1)) if match else None


def _is_readable_pipe(fd: int) -> bool:
    """Whether ``fd`` is open for reading on a pipe or a socket (an output's ``>(...)``
    is open for writing: left alone)."""
    try:
        mode = os.fstat(fd).st_mode
        flags = fcntl.fcntl(fd, fcntl.F_GETFL)
    except OSError:  # not open: the readers say "no such file"
        return False
    if not (stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode)):
        return False
    return flags & os.O_ACCMODE in (os.O_RDONLY, os.O_RDWR)


def _spool(fd: int, shown: str, limit: int) -> None:
    """Read the pipe ``fd`` to its end into an anonymous file put in its place."""
    where = tempfile.gettempdir()
    try:
        os.set_blocking(fd, True)  # (a shell's pipe is; one left non-blocking would not wait)
        with tempfile.TemporaryFile(prefix="ekfviz-piped-") as spool:
            total = 0
            while block := os.read(fd, _BLOCK):
                total += len(block)
                if total > limit:
                    raise PipedInputError(
                        f"{shown}: the pipe gave more than {limit / (1 << 30):g} GiB, expected a"
                        " log that ends (give a log that long as a file)"
                    )
                spool.write(block)
            spool.flush()
            os.dup2(spool.fileno(), fd, inheritable=fd <= 2)
    except OSError as error:
        raise PipedInputError(
            f"{shown}: what the pipe gave could not be kept in a temporary file in {where}"
            f" ({error.strerror or error})"
        ) from None
