"""How a command runs in this process, whichever front end starts it: numpy's
floating-point warnings off, SIGINT and SIGTERM turned into exceptions, the version."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager

from ekfviz import __version__, signals


def begin(command: str | None) -> Callable[[], None]:
    """Set the process up for ``command``; return what ends that (for a caller that goes
    on: the tests, a notebook).

    numpy's RuntimeWarnings (overflow, the square root of a negative) would print a
    source line before the run's own one-line warning or error: the filter's health
    checks say what went wrong (a covariance not PSD, a state no longer finite) and
    where. A replay keeps SIGINT and SIGTERM for once its recording is open (see
    :mod:`ekfviz.signals`); every other command turns them into
    :class:`~ekfviz.signals.Interrupted` at once.
    """
    import numpy as np

    np.seterr(all="ignore")
    if command == "replay":
        return _nothing
    signals.as_interrupts()
    return signals.reset


def _nothing() -> None:
    """Nothing to end."""


def version_line() -> str:
    """The version, and whether the filter's compiled kernel for small maps was built."""
    from ekfviz.filters.ekf import HAVE_KERNEL

    kernel = "compiled" if HAVE_KERNEL else "numpy (the compiled kernel was not built)"
    return f"ekfviz {__version__}, filter kernel for small maps: {kernel}"


def printing_held() -> AbstractContextManager[None]:
    """A block in which a first SIGINT or SIGTERM waits for the block's end (see
    :func:`ekfviz.signals.held`): the results of a command already stopped by a signal,
    printed whole."""
    return signals.held()
