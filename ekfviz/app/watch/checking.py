"""One check of a watched filter on one log, and its recording: what ``ekfviz watch``
asks of the rest of ekfviz, in one place.

:func:`check_once` runs the check (:func:`ekfviz.app.check`) in a worker already started
and says what stopped it, if anything, as a :class:`CheckFailure` naming a file and a
line; :func:`record_once` records the outcome as one recording of its own, the run before
it as a ghost in the map (:mod:`ekfviz.viz.ghost`), held until it is complete and only
then sent to the viewer and the ``--save`` file.
"""

from __future__ import annotations

import re
import shlex
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.app.watch.files import absolute
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.tables import Cell, Styled
from ekfviz.filters.spec import FilterSpec, FilterSpecError
from ekfviz.io.text import WarningCallback
from ekfviz.runner.replay import FilterLineError
from ekfviz.sandbox.remote import StartedWorker
from ekfviz.sources import OwnTruth, SourceArgs

if TYPE_CHECKING:
    from ekfviz.check.coverage import Item
    from ekfviz.check.lockstep import CheckResult
    from ekfviz.viz import Sinks
    from ekfviz.viz.ghost import Ghost

SHAPES_LINE = "course module, shapes detected"  # (how CheckResult.verdict_lines starts it)
# a frame of a Python traceback: its file and line
_FRAME = re.compile(r'^\s*File "([^"]+)", line (\d+)', re.MULTILINE)


@dataclass(frozen=True, slots=True)
class CheckInput:
    """A log the filter is checked on, prepared once when the watch starts.

    :param name: how the verdict names the log (its path, or a battery log's stem)
    :param params: the filter's parameters for it (the source's defaults applied)
    :param own_truth: the source's own truth (a dataset's), where ``truth_path`` is None
    :param save: where the newest complete recording of a check on it is kept
    :param battery: one of the bundled battery's logs (one a course module cannot read
        is said so, not run)
    """

    log: Path
    name: str
    params: FilterParams
    truth_path: Path | None = None
    own_truth: OwnTruth | None = None
    source_args: SourceArgs | None = None
    save: Path | None = None
    battery: bool = False


@dataclass(frozen=True, slots=True)
class CheckFailure:
    """Why a check went no further: where (a file of the filter's or the log, and its
    line, 0 when none) and what, in one line.

    :param kind: ``load`` (the module cannot be imported or lacks what it needs),
        ``input`` (the log), or a worker's kind (``raised``, ``timeout``, ``crashed``...)
    :param log_line: the line of the log whose event failed, if one did
    """

    file: Path
    line: int
    message: str
    kind: str
    log_line: int = 0
    user_traceback: str = ""

    @property
    def where(self) -> str:
        """``FILE:LINE`` (the file's name only), or the name alone without a line."""
        return f"{self.file.name}:{self.line}" if self.line else self.file.name

    def to_json(self) -> dict[str, object]:
        return {
            "file": str(self.file),
            "line": self.line,
            "message": self.message,
            "kind": self.kind,
            "log_line": self.log_line,
        }


@dataclass(frozen=True, slots=True)
class CheckOutcome:
    """A check's result and what its log exercised, or why it went no further (with
    what it checked before, where it stopped during the events)."""

    input: CheckInput
    result: CheckResult | None = None
    coverage: list[Item] = field(default_factory=list)
    failure: CheckFailure | None = None


def verdict_text(outcome: CheckOutcome, every: bool) -> tuple[list[str], str]:
    """The verdict on one log as plain lines (as ``check`` prints it), and the level its
    first line is logged at: ``INFO`` for a match, ``WARN`` for a divergence, ``ERROR``
    for a failure."""
    lines: list[str] = []
    result, failure = outcome.result, outcome.failure
    if result is not None:
        cells = result.verdict_lines(outcome.input.name, every)
        if every and result.divergences:
            cells += result.group_lines()
        for cell in cells:
            lines += _plain(cell).splitlines()
        # the verdict first: a course module's detected shapes after it
        lines.sort(key=lambda line: line.startswith(SHAPES_LINE))
    if failure is not None:
        lines.append(f"error: {failure.where}: {failure.message}")
        return lines, "ERROR"
    return lines, "INFO" if result is not None and result.match else "WARN"


def _plain(cell: Cell) -> str:
    """A line for the terminal as text, its styles dropped."""
    if isinstance(cell, str):
        return cell
    if isinstance(cell, Styled):
        return cell.text
    return "".join(span.text for span in cell)


