"""A reference trajectory (Victoria Park's GPS) fitted to the estimate: in the map, and its
error over time.

| entity | what |
|---|---|
| ``world/reference/gps`` | the track, broken at its dropouts (static) |
| ``world/reference/gps_jumps`` | fixes far off their neighbours' line (static) |
| ``metrics/reference/{gps_error,gps_rmse}`` | the error at each fix, its running RMSE |
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import rerun as rr

from ekfviz.core.types import FloatArray
from ekfviz.evaluation.reference import ReferenceFit
from ekfviz.viz import style
from ekfviz.viz.layers import arrow
from ekfviz.viz.legend import GPS_TRACK, KIND_CLASS

REFERENCE = "world/reference/gps"
REFERENCE_JUMPS = "world/reference/gps_jumps"  # fixes far off their neighbours' line
REFERENCE_ERROR = "metrics/reference/gps_error"
REFERENCE_RMSE = "metrics/reference/gps_rmse"
REFERENCE_COLOR = (128, 0, 128)


# A GPS dropout: a gap between fixes this many times their median interval (and at least
# GAP_MIN_S); at 1 Hz with a few missed fixes the track stays one piece
GAP_FACTOR = 5.0
GAP_MIN_S = 3.0


def gps_pieces(xy: FloatArray, times: FloatArray) -> list[FloatArray]:
    """A GPS track cut into pieces at its dropouts (see ``GAP_FACTOR``).

    :param xy: (K, 2) fixes in time order
    :param times: (K,) their times in seconds
    :return: the pieces, each (k, 2) with k >= 1 (a lone fix is a piece of one point)
    """
    if len(xy) < 2:
        return [xy]
    gaps = np.diff(times)
    limit = max(GAP_FACTOR * float(np.median(gaps)), GAP_MIN_S)
    cuts = np.flatnonzero(gaps > limit) + 1
    return [piece for piece in np.split(xy, cuts) if len(piece)]


def log_reference(
    rec: rr.RecordingStream, path: Callable[[str], str], fit: ReferenceFit, steps: FloatArray
) -> None:
    """The reference fitted to the estimate (static, in the map) and its error over time.

    :param steps: (K,) the step at each reference time (for the step timeline)
    """
    # the track without its jumps (a fix far off for a moment), which are points apart,
    # broken where the GPS had no fix for a while: a dropout is no straight chord
    kept = fit.reference_xy[~fit.jumps]
    rec.log(
        path(REFERENCE),
        rr.LineStrips2D(
            gps_pieces(kept, fit.times[~fit.jumps]),
            colors=[REFERENCE_COLOR],
            radii=rr.Radius.ui_points(1.0),
            class_ids=KIND_CLASS[GPS_TRACK],
            show_labels=False,
        ),
        static=True,
    )
    if fit.jumps.any():
        rec.log(
            path(REFERENCE_JUMPS),
            rr.Points2D(
                fit.reference_xy[fit.jumps],
                colors=[REFERENCE_COLOR],
                radii=rr.Radius.ui_points(4.0),
                labels=[f"GPS jump t={t:.2f} s" for t in fit.times[fit.jumps]],
            ),
            static=True,
        )
    rec.send_columns(
        path(REFERENCE_ERROR),
        indexes=[
            arrow.time_column(fit.times),
            rr.TimeColumn(style.STEP, sequence=steps.astype(np.int64)),
        ],
        columns=rr.Scalars.columns(scalars=fit.errors),
    )
    rmse = np.sqrt(np.cumsum(fit.errors**2) / np.arange(1, len(fit.errors) + 1))
    rec.send_columns(
        path(REFERENCE_RMSE),
        indexes=[
            arrow.time_column(fit.times),
            rr.TimeColumn(style.STEP, sequence=steps.astype(np.int64)),
        ],
        columns=rr.Scalars.columns(scalars=rmse),
    )
