"""A parameter sweep in one recording: every variant under ``variants/<key>/``.

Rerun does not synchronise timelines across recordings, so the variants share one
recording and its ``step`` and ``event`` timelines: scrubbing moves them all together.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from ekfviz.core.consistency import chi2_bounds, update_nis
from ekfviz.core.evaluation import landmark_errors
from ekfviz.core.records import EventKind
from ekfviz.core.truth import GroundTruth
from ekfviz.sweep import VariantRun
from ekfviz.viz import style
from ekfviz.viz.blueprint import sweep_blueprint
from ekfviz.viz.recorder import Recorder
from ekfviz.viz.run import Recording, finish_recorders

SUMMARY = "run/sweep"
# matplotlib's tab10 and a few more: one colour per variant in the overlaid plots
PALETTE: tuple[style.Rgb, ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
    (255, 215, 0), (174, 199, 232), (255, 187, 120), (152, 223, 138),
)  # fmt: skip


def variant_prefix(run: VariantRun) -> str:
    return f"variants/{run.variant.key}"


def record_sweep(
    recording: Recording, runs: list[VariantRun], truth: GroundTruth | None, summary: str
) -> None:
    """Log every variant's run under its own subtree, the layout and the summary table.

    :param summary: the sweep table as markdown
    """
    rec = recording.rec
    recorders = []
    bounds: list[np.ndarray] = []
    for k, run in enumerate(runs):
        prefix = variant_prefix(run)
        recorder = Recorder(rec, truth=truth, blueprint=False, prefix=prefix)
        colour = PALETTE[k % len(PALETTE)]
        rec.log(
            f"{prefix}/{style.NIS}",
            rr.SeriesLines(colors=colour, names=run.variant.label),
            static=True,
        )
        for record in run.records:
            recorder.log_record(record)
        if truth is not None:
            _log_mean_error(rec, prefix, run, truth, colour)
        recorders.append((recorder, run.evaluation))
        for record in run.records:
            bounds.append(record.pose[None, :2])
            bounds.append(record.landmarks_xy)
    points = np.concatenate(bounds)
    box = np.stack([points.min(axis=0), points.max(axis=0)])
    margin = 0.05 * max(float(np.max(box[1] - box[0])), 1.0)
    rec.send_blueprint(
        sweep_blueprint(
            [(run.variant.label, variant_prefix(run)) for run in runs],
            has_truth=truth is not None,
            bounds_xy=box + np.array([[-margin], [margin]]),
            nis_range=nis_axis(runs[0]),
        )
    )
    rec.log(SUMMARY, rr.TextDocument(summary, media_type=rr.MediaType.MARKDOWN), static=True)
    finish_recorders(recording, recorders)


def nis_axis(baseline: VariantRun) -> tuple[float, float] | None:
    """The NIS axis of a sweep: from 0 to three times the baseline's largest 95% upper
    bound, or to its largest NIS if that is higher (None without an update)."""
    uppers, values = [], []
    for record in baseline.records:
        found = update_nis(record)
        if found is not None:
            values.append(found[0])
            uppers.append(chi2_bounds(found[1])[1])
    if not uppers:
        return None
    return 0.0, max(3.0 * max(uppers), max(values))


def _log_mean_error(
    rec: rr.RecordingStream, prefix: str, run: VariantRun, truth: GroundTruth, colour: style.Rgb
) -> None:
    """The mean Euclidean landmark error after every update, as one column send."""
    steps, events, means = [], [], []
    for record in run.records:
        if record.kind is EventKind.PREDICT or not record.n_landmarks:
            continue
        euclidean, _ = landmark_errors(
            record.landmarks_xy, record.landmark_covs, truth.lookup(record.landmark_ids)
        )
        if np.isfinite(euclidean).any():
            steps.append(record.step)
            events.append(record.event)
            means.append(float(np.nanmean(euclidean)))
    path = f"{prefix}/{style.MEAN_LANDMARK_ERROR}"
    rec.log(path, rr.SeriesLines(colors=colour, names=run.variant.label), static=True)
    rec.send_columns(
        path,
        indexes=[
            rr.TimeColumn(style.STEP, sequence=steps),
            rr.TimeColumn(style.EVENT, sequence=events),
        ],
        columns=rr.Scalars.columns(scalars=means),
    )
