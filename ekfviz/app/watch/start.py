"""``ekfviz watch`` as asked on the command line (also ``check --watch`` and ``replay
--filter PATH.py --watch``): the filter and its file, the viewer, each log prepared
once, and the report of every run; then the watch itself (:func:`ekfviz.app.watch.watch`).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ekfviz import signals
from ekfviz.app.check import (
    CheckRequest,
    battery_logs,
    log_entry,
    per_log_path,
    prepared_input,
    report_document,
)
from ekfviz.app.errors import in_family
from ekfviz.app.outputs import RECORDINGS_DIR, filter_module
from ekfviz.app.reporting import Reporter
from ekfviz.app.watch import CheckInput, WatchedRun, WatchHooks, WatchRequest, watch
from ekfviz.core.errors import FilterError, InputError, UsageError
from ekfviz.filters.spec import FilterSpec, target_of
from ekfviz.io.files import check_outputs, write_json
from ekfviz.sandbox.host import WorkerFault

if TYPE_CHECKING:
    from ekfviz.viz import Sinks


@dataclass(frozen=True, slots=True)
class Viewer:
    """Where every run's recording goes besides ``--save``: a spawned viewer, a served
    one (on ``bind``), or one at ``connect``; none of them: a viewer where a display
    exists, else a file under recordings/."""

    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    bind: str | None = None


def watch_check(
    request: CheckRequest,
    viewer: Viewer,
    reporter: Reporter,
    on_run: Callable[[WatchedRun], None],
) -> None:
    """Check the filter on the log (or the battery) now and after every save, until
    Ctrl-C; each complete run handed to ``on_run`` (then its report written).

    :raises Interrupted: Ctrl-C or SIGTERM, everything the watch started ended
    :raises UsageError, InputError, OutputError, FilterError: one line each
    """
    signals.as_interrupts()  # (a replay defers them): the first Ctrl-C ends the watch
    spec, module = _filter(request)
    with tempfile.TemporaryDirectory(prefix="ekfviz-battery-") as folder:
        sinks, save = _sinks(request, viewer, reporter)
        inputs, files = _inputs(request, Path(folder), save, reporter)
        logs = ", ".join(str(path) for path in files) or "the battery"
        reporter.note(f"Watching {module} (and the modules beside it that it imports) on"
                      f" {logs}; Ctrl-C ends the watch.")  # fmt: skip

        def ran(run: WatchedRun) -> None:
            on_run(run)
            if request.report is not None:
                write_json(request.report, run_report(spec, request.data is None, run))

        try:
            with in_family():
                watch(
                    WatchRequest(spec, module, inputs, files, request.tolerance,
                                 request.every, sinks),
                    WatchHooks(ran, reporter.note, reporter.warn),
                )  # fmt: skip
        except WorkerFault as fault:
            raise FilterError(f"--filter {spec.text}: {fault}") from None


def run_report(spec: FilterSpec, battery: bool, run: WatchedRun) -> dict[str, Any]:
    """Check's report of a run, with its number, the files that changed and its first
    error (None where there is none)."""
    entries = []
    for outcome in run.outcomes:
        item, result, failure = outcome.input, outcome.result, outcome.failure
        if result is not None:
            entry = log_entry(item.name, result, outcome.coverage)
        else:
            entry = {"log": item.name, "match": False, "divergences": [], "causes": [],
                     "coverage": []}  # fmt: skip
        if failure is not None:
            entry["error"] = failure.to_json()
        entries.append(entry)
    params = run.outcomes[-1].input.params
    document = report_document(spec, params, entries, battery=battery)
    failures = [outcome.failure for outcome in run.outcomes if outcome.failure is not None]
    document["error"] = failures[0].to_json() if failures else None
    document["run"] = run.number
    document["files"] = [str(path) for path in run.changed]
    return document


def _filter(request: CheckRequest) -> tuple[FilterSpec, Path]:
    """The filter to watch, and its file.

    :raises UsageError: no filter, or one that is not a file
    :raises InputError: a file given that is not there
    """
    if not request.filter_text:
        raise UsageError("give the filter to watch: PATH.py (or PATH.py:ClassName)")
    module = filter_module(request.filter_text)
    if module is None:
        raise UsageError(
            f"{request.filter_text}: watch follows a filter's file: PATH.py or PATH.py:ClassName"
        )
    check_outputs(
        ("--report", request.report), ("--save", request.save),
        inputs=[request.data, request.truth, module],
    )  # fmt: skip
    for given in (module, request.data, request.truth):  # (one deleted later is waited for)
        if given is not None and not given.exists():
            raise InputError(given, 0, "no such file or folder")
    spec = FilterSpec.parse(request.filter_text, worker=request.worker)
    with in_family():
        target_of(spec.text)
    return spec, module


def _sinks(request: CheckRequest, viewer: Viewer, reporter: Reporter) -> tuple[Sinks, Path | None]:
    """The viewer each run is sent to, and where the newest recording is kept: as asked,
    else a spawned viewer where a display exists, else a file under recordings/."""
    from ekfviz import viz

    asked = viz.Sinks(save=request.save, spawn=viewer.spawn, serve=viewer.serve,
                      connect=viewer.connect, bind=viewer.bind or viz.LOOPBACK)  # fmt: skip
    name = f"{Path(request.filter_text.split(':')[0]).stem}-watch"
    if not asked.any:
        with in_family():
            asked, note = viz.resolve_default_sinks(asked, Path(name), RECORDINGS_DIR, name)
        if note:
            reporter.note(note.replace("saved the recording to", "keeping the newest recording in"))
    shown = viz.Sinks(spawn=asked.spawn, serve=asked.serve, connect=asked.connect, bind=asked.bind)
    return shown, asked.save


def _inputs(
    request: CheckRequest, folder: Path, save: Path | None, reporter: Reporter
) -> tuple[tuple[CheckInput, ...], tuple[Path, ...]]:
    """Each log checked (the log, or the battery written in ``folder``) prepared once,
    and the files followed for them (none for the battery, which does not change)."""
    data = request.data
    inputs, files = [], []
    for log, log_truth, start in battery_logs(request, folder):
        opened = prepared_input(replace(request, save=save), log, log_truth, start, reporter)
        for text in opened.notes:
            reporter.note(text)
        target = save if data is not None or save is None else per_log_path(save, log)
        name = str(log) if data is not None else log.stem
        inputs.append(CheckInput(log, name, opened.params, log_truth, opened.own_truth,
                                 request.source_args, target, battery=data is None))  # fmt: skip
        if data is not None:
            files += [*(opened.files or (log,)), *([log_truth] if log_truth else [])]
    return tuple(inputs), tuple(dict.fromkeys(files))
