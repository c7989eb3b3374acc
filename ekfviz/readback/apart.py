"""Read a recording in a child process, so that a damaged one cannot take ekfviz down.

Rerun's reader trusts the lengths written in a file: a recording with a few bytes flipped
can make it ask for exabytes, and an allocation that fails aborts the whole process
(Rust's out-of-memory handler), with a backtrace on stderr and no Python exception to
catch. ``ekfviz info`` and ``ekfviz export`` read recordings people attach to bug
reports, so :func:`read_apart` runs the reading in a forked child: what it reads comes
back through a pipe, and a child that dies says so as one line (exit code 2 at the
command line), with the first line the reader printed. Its stderr is its own.

Rerun's import starts a few threads of its own, and a child forked from a process with
threads could, in principle, find a lock held that no thread of its own will release:
a child that has not answered within :func:`patience` (half a minute, more for a large
file) is killed and the file read in the process, as where there is no ``fork``
(Windows) or it is not safe (macOS).
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import pickle
import select
import signal
import sys
import tempfile
import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from ekfviz.core.errors import UsageError

T = TypeVar("T")


class NotARecordingError(UsageError):
    """A file that is not an ekfviz recording, with a one-line reason."""


FORKS = sys.platform.startswith("linux")  # os.fork is safe to use with threads around here


class ReaderDied(RuntimeError):
    """The child reading a recording ended without an answer: its exit and what it said."""


def read_apart(read: Callable[[Path], T], path: Path | str) -> T:
    """``read(path)`` in a forked child process, its result or its error handed back.

    :raises NotARecordingError: what ``read`` raised, or, for any other error of the
        child or a child that died (killed by a signal, out of memory), one line naming
        ``path``; the child's traceback or last words are the error's cause
    """
    path = Path(path)  # (a str from a notebook)
    if not FORKS:
        return read(path)
    with tempfile.TemporaryFile() as said:
        reader, writer = os.pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        with warnings.catch_warnings():  # Python 3.12+ warns of fork with threads: see above
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child: nothing of the parent's runs on from here
            os.close(reader)
            _child(read, path, writer, said.fileno())
        os.close(writer)
        try:
            data = _answer(reader, patience(path))
        except BaseException:  # (Ctrl-C, a notebook's "interrupt"): no child left behind
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
            raise
        if data is None:  # no answer in time: the child is stuck, read here instead
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return read(path)
        _, status = os.waitpid(pid, 0)
        said.seek(0)
        last_words = said.read(4096).decode("utf-8", "replace").strip()
    if data:
        try:
            kind, value, detail = pickle.loads(data)
        except Exception:  # cut short: the child died while answering
            kind, value, detail = "error", f"{path}: a damaged recording: its reader died", ""
        if kind == "ok":
            return value  # type: ignore[no-any-return]
        error = NotARecordingError(value)
        error.__cause__ = ReaderDied(detail)
        raise error
    how = (
        f"killed by {signal.Signals(os.WTERMSIG(status)).name}"
        if os.WIFSIGNALED(status)
        else f"exit code {os.WEXITSTATUS(status)}"
    )
    first = last_words.splitlines()[0] if last_words else ""
    error = NotARecordingError(
        f"{path}: a damaged recording: Rerun's reader gave up on it ({how}"
        + (f": {first}" if first else "")
        + ")"
    )
    error.__cause__ = ReaderDied(last_words or how)
    raise error


def patience(path: Path) -> float:
    """Seconds to wait for a child's answer: 30, and one more per megabyte of the file
    (a 400 MB recording reads back in some 10 s here)."""
    try:
        size = path.stat().st_size
    except OSError:
        size = 0
    return 30.0 + size / 1e6


def _answer(reader: int, timeout_s: float) -> bytes | None:
    """All the child writes to ``reader`` until it closes it, or None if that takes
    longer than ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    chunks: list[bytes] = []
    with os.fdopen(reader, "rb", buffering=0) as answer:
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([answer], [], [], left)[0]:
                return None
            chunk = answer.read(1 << 20)
            if not chunk:
                return b"".join(chunks)
            chunks.append(chunk)


def _child(read: Callable[[Path], T], path: Path, writer: int, said: int) -> None:
    """Read, answer through ``writer`` (kind, value, detail), and leave at once (no exit
    handlers: they are the parent's). stdout and stderr go to ``said``."""
    code = 0
    try:
        faulthandler.disable()  # (a test runner's): its report of an abort is not ours
        os.dup2(said, 1)
        os.dup2(said, 2)
        # Python's own writes too, where sys.stderr was not fd 2 (under a test's capture)
        sys.stdout = sys.stderr = os.fdopen(said, "w", buffering=1, closefd=False)
        try:
            answer: tuple[str, object, str] = ("ok", read(path), "")
        except NotARecordingError as error:
            answer = ("error", str(error), traceback.format_exc())
        except BaseException as error:  # a reader's bug or panic on bad bytes: still bad input
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            answer = ("error", f"{path}: not a Rerun recording (.rrd): {reason}",
                      traceback.format_exc())  # fmt: skip
        with os.fdopen(writer, "wb") as out:
            pickle.dump(answer, out, protocol=pickle.HIGHEST_PROTOCOL)
    except BaseException:
        code = 1
    finally:
        with contextlib.suppress(BaseException):
            sys.stderr.flush()
        os._exit(code)
