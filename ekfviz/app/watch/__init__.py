"""``ekfviz watch``: check a filter again on every save, each run a new recording in the
viewer that stays open.

The loop: check the filter (on the log, or on each log of the battery), record each
outcome as a recording of its own (the run before drawn grey behind it), keep the newest
complete recording and hand the run to the command line (which prints it and writes the
report); then wait for the next save of the filter's files or the log (:mod:`.files`).
A save that comes while a run goes on cancels it: its workers are ended, and its
recordings, held until complete, are never sent nor saved. A file deleted is waited for.
The workers of the next run are started while the watch waits (:mod:`.workers`).

Ctrl-C (:class:`ekfviz.signals.Interrupted`) ends the watch: the watcher's thread, the
workers and a served viewer are ended; a spawned viewer stays open.
"""

from __future__ import annotations

import contextlib
import os
import queue
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.app.watch.checking import (
    CheckFailure,
    CheckInput,
    CheckOutcome,
    RecordingName,
    check_once,
    record_once,
    verdict_text,
)
from ekfviz.app.watch.files import Watcher, absolute, filter_files
from ekfviz.app.watch.workers import Cancel, WarmWorkers
from ekfviz.core.errors import InputError
from ekfviz.filters.spec import FilterSpec
from ekfviz.io.text import WarningCallback

if TYPE_CHECKING:
    from ekfviz.viz import Sinks
    from ekfviz.viz.ghost import Ghost

__all__ = ["CheckFailure", "CheckInput", "CheckOutcome", "WatchRequest", "WatchedRun", "watch"]

WAIT_SLICE_S = 0.25  # how often a wait for a save looks whether the watcher failed


@dataclass(frozen=True, slots=True)
class WatchRequest:
    """A watch as asked for.

    :param module: the filter's file (``PATH.py`` of ``spec``)
    :param inputs: the logs to check on, each prepared once (one, or the battery's)
    :param input_files: the files the logs are read from (and their truth): followed too
    :param sinks: where each run's recording goes besides each input's ``save``: a
        spawned viewer, ``connect`` (a served viewer's address too), or none
    """

    spec: FilterSpec
    module: Path
    inputs: tuple[CheckInput, ...]
    input_files: tuple[Path, ...]
    tolerance: float
    every: bool
    sinks: Sinks


@dataclass(frozen=True, slots=True)
class WatchedRun:
    """One run of the watch, complete: what it checked and where its recordings went.

    :param number: the run's number, from 1 (a cancelled run takes none)
    :param started: when it started (``time.time()``)
    :param changed: the files whose save started it (none for the first run)
    :param outcomes: one per input, in order
    :param saved: the recordings written (the ``--save`` files replaced)
    :param problems: what went wrong in sending the recordings (a viewer gone), one line each
    """

    number: int
    started: float
    changed: tuple[Path, ...]
    outcomes: tuple[CheckOutcome, ...]
    saved: tuple[Path, ...] = ()
    problems: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class WatchHooks:
    """What the command line does with the watch's news.

    :param on_run: a run is complete (its recordings sent and saved): print it, write
        its report
    :param on_note: something to say between runs (a file waited for)
    :param warn: the readers' warnings
    """

    on_run: Callable[[WatchedRun], None]
    on_note: Callable[[str], None]
    warn: WarningCallback | None = None


