"""The recording of ``ekfviz check``: both filters side by side, opened on the divergence.

Besides each filter's run under ``filters/<key>/`` (see :mod:`ekfviz.viz.study`):

| entity | what |
|---|---|
| ``filters/<key>/world/divergence`` | on every map, red, where each divergence happened |
| ``filters/<checked>/world/divergence/expected`` | the reference's 3-sigma outlines there |
| ``filters/<checked>/world/divergence/got`` | the checked filter's, likewise |
| ``check/difference`` | log10 of the largest scaled difference at every event |
| ``check/tolerance`` | log10 of the tolerance, over the same events |
| ``check/divergent`` | the divergent events' own values (points) |
| ``check/divergences`` | a table of every divergent event: entry, expected, got, hint |
| ``log/divergence`` | an ERROR line at every divergent event |

The time panel shows the ``event`` timeline; the checked run ends at its first
divergence (unless every event is checked), where the cursor opens.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ekfviz.core.batch import EventBatch
from ekfviz.core.records import EventRecord
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.studies.runs import Run
from ekfviz.viz import style
from ekfviz.viz.blueprint import (
    NO_LEGEND,
    log_view,
    map_view,
    run_details,
    study_documents,
    with_legend,
    with_panels,
)
from ekfviz.viz.ellipses import ellipse_extent, ellipse_outlines
from ekfviz.viz.recording import Recording, finish_recorders
from ekfviz.viz.study import SUMMARY, log_legend, log_runs

if TYPE_CHECKING:
    from ekfviz.check.lockstep import CheckResult, Divergence

DIVERGENCE = "world/divergence"
EXPECTED = "world/divergence/expected"
GOT = "world/divergence/got"
DIFFERENCE = "check/difference"
TOLERANCE = "check/tolerance"
DIVERGENT = "check/divergent"
TABLE = "check/divergences"
# under the log: its view shows it. A divergence is an ERROR line, then its values and
# likely cause on lines without a level (on the same entity: the view keeps their order)
LOG = "log/divergence"

MARK_COLOR: style.Rgb = (220, 0, 0)
EXPECTED_COLOR: style.Rgb = (110, 110, 110)
GOT_COLOR: style.Rgb = (220, 0, 0)
# an exact match has a difference of 0, whose log10 is -inf: drawn at the floor
LOG10_FLOOR = -17.0
TABLE_ROWS = 50  # the divergences listed in the table (all are in the log)


def divergences_of(result: CheckResult) -> tuple[Divergence, ...]:
    """Every divergent event of a check: ``result.divergences`` where the check reports
    them all, else the first divergence alone (or none)."""
    found: Sequence[Divergence] = getattr(result, "divergences", ()) or ()
    if found:
        return tuple(found)
    return () if result.first_divergence is None else (result.first_divergence,)


def describe(divergence: Divergence, *, first: bool) -> list[str]:
    """The log lines of a divergent event: where and what (the ERROR line), then the
    values and the likely cause, each within :data:`~ekfviz.viz.style.LOG_WIDTH`
    characters (the log view cuts a line at its edge and cannot wrap one)."""
    worst = divergence.worst
    return [
        f"{'first divergence' if first else 'divergence'}: event {divergence.event}"
        f" ({divergence.kind.value}), line {divergence.line}: {worst.quantity.value}"
        f" {worst.entry}",
        *style.wrapped(
            f"expected {worst.expected:.6g}, got {worst.got:.6g}"
            f" (difference {worst.difference:.3g})"
        ),
        *style.wrapped(f"likely cause: {divergence.hint}"),
    ]


def record_check(
    recording: Recording,
    result: CheckResult,
    runs: list[Run],
    truth: GroundTruth | None,
    summary: str,
    map_note: str = "",
    runs_list: bool = False,
) -> None:
    """Log a check: both runs, the divergences, the difference per event, the layout.

    :param runs: the reference's own run first (the built-in filter alone, not the
        lockstep's, which starts it from the checked filter's state), then the checked
        filter's (either may be missing when it has no record)
    :param summary: the verdict as markdown
    :param map_note: said after the checked filter's name in its map's title (what else
        the map shows, e.g. an earlier run in grey)
    :param runs_list: show the list of recordings (each run of ``ekfviz watch`` is one),
        see :func:`ekfviz.viz.blueprint.with_panels`
    """
    rec = recording.rec
    root = "filters"
    recorders, box = log_runs(rec, runs, truth, root)
    prefixes = [f"{root}/{run.spec.key}" for run in runs]
    divergences = divergences_of(result)
    checked = prefixes[-1]
    rec.log(SUMMARY, rr.TextDocument(summary, media_type=rr.MediaType.MARKDOWN), static=True)
    _log_differences(rec, result, divergences)
    first = divergences[0] if divergences else None
    zoom: FloatArray | None = None
    if first is not None:
        got = _record_at(result.records, first.event)
        expected = _record_at(result.reference, first.event)
        marks = [
            found.pose[:2]
            for divergence in divergences
            if (found := _record_at(result.records, divergence.event)) is not None
        ]
        for k, prefix in enumerate(prefixes):
            # the reference's own map marks the first divergence only: the marks are the
            # checked filter's poses, which after it are off the reference's path
            shown = marks[:1] if k < len(prefixes) - 1 else marks
            if shown:
                rec.log(
                    f"{prefix}/{DIVERGENCE}",
                    rr.Points2D(
                        np.array(shown),
                        colors=[MARK_COLOR],
                        radii=rr.Radius.ui_points(7.0),
                        # short: the entry is in the log, the table and the zoomed title
                        labels=[f"event {first.event}"] + [""] * (len(shown) - 1),
                        show_labels=True,
                    ),
                    static=True,
                )
        if marks:  # the frame takes the mark's label in (it hangs below, centred)
            span = max(float(np.max(box[1] - box[0])), 1e-9)
            room = np.array([[0.15 * span, 0.08 * span]])
            at = np.array(marks[:1])
            low, high = np.minimum(box[0], (at - room)[0]), np.maximum(box[1], (at + room)[0])
            box = np.stack([low, high])
        zoom = _log_side_by_side(rec, checked, first, expected, got)
        for k, divergence in enumerate(divergences):
            rec.set_time(style.STEP, sequence=divergence.step)
            rec.set_time(style.EVENT, sequence=divergence.event)
            where, *rest = describe(divergence, first=k == 0)
            rec.log(LOG, rr.TextLog(where, level="ERROR"))
            for line in rest:  # the ERROR line's continuation: no level of their own
                rec.log(LOG, rr.TextLog(f"  {line}", level=""))
        rec.log(
            TABLE, rr.TextDocument(_table(divergences), media_type="text/markdown"), static=True
        )
    finish_recorders(recording, recorders)
    divergence_marks = (DIVERGENCE, EXPECTED) if first is not None else ()
    log_legend(rec, [recorder for recorder, _ in recorders], *divergence_marks)
    rec.send_blueprint(
        check_blueprint(
            [(run.spec.label, f"{root}/{run.spec.key}") for run in runs],
            has={
                prefix: recorder.entities_with_data
                for prefix, (recorder, _) in zip(prefixes, recorders, strict=True)
            },
            bounds_xy=box,
            zoom_xy=zoom,
            first=first,
            map_note=map_note,
            runs_list=runs_list,
        )
    )


def _record_at(events: EventBatch, event: int) -> EventRecord | None:
    """The view of event number ``event`` of ``events``, if it has one."""
    row = int(np.searchsorted(events.events, event))
    return events.event(row) if row < len(events) and events.events[row] == event else None


def _log_differences(
    rec: rr.RecordingStream, result: CheckResult, divergences: Sequence[Divergence]
) -> None:
    """The largest scaled difference at every event (log10), the tolerance, the divergent
    events as points: a plot with data wherever the check went."""
    differences = np.asarray(result.differences, dtype=np.float64)
    if not len(differences):
        return
    events = np.arange(len(differences))
    steps_of = dict(zip(result.records.events.tolist(), result.records.steps.tolist(), strict=True))
    steps = np.array([steps_of.get(int(e), 0) for e in events])
    with np.errstate(divide="ignore"):
        logged = np.maximum(np.log10(differences), LOG10_FLOOR)
    # one event (a divergence at the first) draws no line: points then
    one = len(differences) == 1
    rec.log(
        DIFFERENCE,
        rr.SeriesPoints(
            colors=style.STATISTIC_COLOR, names="largest difference (log10)", marker_sizes=4.0
        )
        if one
        else rr.SeriesLines(colors=style.STATISTIC_COLOR, names="largest difference (log10)"),
        static=True,
    )
    rec.log(
        TOLERANCE,
        rr.SeriesPoints(colors=style.BOUND_COLOR, names="tolerance (log10)", marker_sizes=4.0)
        if one
        else rr.SeriesLines(colors=style.BOUND_COLOR, names="tolerance (log10)", widths=1.0),
        static=True,
    )
    indexes = [
        rr.TimeColumn(style.EVENT, sequence=events),
        rr.TimeColumn(style.STEP, sequence=steps),
    ]
    rec.send_columns(DIFFERENCE, indexes=indexes, columns=rr.Scalars.columns(scalars=logged))
    tolerance = math.log10(result.tolerance) if result.tolerance > 0 else LOG10_FLOOR
    rec.send_columns(
        TOLERANCE,
        indexes=indexes,
        columns=rr.Scalars.columns(scalars=np.full(len(events), tolerance)),
    )
    if divergences:
        rec.log(
            DIVERGENT,
            rr.SeriesPoints(
                colors=MARK_COLOR, names="divergent event", markers="cross", marker_sizes=6.0
            ),
            static=True,
        )
        rec.send_columns(
            DIVERGENT,
            indexes=[
                rr.TimeColumn(style.EVENT, sequence=[d.event for d in divergences]),
                rr.TimeColumn(style.STEP, sequence=[d.step for d in divergences]),
            ],
            columns=rr.Scalars.columns(
                scalars=[
                    max(math.log10(max(d.worst.difference, 1e-300)), LOG10_FLOOR)
                    for d in divergences
                ]
            ),
        )


def _log_side_by_side(
    rec: rr.RecordingStream,
    prefix: str,
    first: Divergence,
    expected: EventRecord | None,
    got: EventRecord | None,
) -> FloatArray | None:
    """The reference's and the checked filter's pose and landmark outlines at the first
    divergence, in the checked filter's map (at that event and after).

    :return: the (2, 2) box around both, to zoom a view on, or None
    """
    rec.set_time(style.STEP, sequence=first.step)
    rec.set_time(style.EVENT, sequence=first.event)
    corners = []
    for record, path, color, label in (
        (expected, EXPECTED, EXPECTED_COLOR, "expected (reference)"),
        (got, GOT, GOT_COLOR, "got"),
    ):
        if record is None:
            continue
        means = np.vstack([record.pose[None, :2], record.landmarks_xy])
        covs = np.concatenate([record.pose_cov[None, :2, :2], record.landmark_covs])
        rec.log(
            f"{prefix}/{path}",
            rr.LineStrips2D(
                list(ellipse_outlines(means, covs)),
                colors=[color],
                radii=rr.Radius.ui_points(1.5),
                labels=[label] + [""] * (len(means) - 1),
                show_labels=False,
            ),
        )
        corners.append(ellipse_extent(means[:1], covs[:1]))
        if first.worst.landmark_id is not None:
            where = np.flatnonzero(record.landmark_ids == first.worst.landmark_id)
            if len(where):
                corners.append(ellipse_extent(means[1 + where], covs[1 + where]))
    if not corners:
        return None
    points = np.concatenate(corners)
    box = np.stack([points.min(axis=0), points.max(axis=0)])
    margin = 0.3 * max(float(np.max(box[1] - box[0])), 0.5)
    framed: FloatArray = box + np.array([[-margin], [margin]])
    return framed


def _table(divergences: Sequence[Divergence]) -> str:
    """The divergent events as a markdown table (the first ``TABLE_ROWS``)."""
    lines = [
        f"# {len(divergences)} divergent event{'s' * (len(divergences) != 1)}",
        "",
        "| event | kind | line | entry | expected | got | difference |",
        "|---:|---|---:|---|---:|---:|---:|",
    ]
    shown = divergences[:TABLE_ROWS]
    for divergence in shown:
        worst = divergence.worst
        lines.append(
            f"| {divergence.event} | {divergence.kind.value} | {divergence.line} |"
            f" {worst.quantity.value} {worst.entry} | {worst.expected:.6g} | {worst.got:.6g} |"
            f" {worst.difference:.3g} |"
        )
    if len(divergences) > TABLE_ROWS:
        lines.append(f"\n... and {len(divergences) - TABLE_ROWS} more (see the log)")
    # the likely causes below the table, where a long one wraps (a table's last column
    # would run off a narrow view): one item per cause, with the events it explains
    events_of: dict[str, list[int]] = {}
    for divergence in shown:
        events_of.setdefault(divergence.hint, []).append(divergence.event)
    lines += ["", "## Likely cause" + "s" * (len(events_of) != 1), ""]
    for hint, events in events_of.items():
        listed = ", ".join(str(event) for event in events[:8]) + ", ..." * (len(events) > 8)
        lines.append(f"- event{'s' * (len(events) != 1)} {listed}: {hint}")
    return "\n".join(lines) + "\n"


def check_blueprint(
    variants: list[tuple[str, str]],
    *,
    has: dict[str, Any],
    bounds_xy: FloatArray | None,
    zoom_xy: FloatArray | None,
    first: Divergence | None,
    map_note: str = "",
    runs_list: bool = False,
) -> rrb.Blueprint:
    """The check's layout: both maps (the divergence marked), the checked map zoomed on
    the first divergence, the difference per event, the log with its ERROR lines, the
    divergences' table, and a tab per filter with its own plots.

    :param variants: (label, prefix) of the reference's run then the checked filter's
    :param map_note: see :func:`record_check`
    :param runs_list: show the list of recordings, see :func:`with_panels`
    """
    checked = variants[-1][1]
    # the outlines at the divergence in the zoomed view only: they would cover the map
    maps: list[rrb.View] = [
        map_view(
            bounds_xy,
            prefix=prefix,
            name=f"{label}{map_note}" if prefix == checked else label,
            exclude=(EXPECTED, GOT),
        )
        for label, prefix in variants
    ]
    if first is not None:
        prefix = variants[-1][1]
        maps.append(
            map_view(
                zoom_xy,
                prefix=prefix,
                name=f"At event {first.event}",
                exclude=(style.PREVIOUS,),  # grey too: only this event's outlines here
            )
        )
    difference = rrb.TimeSeriesView(
        name="Largest difference per event (log10) and the tolerance"
        + ("" if first is None else f"; first divergence at event {first.event}"),
        contents=[f"/{DIFFERENCE}", f"/{TOLERANCE}", f"/{DIVERGENT}"],
        # top left: the divergence is at the right end, the exact matches at the bottom
        plot_legend=rrb.PlotLegend(corner=rrb.components.Corner2D.LeftTop, visible=True)
        if first is not None
        else NO_LEGEND,
    )
    # the log of the checked filter (the reference's says the same, in its own tab)
    documents = study_documents(
        [variants[-1][1]],
        SUMMARY,
        first=[rrb.TextDocumentView(name="Divergences", origin=TABLE)] if first else [],
    )
    logs: list[rrb.View] = [view for view in documents if isinstance(view, rrb.TextLogView)]
    others = [view for view in documents if not isinstance(view, rrb.TextLogView)]
    details = [
        run_details(label, prefix, has[prefix], log=k < len(variants) - 1)
        for k, (label, prefix) in enumerate(variants)
    ]
    return with_panels(
        rrb.Horizontal(
            rrb.Vertical(
                # the legend of a check is longer and its maps narrower: more lines
                with_legend(rrb.Horizontal(*maps), True, share=4.0),
                difference,
                row_shares=[4, 1],
            ),
            rrb.Vertical(
                *(logs or [log_view()]),
                rrb.Tabs(*others, *details),
                row_shares=[1, 2],
            ),
            column_shares=[3, 2],
        ),
        # the checked run ends at its first divergence: following puts the cursor there
        rrb.TimePanel(timeline=style.EVENT, play_state="following", state="collapsed"),
        runs_list=runs_list,
    )