def check_once(
    spec: FilterSpec,
    item: CheckInput,
    *,
    tolerance: float,
    every: bool,
    started: StartedWorker,
    followed: Sequence[Path],
    warn: WarningCallback | None = None,
) -> CheckOutcome:
    """Check ``spec`` on ``item``'s log in ``started`` (a worker started, its module not
    yet imported); what stops it becomes the outcome's failure, never an exception.

    :param followed: the filter's files: a failure is placed at the innermost line of
        theirs in the filter's traceback (else at the module, line 0)
    """
    from ekfviz.app.check import check_log

    module = Path(followed[0])
    try:
        result, exercised = check_log(
            item.log, item.truth_path, spec, item.params, tolerance=tolerance, save=None,
            every=every, source_args=item.source_args, warn=warn, own_truth=item.own_truth,
            skip_unreadable=item.battery, started=started,
        )  # fmt: skip
    except FilterSpecError as error:  # its module cannot be imported (a syntax error)
        text = str(error).removeprefix(f"--filter {spec.text}: ")
        # "importing PATH raised SyntaxError: ...": the place is said apart
        text = re.sub(r"^importing .+? raised ", "", text, count=1)
        file, line = placed(error.user_traceback, followed, module)
        kind = "load" if error.kind == "raised" else error.kind
        return CheckOutcome(item, failure=CheckFailure(file, line, text, kind, 0,
                                                       error.user_traceback))  # fmt: skip
    except FilterLineError as error:  # its construction failed
        trace = str(getattr(error.__cause__, "user_traceback", "") or "")
        file, line = placed(trace, followed, module)
        failure = CheckFailure(file, line, str(error), "raised", error.line, trace)
        return CheckOutcome(item, failure=failure)
    except InputError as error:  # the log (a bad edit of it)
        failure = CheckFailure(error.path, error.line, error.message, "input")
        return CheckOutcome(item, failure=failure)
    if result.error is None:
        return CheckOutcome(item, result, exercised)
    file, line = placed(result.error_traceback, followed, module)
    failure = CheckFailure(file, line, result.error, result.error_kind or "raised",
                           result.error_line, result.error_traceback)  # fmt: skip
    return CheckOutcome(item, result, exercised, failure)


def placed(user_traceback: str, followed: Sequence[Path], module: Path) -> tuple[Path, int]:
    """The innermost frame of a filter's traceback that is in one of its own files (a
    syntax error's place is the last frame Python lists), else the module and line 0."""
    mine = {absolute(path) for path in followed}
    # the sandbox hands a traceback over printable: its line breaks escaped
    text = user_traceback.replace("\\n", "\n")
    for name, line in reversed(_FRAME.findall(text)):
        if absolute(Path(name)) in mine:
            return absolute(Path(name)), int(line)
    return module, 0


@dataclass(frozen=True, slots=True)
class RecordingName:
    """Who a run's recording is: its name in the viewer (one that sorts in run order),
    its id (one of its own) and its start time."""

    name: str
    recording_id: str
    start_ns: int


def record_once(
    spec: FilterSpec,
    outcome: CheckOutcome,
    sinks: Sinks,
    who: RecordingName,
    ghost: Ghost | None,
    lines: Sequence[str],
    level: str,
    given_up: Callable[[], bool],
) -> Path | None:
    """Record one run's outcome on one log as a recording of its own, sent to ``sinks``
    only once complete: not at all where ``given_up()`` says so once it is logged.

    :param ghost: the run before, drawn grey in the checked filter's map
    :param lines: the verdict or the error, for the log view, its first at ``level``
    :return: where the ``--save`` file went, None where none was written
    :raises SinkError: a viewer or a file that cannot take it; InputError: the log or
        its truth cannot be read for the recording's description
    """
    from ekfviz import viz
    from ekfviz.app.check import Recorded, check_recording
    from ekfviz.app.inputs import source_events
    from ekfviz.app.study import study_truth
    from ekfviz.core.records import LogEvent, with_ids
    from ekfviz.sources import open_source
    from ekfviz.viz.check import record_check
    from ekfviz.viz.ghost import log_ghost, log_lines, map_note, record_failure

    item, result = outcome.input, outcome.result
    truth, truth_files = study_truth(item.truth_path, item.own_truth)
    files = open_source(item.log, item.source_args).files
    key = spec.key if spec.key != "reference" else "checked"
    command = shlex.join(["ekfviz", *sys.argv[1:]])
    shown = None
    if result is not None and len(result.records):
        events: list[LogEvent] = []
        if result.every and result.first_divergence is not None:  # the reference's own run
            source = open_source(item.log, item.source_args)
            events = list(with_ids(source_events(source, truth, item.truth_path)))
        recorded = Recorded(item.log, truth, truth_files, files, command, events)
        shown = check_recording(recorded, spec, item.params, result)
        info = replace(shown.info, name=who.name)
    else:
        info = viz.run_info(name=who.name, kind="check", command=command,
                            parameters={"filter": spec.text, **item.params.as_dict()},
                            input_path=item.log, truth=truth, input_files=files,
                            truth_files=truth_files)  # fmt: skip
    with viz.open_recording(info, sinks, recording_id=who.recording_id, deferred=True) as recording:
        rec = recording.rec
        rec.send_recording_start_time_nanos(who.start_ns)
        prefix = f"filters/{key}"
        if shown is None:
            record_failure(recording, prefix, spec.label, ghost, lines)
        else:
            if ghost is not None:
                log_ghost(rec, prefix, ghost)
            log_lines(rec, lines, level)
            record_check(recording, shown.result, shown.runs, truth, shown.summary,
                         map_note=map_note(ghost), runs_list=True)  # fmt: skip
        if given_up():  # a newer save came: this run is never shown nor saved
            recording.complete = False
    return recording.saved_to
