"""A study in one recording: every run under ``variants/<key>/`` (a sweep) or
``filters/<key>/`` (a comparison).

Rerun does not synchronise timelines across recordings, so the runs share one
recording and its ``step`` and ``event`` timelines: scrubbing moves them all together.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import rerun as rr

from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.evaluation.consistency import events_nis
from ekfviz.evaluation.errors import Evaluation, landmark_errors
from ekfviz.studies.runs import Run
from ekfviz.viz import style
from ekfviz.viz.axes import FittedAxis, study_axis
from ekfviz.viz.blueprint import STUDY_COLUMN_SHARES, sweep_blueprint
from ekfviz.viz.ellipses import ellipse_extent
from ekfviz.viz.legend import legend_markdown, markdown_document
from ekfviz.viz.recorder import Recorder
from ekfviz.viz.recording import Recording, finish_recorders
from ekfviz.viz.tables import fit_tables, view_characters

SUMMARY = "run/summary"
# matplotlib's tab10 (its grey swapped for navy: grey is the 95% bounds' colour) and a
# few more: one colour per variant in the overlaid plots
PALETTE: tuple[style.Rgb, ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (0, 0, 128), (188, 189, 34), (23, 190, 207),
    (255, 215, 0), (174, 199, 232), (255, 187, 120), (152, 223, 138),
)  # fmt: skip
# their names, for the maps' titles (the plots have no legend: it covered the lines)
PALETTE_NAMES: tuple[str, ...] = (
    "blue", "orange", "green", "red", "purple", "brown", "pink", "navy", "olive", "cyan",
    "gold", "light blue", "light orange", "light green",
)  # fmt: skip


def record_study(
    recording: Recording,
    runs: list[Run],
    truth: GroundTruth | None,
    summary: str,
    root: str = "variants",
) -> None:
    """Log every run under its own subtree ``<root>/<key>``, the layout and the summary.

    :param summary: the study's table as markdown
    :param root: ``variants`` for a sweep, ``filters`` for a comparison
    """
    rec = recording.rec
    recorders, box = log_runs(rec, runs, truth, root)
    twins = identical_runs(runs)
    for k, run in enumerate(runs):
        if k in twins:  # drawn apart: the earlier wide beneath, the later narrow on top
            prefix = f"{root}/{run.spec.key}"
            marks = _series_style(
                run, runs[0], PALETTE[k % len(PALETTE)], width=twins[k][0], same=twins[k][1]
            )
            for series in (style.NIS, style.NEES):
                rec.log(f"{prefix}/{series}", marks, static=True)
            if truth is not None:
                rec.log(f"{prefix}/{style.MEAN_LANDMARK_ERROR}", marks, static=True)
    # its tables cut to the summary view's width: the view neither wraps nor scrolls them
    shares = STUDY_COLUMN_SHARES
    fitted = fit_tables(summary, view_characters(shares[1] / sum(shares)))
    rec.log(SUMMARY, rr.TextDocument(fitted, media_type=rr.MediaType.MARKDOWN), static=True)
    finish_recorders(recording, recorders)
    colours = [PALETTE_NAMES[k % len(PALETTE)] for k in range(len(runs))]
    # the plots' colours here too: a narrow map's title cuts its colour off
    key = "**plot colours**: " + ", ".join(
        f"{run.spec.label} {colour}" for run, colour in zip(runs, colours, strict=True)
    )
    log_legend(rec, [recorder for recorder, _ in recorders], key=key)
    # after the runs are finished: the layout shows what they logged, no empty plot
    rec.send_blueprint(
        sweep_blueprint(
            [(run.spec.label, f"{root}/{run.spec.key}") for run in runs],
            has_truth=truth is not None,
            bounds_xy=box,
            what="variant" if root == "variants" else "filter",
            has_poses=truth is not None and truth.has_poses,
            value_axes=study_axes(runs, [recorder for recorder, _ in recorders]),
            identical=identical_note(runs, twins),
            colours=colours,
            has={
                f"{root}/{run.spec.key}": recorder.entities_with_data
                for run, (recorder, _) in zip(runs, recorders, strict=True)
            },
            summary=SUMMARY,
            offline=[
                f"{root}/{run.spec.key}"
                for run, (recorder, _) in zip(runs, recorders, strict=True)
                if recorder.offline
            ],
        )
    )


def log_runs(
    rec: rr.RecordingStream, runs: list[Run], truth: GroundTruth | None, root: str
) -> tuple[list[tuple[Recorder, Evaluation]], FloatArray]:
    """Log every run's events under ``<root>/<key>``, one colour per run in the plots.

    :return: the recorders to finish with their evaluations, and the (2, 2) world box
        of every pose and landmark's 3-sigma ellipse, with a margin
    """
    recorders: list[tuple[Recorder, Evaluation]] = []
    bounds: list[FloatArray] = []
    for k, run in enumerate(runs):
        prefix = f"{root}/{run.spec.key}"
        offline = is_offline(run, runs[0])
        recorder = Recorder(rec, truth=truth, blueprint=False, prefix=prefix, offline=offline)
        colour = PALETTE[k % len(PALETTE)]
        marks = _series_style(run, runs[0], colour)
        for series in (style.NIS, style.NEES):  # one colour and name per run, overlaid
            rec.log(f"{prefix}/{series}", marks, static=True)
        recorder.log(run.events)
        if truth is not None:
            _log_mean_error(rec, prefix, run, truth, marks)
        recorders.append((recorder, run.evaluation))
        bounds.append(run.events.poses[:, :2])
        last = run.events.last  # the final map's ellipses in the frame, not only its points
        if last.n_landmarks:
            bounds.append(ellipse_extent(last.landmarks_xy, last.landmark_covs))
    points = np.concatenate(bounds)
    box = np.stack([points.min(axis=0), points.max(axis=0)])
    margin = 0.05 * max(float(np.max(box[1] - box[0])), 1.0)
    return recorders, box + np.array([[-margin], [margin]])


def log_legend(
    rec: rr.RecordingStream, recorders: Sequence[Recorder], *extra: str, key: str = ""
) -> None:
    """The legend of the maps of a study's runs (``run/legend``), from what any of them
    drew and the ``extra`` entity paths (see :mod:`ekfviz.viz.legend`), then ``key``."""
    drawn = {path for recorder in recorders for path in recorder.entities_with_data}
    legend = " · ".join(part for part in (legend_markdown(drawn | set(extra)), key) if part)
    if legend:
        rec.log(style.RUN_LEGEND, markdown_document(legend), static=True)


def study_axes(runs: Sequence[Run], recorders: Sequence[Recorder]) -> dict[str, FittedAxis]:
    """The NIS and NEES axes of a study, fitted to its runs that are not wild (see
    :func:`ekfviz.viz.axes.study_axis`): a wild run is clipped, with a note, not the
    rest flattened."""
    axes: dict[str, FittedAxis] = {}
    for path in (style.NIS, style.NEES):
        fitted = study_axis(
            [
                (run.spec.label, recorder.value_extents[path])
                for run, recorder in zip(runs, recorders, strict=True)
                if path in recorder.value_extents
            ]
        )
        if fitted is not None:
            axes[path] = fitted
    return axes


def identical_runs(runs: Sequence[Run]) -> dict[int, tuple[float, str]]:
    """The runs whose poses and NIS equal another's, drawn apart: by index, the line
    width and the labels of the other runs it equals.

    :return: {index: (width, "ekf, Textbook")}, the first of a group widest
    """
    groups: list[list[int]] = []
    for k, run in enumerate(runs):
        for group in groups:
            if _same_run(runs[group[0]], run):
                group.append(k)
                break
        else:
            groups.append([k])
    twins: dict[int, tuple[float, str]] = {}
    for group in groups:
        if len(group) < 2:
            continue
        for rank, k in enumerate(group):
            others = ", ".join(runs[j].spec.label for j in group if j != k)
            twins[k] = (max(1.5, 6.0 - 2.0 * rank), others)
    return twins


def identical_note(runs: Sequence[Run], twins: Mapping[int, tuple[float, str]]) -> str:
    """The plots' note on identical runs: "ekf = Textbook (identical)", or empty."""
    groups: list[str] = []
    seen: set[int] = set()
    for k in sorted(twins):
        if k in seen:
            continue
        group = [k, *(j for j in sorted(twins) if j != k and runs[j].spec.label in
                      twins[k][1].split(", "))]  # fmt: skip
        seen.update(group)
        groups.append(" = ".join(runs[j].spec.label for j in group))
    return f"{'; '.join(groups)} identical" if groups else ""


