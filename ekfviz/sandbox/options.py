"""How a user's filter runs (:class:`WorkerOptions`), apart from the worker itself
(:mod:`.host`), which a replay of ekfviz's own filter never imports. Standard library only."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ekfviz.sandbox.submission import Submission

DEFAULT_TIMEOUT_S = 60.0


@dataclass(frozen=True, slots=True)
class WorkerOptions:
    """How a user's filter runs.

    :param python: the interpreter (None: ekfviz's own)
    :param timeout_s: the longest one call may take (None: no bound)
    :param memory_mb: the worker's address-space limit (None: none)
    :param clean_env: without the sandbox, start it without the caller's environment
        variables (in the sandbox it has none of them)
    :param cwd: without the sandbox, its working directory (None: the caller's; in the
        sandbox, its private /tmp)
    :param echo: what it prints goes to ekfviz's stderr as it comes, prefixed by the
        filter's name (else it is only kept, see :attr:`.host.WorkerProcess.output`)
    :param deadline: a time (``time.time()``) by which every call must be done, the
        bound of a whole submission in ``grade`` (None: none)
    :param sandbox: start it in the sandbox (:mod:`.bwrap`); off: as the caller, with the
        caller's files and network (``--no-sandbox``)
    :param submission: what of the caller's files it sees (None: the filter file's
        folder, its Python files)
    """

    python: str | None = None
    timeout_s: float | None = DEFAULT_TIMEOUT_S
    memory_mb: int | None = None
    clean_env: bool = False
    cwd: str | None = None
    echo: bool = True
    deadline: float | None = None
    sandbox: bool = True
    submission: Submission | None = None