class _Changes:
    """The saves the watcher's thread reports, queued for the main thread; each one
    cancels the run in progress."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue[set[Path]] = queue.SimpleQueue()
        self.cancel = Cancel()

    def add(self, paths: set[Path]) -> None:
        """(The watcher's thread.) Queue ``paths`` and give the current run up."""
        self._queue.put(paths)
        self.cancel.cancel()

    def pending(self) -> set[Path]:
        """Every change queued so far, without waiting."""
        paths: set[Path] = set()
        with contextlib.suppress(queue.Empty):
            while True:
                paths |= self._queue.get_nowait()
        return paths

    def wait(self, watcher: Watcher) -> set[Path]:
        """Block until a change comes (Ctrl-C ends the wait), then take every one queued.

        :raises InputError: the watcher stopped (a folder followed went away)
        """
        while True:
            try:
                paths = self._queue.get(timeout=WAIT_SLICE_S)
            except queue.Empty:
                paths = None
            if watcher.error is not None:
                folder = ", ".join(sorted(str(f) for f in watcher.folders))
                raise InputError(folder, 0, f"cannot be watched any more ({watcher.error})")
            if paths is not None:
                return paths | self.pending()

    @contextlib.contextmanager
    def running(self) -> Iterator[Cancel]:
        """A run's cancellation, set by any change from now until the run ends."""
        self.cancel = Cancel()
        if not self._queue.empty():  # a save queued already: this run would check the
            self.cancel.cancel()  # files it replaced
        try:
            yield self.cancel
        finally:
            self.cancel.disarm()


@dataclass
class _Followed:
    """The files followed: the filter's (found anew after every run) and the inputs'."""

    module: Path
    inputs: tuple[Path, ...]
    filter_files: list[Path] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.module = absolute(self.module)
        self.inputs = tuple(absolute(path) for path in self.inputs)
        self.filter_files = filter_files(self.module)

    @property
    def files(self) -> frozenset[Path]:
        return frozenset([*self.filter_files, *self.inputs])

    def refresh(self) -> bool:
        """Find the filter's files again (an import added or dropped); whether they changed."""
        found = filter_files(self.module)
        changed, self.filter_files = found != self.filter_files, found
        return changed

    def missing(self) -> list[Path]:
        """The module and inputs that are not there (deleted, not yet saved again)."""
        return [path for path in (self.module, *self.inputs) if not path.exists()]

    def stamps(self) -> dict[Path, tuple[int, int, int] | None]:
        """Each file's modification time, size and inode (None: not there)."""
        stamps: dict[Path, tuple[int, int, int] | None] = {}
        for path in sorted(self.files):
            try:
                found = os.stat(path)
                stamps[path] = (found.st_mtime_ns, found.st_size, found.st_ino)
            except OSError:
                stamps[path] = None
        return stamps


def watch(request: WatchRequest, hooks: WatchHooks) -> None:
    """Check the filter now and again after every save, until Ctrl-C.

    :raises Interrupted: Ctrl-C or SIGTERM, once everything the watch started is ended
    :raises WorkerFault: no worker can start (``--python``)
    :raises InputError: a folder followed cannot be watched any more
    :raises SinkError: the viewer asked for cannot be had
    """
    with _viewer(request.sinks, hooks) as sinks:
        _watch(replace(request, sinks=sinks), hooks)


@contextlib.contextmanager
def _viewer(sinks: Sinks, hooks: WatchHooks) -> Iterator[Sinks]:
    """The viewer every run is sent to: a served one started once here (its address
    said), a spawned or a connected one looked for now.

    :raises SinkError: no display for a spawned viewer, no viewer at ``connect``
    """
    from ekfviz.viz.viewer import (
        ServedViewer,
        SinkError,
        check_bind,
        display_problem,
        viewer_answers,
    )

    problem = display_problem() if sinks.spawn else None
    if problem is not None:
        raise SinkError(f"--spawn needs a display: {problem}; use --save or --serve")
    if sinks.connect is not None and viewer_answers(sinks.connect) is False:
        raise SinkError(f"no Rerun viewer at {sinks.connect} (start one with: rerun)")
    if not sinks.serve:
        yield sinks
        return
    served = ServedViewer(check_bind(sinks.bind))
    try:
        hooks.on_note(f"Serving the web viewer at {served.url} (Ctrl-C ends it with the watch)")
        yield replace(sinks, serve=False, connect=served.grpc_url)
    finally:
        served.close()


def _watch(request: WatchRequest, hooks: WatchHooks) -> None:
    """:func:`watch`, its viewer open."""
    followed = _Followed(request.module, request.input_files)
    changes = _Changes()
    warm = WarmWorkers(request.spec)
    watcher = Watcher(followed.files, changes.add)
    ghosts: dict[str, Ghost] = {}
    number, changed, said = 0, set[Path](), ""
    try:
        warm.fill(len(request.inputs))
        while True:
            missing = followed.missing()
            if missing:
                note = ", ".join(str(path) for path in missing)
                if note != said:  # once, not at every event of a file being made
                    hooks.on_note(f"waiting for {note} (not there: deleted or being saved)")
                said = note
                changed |= changes.wait(watcher)
                continue
            said = ""
            before = followed.stamps()
            run = _run(request, hooks, changes, warm, ghosts, number + 1, changed)
            if run is not None:  # (a cancelled run's changes are the next one's too)
                number, changed = run.number, set()
                hooks.on_run(run)
            if followed.refresh():
                watcher.close()
                watcher = Watcher(followed.files, changes.add)
            warm.fill(len(request.inputs))  # while waiting: the next run's workers
            changed |= changes.pending()
            if not changed:  # a save during the run that its events may have missed
                now = followed.stamps()
                changed = {path for path, stamp in before.items() if now.get(path) != stamp}
            if not changed:
                changed = changes.wait(watcher)
    finally:
        watcher.close()
        warm.close()


def _run(
    request: WatchRequest,
    hooks: WatchHooks,
    changes: _Changes,
    warm: WarmWorkers,
    ghosts: dict[str, Ghost],
    number: int,
    changed: set[Path],
) -> WatchedRun | None:
    """One run on every input: checked, then recorded; None where a save cancelled it."""
    from ekfviz.viz.ghost import Ghost

    started = time.time()
    outcomes: list[CheckOutcome] = []
    followed = filter_files(request.module)
    with changes.running() as cancel:
        warm.refresh()  # what the workers import: the files as this run found them
        for item in request.inputs:
            worker = warm.take()
            cancel.guard(worker.process)
            try:
                outcome = check_once(request.spec, item, tolerance=request.tolerance,
                                     every=request.every, started=worker, followed=followed,
                                     warn=hooks.warn)  # fmt: skip
            finally:
                worker.process.close()  # (the check closed it, unless it never got to it)
            if cancel.is_set:
                return None
            outcomes.append(outcome)
        saved, problems = _record(request, hooks, outcomes, ghosts, number, started, cancel)
        if cancel.is_set:
            return None
    for outcome in outcomes:  # what the next run draws behind its own
        if outcome.result is not None and outcome.failure is None:
            ghost = Ghost.of(outcome.result.records, f"run {number}")
            if ghost is not None:
                ghosts[outcome.input.name] = ghost
    return WatchedRun(number, started, tuple(sorted(changed)), tuple(outcomes), saved, problems)


def _record(
    request: WatchRequest,
    hooks: WatchHooks,
    outcomes: Sequence[CheckOutcome],
    ghosts: dict[str, Ghost],
    number: int,
    started: float,
    cancel: Cancel,
) -> tuple[tuple[Path, ...], tuple[str, ...]]:
    """Each outcome's recording, sent to the viewer; saved where it is a complete check
    (a failed run leaves the last good recording where it is)."""
    from ekfviz.viz.viewer import SinkError

    saved: list[Path] = []
    problems: list[str] = []
    clock = time.strftime("%H:%M:%S", time.localtime(started))
    for outcome in outcomes:
        item = outcome.input
        if outcome.result is not None and outcome.result.skipped:
            continue  # a battery log the filter cannot read: nothing ran, nothing to show
        good = outcome.failure is None and outcome.result is not None
        sinks = replace(request.sinks, save=item.save if good else None)
        if not sinks.any:
            continue
        battery = f" {item.name}" if len(request.inputs) > 1 else ""
        who = RecordingName(
            f"{request.spec.label} run {number:03d}{battery} ({clock})",
            str(uuid.uuid4()),
            int(started * 1e9),
        )
        lines, level = verdict_text(outcome, request.every)
        try:
            path = record_once(request.spec, outcome, sinks, who, ghosts.get(item.name),
                               lines, level, lambda: cancel.is_set)  # fmt: skip
        except (SinkError, InputError) as error:
            problems.append(str(error))
            continue
        if path is not None:
            saved.append(path)
    return tuple(saved), tuple(problems)