def _same_run(first: Run, second: Run) -> bool:
    """Whether two runs have the same poses and NIS at every event, to a part in 10^6
    (two implementations of one filter differ in round-off only)."""
    a, b = first.events, second.events
    if len(a) != len(b) or not np.allclose(a.poses, b.poses, rtol=1e-6, atol=1e-9):
        return False
    nis_a, nis_b = events_nis(a.observed)[1], events_nis(b.observed)[1]
    return nis_a.shape == nis_b.shape and bool(np.allclose(nis_a, nis_b, rtol=1e-6, atol=1e-9))


def is_offline(run: Run, baseline: Run) -> bool:
    """Whether a run is an offline filter's (it has ``finish()``): its events are the
    initialisation and the optimum at the end, with the whole path in the last."""
    events = run.events
    last_path = events.extra(len(events) - 1).path_xytheta
    return last_path is not None or (len(events) <= 2 < len(baseline.events))


def _series_style(
    run: Run, baseline: Run, colour: style.Rgb, *, width: float | None = None, same: str = ""
) -> rr.AsComponents:
    """An online run's series as lines; an offline run's as points: a line between its
    two events would look like a value at every step.

    :param width: the line's width (a marker's size) where it is drawn apart from runs
        identical to it, named in ``same``
    """
    name = run.spec.label + (f" (= {same})" if same else "")
    if is_offline(run, baseline):
        return rr.SeriesPoints(
            colors=colour,
            names=f"{name} (offline: start, end)",
            marker_sizes=5.0 if width is None else width + 3.0,
        )
    return rr.SeriesLines(colors=colour, names=name, widths=width)


