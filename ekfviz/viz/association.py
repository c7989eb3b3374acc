"""The association of id-less scans on the timeline, and a reference trajectory (GPS).

At every scan (logged on ``step``, ``event`` and, where the log has times, ``time``):

| entity | what |
|---|---|
| ``world/association/rays`` | sensor -> each measurement: green matched, orange new, red rejected |
| ``world/association/links`` | each matched measurement -> the landmark it was paired with |
| ``world/association/gates`` | each candidate's gate: its innovation ellipse, mapped to the map |
| ``world/landmarks/tentative`` | the landmarks still tentative (orange crosses) |
| ``world/landmarks/sizes`` | landmarks drawn at their objects' size (trunk diameters) |
| ``metrics/association/{matched,new,rejected,confirmed,...}`` | per scan |
| ``metrics/association/{correct,wrong,missed}`` | per scan, with truth |
| ``log`` | what the association chose and how many JCBB hypotheses it explored |
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import rerun as rr

from ekfviz.association.evaluation import AssociationTally
from ekfviz.core.records import EventRecord, Fate
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.evaluation.reference import ReferenceFit
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.viz import style
from ekfviz.viz.ellipses import ellipse_outlines
from ekfviz.viz.layers.arrow import time_is_epoch  # the recorder's choice of the time's type

RAYS = "world/association/rays"
LINKS = "world/association/links"
GATES = "world/association/gates"
TENTATIVE = "world/landmarks/tentative"
SIZES = "world/landmarks/sizes"
SERIES = "metrics/association"
REFERENCE = "world/reference/gps"
REFERENCE_JUMPS = "world/reference/gps_jumps"  # fixes far off their neighbours' line
REFERENCE_ERROR = "metrics/reference/gps_error"
REFERENCE_RMSE = "metrics/reference/gps_rmse"

FATE_COLORS = np.array([(0, 160, 0), (255, 140, 0), (220, 0, 0)], dtype=np.uint8)
LINK_COLOR = (0, 160, 0)
GATE_COLOR = (120, 120, 220)
TENTATIVE_COLOR = (255, 140, 0)
REFERENCE_COLOR = (128, 0, 128)
_SERIES_FLUSH = 1024


class AssociationView:
    """Logs each scan's association; the recorder calls :meth:`log` per record.

    :param path: maps an entity path to the recording's (under the recorder's prefix)
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        path: Callable[[str], str],
        sensor: RangeBearing,
        truth: GroundTruth | None,
    ) -> None:
        self._rec = rec
        self._path = path
        self._sensor = sensor
        self.tally = AssociationTally(truth, sensor)
        self._sizes: dict[int, float] = {}
        self._series: dict[str, list[tuple[int, int, float, float]]] = {}
        rec.log(path(RAYS), rr.LineStrips2D([], radii=rr.Radius.ui_points(0.75)), static=True)
        rec.log(path(TENTATIVE), rr.Points2D([], colors=[TENTATIVE_COLOR]), static=True)

    def log(self, record: EventRecord) -> None:
        association = record.association
        if association is None:
            return
        rec, path = self._rec, self._path
        rec.set_time(style.STEP, sequence=record.step)
        rec.set_time(style.EVENT, sequence=record.event)
        if record.time is not None:
            if time_is_epoch(record.time):
                rec.set_time(style.TIME, timestamp=record.time)
            else:
                rec.set_time(style.TIME, duration=record.time)
        pose = record.pose
        sx, sy, _, _ = self._sensor.sensor(pose)
        points = _points(self._sensor, pose, association.z)
        fate = association.fate.astype(np.int64)
        rays = np.stack([np.repeat([[sx, sy]], len(points), axis=0), points], axis=1)
        rec.log(path(RAYS), rr.LineStrips2D(rays, colors=FATE_COLORS[fate]))
        where = {int(i): k for k, i in enumerate(record.landmark_ids.tolist())}
        matched = [
            (points[k], record.landmarks_xy[where[i]])
            for k, (f, i) in enumerate(
                zip(fate.tolist(), association.landmark.tolist(), strict=True)
            )
            if f == Fate.MATCHED and i in where
        ]
        rec.log(
            path(LINKS),
            # an array of strips, not a list: Rerun converts it ten times faster
            rr.LineStrips2D(np.array(matched).reshape(-1, 2, 2), colors=[LINK_COLOR]),
        )
        if len(association.gate_ids):
            centres = np.array([self._sensor.inverse(pose, z) for z in association.gate_z])
            jacobians = np.array(
                [self._sensor.inverse_jacobians(pose, z)[1] for z in association.gate_z]
            )
            covs = jacobians @ association.gate_S @ jacobians.transpose(0, 2, 1)
            outlines = ellipse_outlines(
                centres, covs, n_sigma=math.sqrt(association.gate_threshold)
            )
        else:
            outlines = np.zeros((0, 2, 2))
        # float32 as Rerun stores points (what it would convert them to)
        rec.log(path(GATES), rr.LineStrips2D(outlines.astype(np.float32), colors=[GATE_COLOR]))
        tentative = [where[i] for i in association.tentative.tolist() if i in where]
        rec.log(
            path(TENTATIVE),
            rr.Points2D(
                record.landmarks_xy[tentative],
                labels=[f"L{i} (tentative)" for i in association.tentative.tolist() if i in where],
                colors=[TENTATIVE_COLOR],
                radii=rr.Radius.ui_points(6.0),
            ),
        )
        if association.diameters is not None:
            for f, i, size in zip(
                fate.tolist(),
                association.landmark.tolist(),
                association.diameters.tolist(),
                strict=True,
            ):
                if f != Fate.REJECTED:
                    old = self._sizes.get(i)
                    self._sizes[i] = size if old is None else 0.8 * old + 0.2 * size
            for i in association.removed.tolist():
                self._sizes.pop(i, None)
            ids = [i for i in record.landmark_ids.tolist() if i in self._sizes]
            rec.log(
                path(SIZES),
                rr.Points2D(
                    record.landmarks_xy[[where[i] for i in ids]],
                    radii=[max(self._sizes[i], 0.05) / 2 for i in ids],
                    colors=[style.LANDMARK_COLOR],
                ),
            )
        score = self.tally.add(record)
        values = {
            "matched": association.count(Fate.MATCHED),
            "new": association.count(Fate.NEW),
            "rejected": association.count(Fate.REJECTED),
            "confirmed": len(association.confirmed),
            "removed": len(association.removed),
            "landmarks": record.n_landmarks - len(association.tentative),
            "fell_back": int(association.exhausted),  # JCBB's budget ran out at this scan
        }
        if score is not None:
            values.update(correct=score.correct, wrong=score.wrong, missed=score.missed)
        time = math.nan if record.time is None else record.time
        for name, value in values.items():
            self._series.setdefault(name, []).append((record.step, record.event, time, value))
        if len(self._series["matched"]) >= _SERIES_FLUSH:
            self.flush()
        text = (
            f"step {record.step} scan line {record.line}: {association.method}"
            f" matched {values['matched']} of {len(fate)}, {values['new']} new,"
            f" {values['rejected']} rejected"
        )
        if association.method == "jcbb":
            text += f"; {association.hypotheses} hypotheses"
            if association.exhausted:
                text += f" (budget exhausted: fell back to {association.fallback or 'best found'})"
            text += f", joint NIS {association.joint_nis:.2f}"
        if len(association.confirmed) or len(association.removed):
            confirmed, removed = association.confirmed.tolist(), association.removed.tolist()
            text += f"; confirmed {confirmed}, removed {removed}"
        level = rr.TextLogLevel.WARN if association.exhausted else rr.TextLogLevel.DEBUG
        rec.log(path(style.LOG), rr.TextLog(text, level=level))

    def flush(self) -> None:
        """Send the buffered series, one column each."""
        for name, rows in self._series.items():
            if not rows:
                continue
            table = np.array(rows, dtype=np.float64)
            indexes = [
                rr.TimeColumn(style.STEP, sequence=table[:, 0].astype(np.int64)),
                rr.TimeColumn(style.EVENT, sequence=table[:, 1].astype(np.int64)),
            ]
            if np.isfinite(table[:, 2]).all():
                indexes.append(_time_column(table[:, 2]))
            self._rec.send_columns(
                self._path(f"{SERIES}/{name}"),
                indexes=indexes,
                columns=rr.Scalars.columns(scalars=table[:, 3]),
            )
        self._series = {name: [] for name in self._series}


def _time_column(times: FloatArray) -> rr.TimeColumn:
    """The ``time`` timeline of some rows, of the type the recorder chose for the log."""
    if len(times) and time_is_epoch(float(times[0])):
        return rr.TimeColumn(style.TIME, timestamp=times)
    return rr.TimeColumn(style.TIME, duration=times)


def _points(sensor: RangeBearing, pose: FloatArray, z: FloatArray) -> FloatArray:
    return np.array([sensor.inverse(pose, row) for row in z]).reshape(-1, 2)


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
            _time_column(fit.times),
            rr.TimeColumn(style.STEP, sequence=steps.astype(np.int64)),
        ],
        columns=rr.Scalars.columns(scalars=fit.errors),
    )
    rmse = np.sqrt(np.cumsum(fit.errors**2) / np.arange(1, len(fit.errors) + 1))
    rec.send_columns(
        path(REFERENCE_RMSE),
        indexes=[
            _time_column(fit.times),
            rr.TimeColumn(style.STEP, sequence=steps.astype(np.int64)),
        ],
        columns=rr.Scalars.columns(scalars=rmse),
    )
