"""The workers of ``ekfviz watch``: one kept started for the next run, and the run's
cancellation, which ends its workers at once when a newer save comes."""

from __future__ import annotations

import contextlib
import os
import signal
import threading

from ekfviz import signals
from ekfviz.filters.spec import FilterSpec, target_of, worker_label
from ekfviz.sandbox import bwrap
from ekfviz.sandbox.host import WorkerProcess
from ekfviz.sandbox.options import WorkerOptions
from ekfviz.sandbox.remote import PrivateCopy, StartedWorker


class Cancel:
    """One run's cancellation, safe to set from another thread (the watcher's).

    Setting it kills the process groups of the workers it guards: the run's next request
    to its filter then finds the worker gone and the run stops there (its outcome is
    dropped). A worker is guarded from before its module is imported until the run
    ends (:meth:`disarm`), never after: its process id may then be another's.
    """

    def __init__(self) -> None:
        self._set = threading.Event()
        self._lock = threading.Lock()
        self._groups: list[int] = []

    @property
    def is_set(self) -> bool:
        return self._set.is_set()

    def guard(self, process: WorkerProcess) -> None:
        """Kill ``process`` when the run is cancelled (at once if it is already)."""
        with self._lock:
            self._groups.append(process.process.pid)  # its own session: group = pid
            if self._set.is_set():
                _kill(process.process.pid)

    def cancel(self) -> None:
        """Give the run up: its workers are ended now."""
        with self._lock:
            self._set.set()
            for group in self._groups:
                _kill(group)

    def disarm(self) -> None:
        """The run is over: its workers are closed by it, never killed from here."""
        with self._lock:
            self._groups.clear()


def _kill(group: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(group, signal.SIGKILL)


class _Worker(WorkerProcess):
    """A worker whose close does not hold up the watch: it is asked to end, and waited
    for (its last output echoed), in a thread of its own, while the run records."""

    closing: threading.Thread | None = None

    def close(self) -> None:
        if self.closing is None:
            self.closing = threading.Thread(
                target=super().close, name="ekfviz-worker-close", daemon=True
            )
            self.closing.start()

    def end(self) -> None:
        """End it now (a close under way is not waited for)."""
        if self.process.poll() is None:
            self.kill()
        if self.closing is not None:
            self.closing.join()


class WarmWorkers:
    """Workers started ahead of the runs that take them: the interpreter and numpy of
    each loaded, waiting for the filter's module, so that a run after a save does not
    wait for a worker to start (a few tenths of a second, more on a loaded machine).

    They are started in the calling (main) thread: a worker ends with the thread that
    started it (Linux's parent-death signal follows the thread), and a thread of its own
    would have to live as long as the watch. In the sandbox they are shown one private
    copy of the filter's folder, made again (:meth:`refresh`) as each run starts: a
    worker started before a save imports what the save wrote.
    """

    def __init__(self, spec: FilterSpec) -> None:
        target = target_of(spec.text)
        self._options = spec.worker if spec.worker is not None else WorkerOptions()
        self._label = worker_label(target)
        self._copy = PrivateCopy(target, self._options)
        self._ready: list[_Worker] = []
        self._made: list[_Worker] = []  # every worker not known to have ended

    @property
    def mounts(self) -> tuple[bwrap.Mount, ...]:
        return self._copy.mounts

    def refresh(self) -> None:
        """Copy the filter's folder again for the run that starts now.

        :raises WorkerFault: the folder is not copied (over a bound, a link out of it)
        """
        self._copy.refresh()

    def fill(self, count: int) -> None:
        """Have ``count`` workers ready (a worker that ended meanwhile is replaced).

        :raises WorkerFault: a worker cannot start (``--python`` cannot run it)
        """
        self._ready = [worker for worker in self._ready if worker.process.poll() is None]
        while len(self._ready) < count:
            self._ready.append(self._start())

    def take(self) -> StartedWorker:
        """A ready worker, or one started now where none is, with what it is shown.

        :raises WorkerFault: a worker cannot start
        """
        while self._ready:
            worker = self._ready.pop(0)
            if worker.process.poll() is None:
                return StartedWorker(worker, self.mounts)
            worker.close()
        return StartedWorker(self._start(), self.mounts)

    def _start(self) -> _Worker:
        self._made = [w for w in self._made if w.closing is None or w.closing.is_alive()]
        # Ctrl-C while a worker starts is acted on once it is here to be ended: a worker
        # left half-started (its parent's death not yet asked to end it) would outlive us
        with signals.held():
            worker = _Worker(self._options, self._label, self.mounts)
            self._made.append(worker)
        return worker

    def close(self) -> None:
        """End every worker started: those waiting, and those still being closed."""
        for worker in self._made:
            worker.end()
        self._ready.clear()
        self._made.clear()
        self._copy.close()
