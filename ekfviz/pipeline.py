"""Orchestration: a log from its source through filters to its consumers.

The commands of :mod:`ekfviz.cli` parse options and print; what happens between reading
a log and writing a recording lives here, so that a newcomer reads the steps of a study
in one place: read and check the input, run every pipeline (in parallel), summarise,
record. Rerun is imported only when a recording is made.
"""

from __future__ import annotations

import json
import shlex
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.core.consistency import Consistency
from ekfviz.core.evaluation import evaluate
from ekfviz.core.filter import FilterParams
from ekfviz.core.records import AnyEvent, with_ids
from ekfviz.core.truth import GroundTruth
from ekfviz.filters import FilterSpec
from ekfviz.io.extended import is_extended, read_log
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.io.truth import checked_against, read_truth
from ekfviz.studies.runs import Run, RunSpec, Summary, run_specs, summarise

if TYPE_CHECKING:
    from ekfviz.core.check import CheckResult


def log_events(
    data: Path,
    truth: GroundTruth | None,
    truth_path: Path | None,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[AnyEvent]:
    """The log's events, checked against the truth's landmarks when there is one."""
    events = read_log(data, progress, warn)
    if truth is not None and truth_path is not None:
        events = checked_against(events, truth, truth_path, every_id=not is_extended(data))
    return events


@dataclass(frozen=True, slots=True)
class StudyResult:
    """A study run and recorded: its runs in order, their summaries, the input's digest."""

    runs: list[Run]
    summaries: list[Summary]
    truth: GroundTruth | None
    input_sha256: str


def study(
    data: Path,
    truth_path: Path | None,
    specs: list[RunSpec],
    *,
    target: Path,
    workers: int | None,
    root: str,
    parameters: dict[str, object],
    markdown: Callable[[list[Summary]], str],
    done: Callable[[], None] | None = None,
) -> StudyResult:
    """Replay ``data`` with every spec, summarise against the first, save one recording.

    The log is read whole once before any work, so that bad input stops the study early;
    every filter is loaded once here for the same reason.

    :param root: ``variants`` (a sweep) or ``filters`` (a comparison)
    :param markdown: the summary table as markdown, for the recording
    :raises InputError, FilterLineError, FilterSpecError, SinkError: one line each
    """
    from ekfviz import viz
    from ekfviz.viz.study import record_study

    truth = read_truth(truth_path) if truth_path is not None else None
    for _ in log_events(data, truth, truth_path):
        pass
    for spec in specs:
        spec.filter.load()
    runs = run_specs(data, specs, truth, workers, done=None if done is None else lambda _: done())
    summaries = [summarise(run, runs[0]) for run in runs]
    info = viz.run_info(
        name=f"{data.stem}-{'sweep' if root == 'variants' else 'compare'}",
        command=shlex.join(["ekfviz", *sys.argv[1:]]),
        parameters=parameters,
        input_path=data,
        truth=truth,
        truth_path=truth_path,
    )
    with viz.open_recording(info, viz.Sinks(save=target)) as recording:
        record_study(recording, runs, truth, markdown(summaries), root=root)
    return StudyResult(runs, summaries, truth, info.input_sha256)


def check(
    data: Path,
    truth_path: Path | None,
    filter_spec: str,
    params: FilterParams,
    *,
    tolerance: float,
    save: Path | None,
) -> CheckResult:
    """Check a protocol filter against the reference in lockstep over ``data``; with
    ``save``, one recording of both side by side, the first divergence marked.

    :raises InputError, FilterLineError, FilterSpecError, SinkError: one line each
    """
    from ekfviz.core.check import lockstep

    spec = FilterSpec(filter_spec)
    make_filter = spec.load()
    truth = read_truth(truth_path) if truth_path is not None else None
    result = lockstep(
        with_ids(log_events(data, truth, truth_path)), params, make_filter, name=spec.text,
        tolerance=tolerance,
    )  # fmt: skip
    if save is not None:
        _record_check(data, truth, truth_path, spec, params, result, save)
    return result


def _record_check(
    data: Path,
    truth: GroundTruth | None,
    truth_path: Path | None,
    spec: FilterSpec,
    params: FilterParams,
    result: CheckResult,
    save: Path,
) -> None:
    from ekfviz import viz
    from ekfviz.viz.study import mark_event, record_study

    runs = []
    for label, key, records in (
        ("reference (ekf)", "reference", result.reference),
        (spec.label, spec.key if spec.key != "reference" else "checked", result.records),
    ):
        if not records:
            continue
        consistency = Consistency(truth)
        for record in records:
            consistency.add(record)
        evaluation = evaluate(records[-1], truth, consistency)
        runs.append(Run(RunSpec(label, key, params), records, evaluation, 0.0))
    info = viz.run_info(
        name=f"{data.stem}-check",
        command=shlex.join(["ekfviz", *sys.argv[1:]]),
        parameters={"filter": spec.text, "tolerance": result.tolerance, **params.as_dict()},
        input_path=data,
        truth=truth,
        truth_path=truth_path,
    )
    verdict = json.dumps(result.to_json(), indent=2)
    summary = f"# Check of {spec.text} against the reference\n\n```json\n{verdict}\n```\n"
    with viz.open_recording(info, viz.Sinks(save=save)) as recording:
        record_study(recording, runs, truth, summary, root="filters")
        first = result.first_divergence
        if first is not None:
            where = next((r.pose[:2] for r in result.records if r.event == first.event), None)
            mark_event(
                recording, step=first.step, event=first.event, where_xy=where,
                text=f"first divergence: event {first.event} ({first.kind.value}), line"
                f" {first.line}: {first.quantity.value} {first.entry} expected"
                f" {first.expected:.6g}, got {first.got:.6g}; likely cause: {first.hint}",
            )  # fmt: skip