def _log_mean_error(
    rec: rr.RecordingStream, prefix: str, run: Run, truth: GroundTruth, marks: rr.AsComponents
) -> None:
    """The mean Euclidean landmark error after every update, as one column send."""
    steps, events, means = [], [], []
    found = run.events
    for row in found.corrected.tolist():
        record = found.event(row)
        if not record.n_landmarks:
            continue
        euclidean, _ = landmark_errors(
            record.landmarks_xy, record.landmark_covs, truth.lookup(record.landmark_ids)
        )
        if np.isfinite(euclidean).any():
            steps.append(record.step)
            events.append(record.event)
            means.append(float(np.nanmean(euclidean)))
    path = f"{prefix}/{style.MEAN_LANDMARK_ERROR}"
    rec.log(path, marks, static=True)
    rec.send_columns(
        path,
        indexes=[
            rr.TimeColumn(style.STEP, sequence=steps),
            rr.TimeColumn(style.EVENT, sequence=events),
        ],
        columns=rr.Scalars.columns(scalars=means),
    )


def mark_event(
    recording: Recording, *, step: int, event: int, text: str, where_xy: FloatArray | None
) -> None:
    """Mark one event of a study on the timeline: an ERROR line in the log and, on the
    maps, a red cross where it happened (``ekfviz check``'s first divergence)."""
    rec = recording.rec
    rec.set_time(style.STEP, sequence=step)
    rec.set_time(style.EVENT, sequence=event)
    rec.log(style.LOG, rr.TextLog(text, level=rr.TextLogLevel.ERROR))
    rec.log(f"{style.LOG}/divergence", rr.TextLog(text, level=rr.TextLogLevel.ERROR))
    if where_xy is not None:
        rec.log(
            "world/divergence",
            rr.Points2D([where_xy], colors=[(220, 0, 0)], radii=rr.Radius.ui_points(8.0),
                        labels=["first divergence"], show_labels=True),
        )  # fmt: skip
