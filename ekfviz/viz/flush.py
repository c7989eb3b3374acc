"""Flushing a recording stream without going deaf to Ctrl-C, or to a full disk."""

from __future__ import annotations

import contextlib
import os
import threading
import time
import weakref
from pathlib import Path

import rerun as rr

# Rerun's file sink stops writing when its disk is full (it logs the error itself) and a
# flush then waits out its whole timeout: the file a recording is written to, by stream
_FILES: weakref.WeakKeyDictionary[rr.RecordingStream, Path] = weakref.WeakKeyDictionary()
LOW_SPACE_BYTES = 64 * 1024  # less free space than this beside a file being written: full
SPACE_CHECK_AFTER_S = 0.5  # a flush that takes longer looks at the disk now and then


class DiskFull(RuntimeError):
    """A recording's file could not be written whole: its disk is full, or Rerun's file
    writer stopped (a file-size limit, a write error)."""


WRITER_THREAD = "file_writer"  # the name of Rerun's file sink thread (Linux shows it)


# the streams whose file writer was seen running (see note_writer): only for them does
# its absence mean that it stopped (another version of Rerun may name its thread otherwise)
_WRITERS: weakref.WeakSet[rr.RecordingStream] = weakref.WeakSet()


def writer_running() -> bool | None:
    """Whether Rerun's file writer thread runs in this process; None where that cannot
    be told (no /proc)."""
    try:
        tasks = os.listdir("/proc/self/task")
        names = []
        for task in tasks:
            with contextlib.suppress(OSError), open(f"/proc/self/task/{task}/comm") as comm:
                names.append(comm.read().strip())  # (OSError: a thread that ended meanwhile)
    except OSError:
        return None
    return WRITER_THREAD in names


def writer_stopped() -> bool:
    """Whether Rerun's file writer thread is gone from this process; False where that
    cannot be told (no /proc)."""
    return writer_running() is False


def note_writer(rec: rr.RecordingStream) -> None:
    """Look once whether ``rec``'s file writer runs, once its sinks are set (see
    :func:`watch_file`): a flush takes its end for a stopped writer only where it was
    seen running."""
    if rec in _FILES and writer_running():
        _WRITERS.add(rec)


def watch_file(rec: rr.RecordingStream, path: Path) -> None:
    """Have flushes of ``rec`` stop waiting once the disk of ``path`` (the file its sink
    writes) is full."""
    _FILES[rec] = path


def written_file(rec: rr.RecordingStream) -> Path | None:
    """The file ``rec``'s sink writes, if :func:`watch_file` was told."""
    return _FILES.get(rec)


def disk_full(path: Path) -> bool:
    """Whether the file system of ``path`` has (next to) no space left for it."""
    try:
        stats = os.statvfs(path.parent)
    except (OSError, AttributeError):
        return False
    # root may take the blocks reserved for it, others only those available to anyone
    blocks = stats.f_bfree if hasattr(os, "geteuid") and os.geteuid() == 0 else stats.f_bavail
    return blocks * stats.f_frsize < LOW_SPACE_BYTES


def flush_interruptibly(rec: rr.RecordingStream, timeout: float) -> None:
    """``rec.flush(timeout)``, with Ctrl-C and SIGTERM honoured while it waits.

    Rerun's flush blocks in native code, where Python's signal handlers cannot run; it
    runs in a helper thread here while this one waits in short slices.

    :raises RuntimeError: as ``flush`` does, for a sink that did not take the data
    :raises DiskFull: the disk of the stream's file (see :func:`watch_file`) is full, or
        Rerun's file writer has stopped: the flush would wait out its timeout for it
    """
    failure: list[BaseException] = []

    def flush() -> None:
        try:
            rec.flush(timeout_sec=timeout)
        except BaseException as error:  # handed to the waiting thread
            failure.append(error)

    helper = threading.Thread(target=flush, name="ekfviz-flush", daemon=True)
    helper.start()
    started = time.monotonic()
    path = _FILES.get(rec)
    while helper.is_alive():
        helper.join(0.1)
        if (
            path is not None
            and helper.is_alive()
            and time.monotonic() - started > SPACE_CHECK_AFTER_S
        ):
            if disk_full(path):
                raise DiskFull(f"no space left on the device of {path.parent}")
            if rec in _WRITERS and writer_stopped():
                raise DiskFull("Rerun's file writer stopped: a file-size limit or a write error")
    if failure:
        raise failure[0]
