"""Flushing a recording stream without going deaf to Ctrl-C."""

from __future__ import annotations

import threading

import rerun as rr


def flush_interruptibly(rec: rr.RecordingStream, timeout: float) -> None:
    """``rec.flush(timeout)``, with Ctrl-C and SIGTERM honoured while it waits.

    Rerun's flush blocks in native code, where Python's signal handlers cannot run; it
    runs in a helper thread here while this one waits in short slices.

    :raises RuntimeError: as ``flush`` does, for a sink that did not take the data
    """
    failure: list[BaseException] = []

    def flush() -> None:
        try:
            rec.flush(timeout_sec=timeout)
        except BaseException as error:  # handed to the waiting thread
            failure.append(error)

    helper = threading.Thread(target=flush, name="ekfviz-flush", daemon=True)
    helper.start()
    while helper.is_alive():
        helper.join(0.1)
    if failure:
        raise failure[0]
