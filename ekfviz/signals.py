"""SIGINT and SIGTERM for a replay: never lose the recording, whenever they arrive.

A replay keeps everything it recorded before an interrupt (see ``ekfviz replay``). The
first second of a run is spent importing rerun and numpy, before there is anything to
record; a signal then would end the process with nothing saved. So the command line
*defers* both signals from its first line on (:func:`defer`); ``replay`` turns them into
exceptions once its recording is open (:func:`as_exceptions`) and honours one that came
early right after logging its first event (:func:`raise_pending`). Every other command
turns them into :class:`Interrupted` at once (:func:`as_interrupts`), which the command
line answers with one line saying what was kept, and exit code 130 or 143; a second
signal while it cleans up is ignored.

SIGINT is handled even when the parent started ekfviz with SIGINT ignored, as a
non-interactive shell does for ``ekfviz ... &``: ``kill -INT`` must still stop a replay
cleanly.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType

_pending: list[int] = []


class Interrupted(BaseException):  # like KeyboardInterrupt: not caught by "except Exception"
    """SIGINT (or, as :class:`Terminated`, SIGTERM) in a command: stop, clean up, say so.

    Not a KeyboardInterrupt, which typer would answer with "Aborted." and exit code 1.

    :ivar kept: what the command kept, and where, as the line saying it stopped says it
        (None: nothing was written, unless ``written``)
    :ivar written: the files written whole just before it (a set of files replaced
        together, the signal acted on after the last of them)
    """

    signum: int = signal.SIGINT
    kept: str | None = None
    written: tuple[Path, ...] = ()

    @property
    def name(self) -> str:
        """``SIGINT`` or ``SIGTERM``."""
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """128 + the signal's number, as a shell reports a process the signal ended."""
        return 128 + self.signum


class Terminated(Interrupted):
    """SIGTERM, turned into an exception so that a run can close its recording."""

    signum = signal.SIGTERM


def _remember(signum: int, frame: FrameType | None) -> None:
    _pending.append(signum)


def _raise(signum: int, frame: FrameType | None = None) -> None:
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated


_owner: list[int] = []  # the process that turned signals into Interrupted
_fired: list[int] = []  # the signal that did, in case its exception was swallowed


def _interrupt(signum: int, frame: FrameType | None = None) -> None:
    if _owner and os.getpid() != _owner[0]:
        return  # a worker just forked, before its own handlers: its parent stops it
    _fired.append(signum)
    defer()  # a second signal while the first is handled must not cut the clean-up short
    raise Terminated if signum == signal.SIGTERM else Interrupted


def _handle(on_sigint: signal._HANDLER, on_sigterm: signal._HANDLER) -> None:
    signal.signal(signal.SIGINT, on_sigint)
    signal.signal(signal.SIGTERM, on_sigterm)


def _usual() -> None:
    _handle(signal.default_int_handler, signal.SIG_DFL)


def _take_pending() -> int | None:
    """The first signal remembered while deferred, forgetting any others."""
    signum = _pending[0] if _pending else None
    _pending.clear()
    return signum


def defer() -> None:
    """From now on, remember SIGINT and SIGTERM instead of acting on them."""
    _handle(_remember, _remember)


def restore() -> None:
    """The usual handlers again; a signal that came while deferred is acted on now."""
    _usual()
    signum = _take_pending()
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    if signum is not None:
        signal.raise_signal(signum)


def as_interrupts() -> None:
    """From now on SIGINT raises :class:`Interrupted` and SIGTERM :class:`Terminated`
    (the commands other than replay); one that came while deferred is raised now."""
    _owner[:] = [os.getpid()]
    _fired.clear()
    sys.unraisablehook = _quiet_unraisable
    _handle(_interrupt, _interrupt)
    signum = _take_pending()
    if signum is not None:
        _interrupt(signum)


def reset() -> None:
    """The usual handlers again, forgetting any signal that came while deferred."""
    _pending.clear()
    _owner.clear()  # (_fired is kept: fired() says the process is leaving on a signal)
    sys.unraisablehook = sys.__unraisablehook__
    _usual()


def _quiet_unraisable(unraisable: sys.UnraisableHookArgs) -> None:
    """Say nothing of an interrupt's exception that Python had to drop (see
    :func:`raise_if_interrupted`, which raises it again); the rest as usual."""
    if isinstance(unraisable.exc_value, Interrupted):
        return
    sys.__unraisablehook__(unraisable)


def fired() -> bool:
    """Whether SIGINT or SIGTERM became :class:`Interrupted` since :func:`as_interrupts`."""
    return bool(_fired)


def raise_if_interrupted() -> None:
    """Raise again the :class:`Interrupted` of a signal whose exception was swallowed.

    Python drops an exception raised where it cannot propagate: a signal handled while
    ``os.fork`` runs its hooks (a process pool starting its workers), in a finaliser.
    Code that waits (a study's executor) calls this now and then, so that such a signal
    still stops the command.
    """
    if _fired and _owner:
        raise Terminated if _fired[0] == signal.SIGTERM else Interrupted


def raise_pending() -> None:
    """Raise the exception of a signal that came while deferred, if any."""
    signum = _take_pending()
    if signum is not None:
        _raise(signum)


@contextmanager
def interruptible() -> Iterator[None]:
    """Inside the block SIGINT raises :class:`Interrupted` and SIGTERM :class:`Terminated`
    at once: a wait that has nothing to lose (a pipe read ahead before the command
    starts, see :mod:`ekfviz.io.piped`). The handlers of before after it; a signal that
    came before the block, while deferred, stays so (a replay honours it once it has
    something to keep)."""
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    _handle(_interrupt, _interrupt)  # a second signal while it is answered: deferred
    try:
        yield
    finally:
        _handle(*before)


@contextmanager
def held() -> Iterator[None]:
    """Inside the block a first SIGINT or SIGTERM is remembered, not acted on, and handled
    as before the block once the block is done (a recording being finished: cut short
    there it would be lost whole, finished it is kept); a second one is acted on at once
    (a flush to a viewer that does not answer may wait long). One remembered before the
    block (by an enclosing block, or deferred) is remembered still after it."""
    before = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))
    earlier = _pending[:]

    def act(signum: int, frame: FrameType | None) -> None:
        handler = before[0 if signum == signal.SIGINT else 1]
        if callable(handler):
            handler(signum, frame)

    def hold(signum: int, frame: FrameType | None) -> None:
        if _pending:  # the second: now
            _pending.clear()
            act(signum, frame)
        else:
            _pending.append(signum)

    _pending.clear()
    _handle(hold, hold)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before[0])
        signal.signal(signal.SIGTERM, before[1])
    signum = _take_pending()
    _pending[:] = earlier
    if signum is not None:
        act(signum, None)


@contextmanager
def as_exceptions() -> Iterator[None]:
    """Inside the block SIGINT raises KeyboardInterrupt and SIGTERM :class:`Terminated`;
    one that came earlier waits for :func:`raise_pending`. The usual handlers after it."""
    _handle(_raise, _raise)
    try:
        yield
    finally:
        _pending.clear()
        _usual()
