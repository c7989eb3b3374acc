"""SIGINT and SIGTERM for a replay: never lose the recording, whenever they arrive.

A replay keeps everything it recorded before an interrupt (see ``ekfviz replay``). The
first second of a run is spent importing rerun and numpy, before there is anything to
record; a signal then would end the process with nothing saved. So the command line
*defers* both signals from its first line on (:func:`defer`); ``replay`` turns them into
exceptions once its recording is open (:func:`as_exceptions`) and honours one that came
early right after logging its first event (:func:`raise_pending`). Other commands get
the usual behaviour back at once (:func:`restore`).

SIGINT is handled even when the parent started ekfviz with SIGINT ignored, as a
non-interactive shell does for ``ekfviz ... &``: ``kill -INT`` must still stop a replay
cleanly.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

_pending: list[int] = []


class Terminated(BaseException):  # like KeyboardInterrupt: not caught by "except Exception"
    """SIGTERM, turned into an exception so that a run can close its recording."""


def _remember(signum: int, frame: FrameType | None) -> None:
    _pending.append(signum)


def _raise(signum: int, frame: FrameType | None = None) -> None:
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated


def defer() -> None:
    """From now on, remember SIGINT and SIGTERM instead of acting on them."""
    signal.signal(signal.SIGINT, _remember)
    signal.signal(signal.SIGTERM, _remember)


def restore() -> None:
    """The usual handlers again; a signal that came while deferred is acted on now."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if _pending:
        signum = _pending.pop(0)
        _pending.clear()
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        signal.raise_signal(signum)


def raise_pending() -> None:
    """Raise the exception of a signal that came while deferred, if any."""
    if _pending:
        signum = _pending.pop(0)
        _pending.clear()
        _raise(signum)


@contextmanager
def as_exceptions() -> Iterator[None]:
    """Inside the block SIGINT raises KeyboardInterrupt and SIGTERM :class:`Terminated`;
    one that came earlier waits for :func:`raise_pending`. The usual handlers after it."""
    signal.signal(signal.SIGINT, _raise)
    signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        _pending.clear()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
