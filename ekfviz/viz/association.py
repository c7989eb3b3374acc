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
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.association.evaluation import AssociationTally
from ekfviz.core.records import EventRecord, Fate
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.evaluation.reference import ReferenceFit
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.viz import style
from ekfviz.viz.ellipses import N_POINTS, ellipse_outlines
from ekfviz.viz.layers import arrow
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
_MATCHED, _REJECTED = int(Fate.MATCHED), int(Fate.REJECTED)
# the scans' shapes and texts are sent every this many scans: one send per entity instead of
# a log per scan (7,200 scans x 6 entities cost Victoria Park a third of its time), in
# chunks small enough for ``rerun rrd verify`` (see recorder.SHAPES_EVERY)
SCANS_EVERY = 256


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
        # each landmark's smoothed object size, by id (known: it has one)
        self._size_value = np.zeros(0)
        self._size_known = np.zeros(0, dtype=bool)
        self._series: dict[str, list[tuple[int, int, float, float]]] = {}
        self._rows = _ScanRows()
        self._lookup = _RowLookup()
        rec.log(path(RAYS), rr.LineStrips2D([], radii=rr.Radius.ui_points(0.75)), static=True)
        rec.log(path(TENTATIVE), rr.Points2D([], colors=[TENTATIVE_COLOR]), static=True)

    def log(self, record: EventRecord) -> None:
        """Buffer one scan's association; sent every ``SCANS_EVERY`` scans and at
        :meth:`flush`."""
        association = record.association
        if association is None:
            return
        if self._rows.steps and math.isnan(self._rows.times[-1]) != (record.time is None):
            self._send_scans()  # a batch's rows all have a time or none has
        rows = self._rows
        rows.steps.append(record.step)
        rows.events.append(record.event)
        rows.times.append(math.nan if record.time is None else record.time)
        # the geometry (rays, links, gates) is computed at the send, for every scan of the
        # batch at once: here only what it needs is kept
        x, y, theta = record.pose.tolist()
        fate = association.fate.astype(np.int64)
        rows.poses.append((x, y, theta))
        rows.z.append(association.z)
        rows.fates.append(fate)
        landmark_ids = record.landmark_ids
        matched = np.flatnonzero(fate == _MATCHED)
        rows_of = self._lookup.rows(landmark_ids, association.landmark[matched])
        found = rows_of >= 0
        rows.link_from.append(matched[found])
        rows.link_to.append(record.landmarks_xy[rows_of[found]])
        rows.gate_z.append(association.gate_z)
        rows.gate_covs.append(association.gate_S)
        rows.gate_threshold.append(association.gate_threshold)
        tentative_rows = self._lookup.rows(landmark_ids, association.tentative)
        tentative_rows = tentative_rows[tentative_rows >= 0]
        rows.tentative.append(record.landmarks_xy[tentative_rows])
        rows.tentative_labels.extend(
            f"L{i} (tentative)" for i in landmark_ids[tentative_rows].tolist()
        )
        if association.diameters is not None:
            kept = fate != _REJECTED
            updates = zip(
                association.landmark[kept].tolist(),
                association.diameters[kept].tolist(),
                strict=True,
            )
            self._grow_sizes(int(association.landmark[kept].max(initial=-1)))
            known, smoothed = self._size_known, self._size_value
            for i, size in updates:
                smoothed[i] = 0.8 * smoothed[i] + 0.2 * size if known[i] else size
                known[i] = True
            removed = association.removed
            known[removed[(removed >= 0) & (removed < len(known))]] = False
            # the landmarks with a size, in the record's order (ids of the associator: >= 0)
            ids = landmark_ids
            has = np.zeros(len(ids), dtype=bool)
            inside = (ids >= 0) & (ids < len(known))
            has[inside] = known[ids[inside]]
            picked_rows = np.flatnonzero(has)
            radii = np.maximum(smoothed[ids[picked_rows]], 0.05) / 2
            rows.sized.append(len(rows.steps) - 1)
            rows.sizes.append(record.landmarks_xy[picked_rows])
            rows.size_radii.append(radii)
        score = self.tally.add(record)
        matched_n, new_n, rejected_n = np.bincount(fate, minlength=3)[:3].tolist()
        values = {
            "matched": matched_n,
            "new": new_n,
            "rejected": rejected_n,
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
        rows.texts.append(text)
        rows.levels.append(rr.TextLogLevel.WARN if association.exhausted else rr.TextLogLevel.DEBUG)
        if len(rows.steps) >= SCANS_EVERY:
            self._send_scans()
        if len(self._series["matched"]) >= _SERIES_FLUSH:
            self._send_series()

    def _grow_sizes(self, largest_id: int) -> None:
        """Room in the size arrays for ids up to ``largest_id``."""
        n = len(self._size_known)
        if largest_id < n:
            return
        grown = max(largest_id + 1, 2 * n, 64)
        self._size_value = np.concatenate([self._size_value, np.zeros(grown - n)])
        self._size_known = np.concatenate([self._size_known, np.zeros(grown - n, dtype=bool)])

    def flush(self) -> None:
        """Send everything buffered: the scans' shapes and texts, and the series."""
        self._send_scans()
        self._send_series()

    def _send_scans(self) -> None:
        """The buffered scans, one column per component of each entity."""
        rows, self._rows = self._rows, _ScanRows()
        if not rows.steps:
            return
        # the stream's clock at the last scan, as a log per scan left it, for whatever
        # is logged next without setting it
        rec = self._rec
        rec.set_time(style.STEP, sequence=rows.steps[-1])
        rec.set_time(style.EVENT, sequence=rows.events[-1])
        last_time = rows.times[-1]
        if not math.isnan(last_time):
            if time_is_epoch(last_time):
                rec.set_time(style.TIME, timestamp=last_time)
            else:
                rec.set_time(style.TIME, duration=last_time)
        steps = np.array(rows.steps, dtype=np.int64)
        events = np.array(rows.events, dtype=np.int64)
        times = np.array(rows.times, dtype=np.float64)
        everything = np.arange(len(steps))

        def send(entity: str, at: IntArray, columns: list[rr.ComponentColumn]) -> None:
            indexes = [
                rr.TimeColumn(style.STEP, sequence=steps[at]),
                rr.TimeColumn(style.EVENT, sequence=events[at]),
            ]
            if np.isfinite(times).all():  # all or none (see log)
                indexes.append(_rounded_time_column(times[at]))
            self._rec.send_columns(self._path(entity), indexes=indexes, columns=columns)

        ones = np.ones(len(steps), dtype=np.int64)
        geometry = _geometry(self._sensor, rows)
        send(
            RAYS,
            everything,
            [
                arrow.column(
                    rr.LineStrips2D.descriptor_strips(),
                    _strips(geometry.rays),
                    geometry.rays_per_scan,
                ),
                arrow.column(
                    rr.LineStrips2D.descriptor_colors(),
                    _colors(FATE_COLORS[np.concatenate(rows.fates)]),
                    geometry.rays_per_scan,
                ),
            ],
        )
        send(
            LINKS,
            everything,
            _one_colour_strips(geometry.links, geometry.links_per_scan, LINK_COLOR, ones),
        )
        send(
            GATES,
            everything,
            _one_colour_strips(geometry.gates, geometry.gates_per_scan, GATE_COLOR, ones),
        )
        counts = np.array([len(r) for r in rows.tentative], dtype=np.int64)
        send(
            TENTATIVE,
            everything,
            [
                arrow.column(
                    rr.Points2D.descriptor_positions(),
                    arrow.xy(np.concatenate(rows.tentative).reshape(-1, 2)),
                    counts,
                ),
                arrow.column(
                    rr.Points2D.descriptor_radii(),
                    pa.array(np.full(len(steps), -6.0, dtype=np.float32)),
                    ones,
                ),
                arrow.column(
                    rr.Points2D.descriptor_colors(),
                    _colors(np.repeat([TENTATIVE_COLOR], len(steps), axis=0)),
                    ones,
                ),
                arrow.column(
                    rr.Points2D.descriptor_labels(),
                    pa.array(rows.tentative_labels, type=pa.utf8()),
                    counts,
                ),
            ],
        )
        if rows.sized:
            at = np.array(rows.sized, dtype=np.int64)
            counts = np.array([len(r) for r in rows.sizes], dtype=np.int64)
            send(
                SIZES,
                at,
                [
                    arrow.column(
                        rr.Points2D.descriptor_positions(),
                        arrow.xy(np.concatenate(rows.sizes).reshape(-1, 2)),
                        counts,
                    ),
                    arrow.column(
                        rr.Points2D.descriptor_radii(),
                        pa.array(np.concatenate(rows.size_radii).astype(np.float32)),
                        counts,
                    ),
                    arrow.column(
                        rr.Points2D.descriptor_colors(),
                        _colors(np.repeat([style.LANDMARK_COLOR], len(at), axis=0)),
                        np.ones(len(at), dtype=np.int64),
                    ),
                ],
            )
        send(
            style.LOG,
            everything,
            list(rr.TextLog.columns(text=rows.texts, level=rows.levels)),
        )

    def _send_series(self) -> None:
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


@dataclass(frozen=True, slots=True)
class _ScanRows:
    """The scans buffered since the last send: per scan its times and each entity's
    values (lists of arrays, one per scan; labels flat)."""

    steps: list[int] = field(default_factory=list)
    events: list[int] = field(default_factory=list)
    times: list[float] = field(default_factory=list)  # nan: the log has no times
    poses: list[tuple[float, float, float]] = field(default_factory=list)
    z: list[FloatArray] = field(default_factory=list)  # (k, 2) each: the measurements
    fates: list[IntArray] = field(default_factory=list)  # (k,) each
    link_from: list[IntArray] = field(default_factory=list)  # (l,) each: measurements ...
    link_to: list[FloatArray] = field(default_factory=list)  # (l, 2) each: ... to landmarks
    gate_z: list[FloatArray] = field(default_factory=list)  # (g, 2) each
    gate_covs: list[FloatArray] = field(default_factory=list)  # (g, 2, 2) each: S
    gate_threshold: list[float] = field(default_factory=list)
    tentative: list[FloatArray] = field(default_factory=list)  # (t, 2) each
    tentative_labels: list[str] = field(default_factory=list)
    sized: list[int] = field(default_factory=list)  # the scans with sizes (their index)
    sizes: list[FloatArray] = field(default_factory=list)  # (s, 2) each
    size_radii: list[FloatArray] = field(default_factory=list)  # (s,) each
    texts: list[str] = field(default_factory=list)
    levels: list[rr.TextLogLevel] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class _Geometry:
    """The batch's shapes, every scan's in order: (k, n, 2) polylines and their count per
    scan."""

    rays: FloatArray
    rays_per_scan: IntArray
    links: FloatArray
    links_per_scan: IntArray
    gates: FloatArray
    gates_per_scan: IntArray


def _geometry(sensor: RangeBearing, rows: _ScanRows) -> _Geometry:
    """The rays, links and gates of the buffered scans, a few array operations for all.

    Each measurement and each gate's centre through the sensor's inverse model at its
    scan's pose; each gate's covariance mapped to the plane through that model's Jacobian
    (``l_D_z S l_D_z^T``); a link from its measurement's point to its landmark.
    """
    poses = np.array(rows.poses, dtype=np.float64).reshape(-1, 3)
    origins = np.array([sensor.sensor(pose)[:2] for pose in poses], dtype=np.float64)
    rays_per_scan = np.array([len(z) for z in rows.z], dtype=np.int64)
    gates_per_scan = np.array([len(z) for z in rows.gate_z], dtype=np.int64)
    z = np.concatenate([*rows.z, *rows.gate_z]).reshape(-1, 2)
    scan = np.concatenate(
        [
            np.repeat(np.arange(len(poses)), rays_per_scan),
            np.repeat(np.arange(len(poses)), gates_per_scan),
        ]
    )
    ends, l_D_z = _inverse_at(origins[scan], poses[scan, 2], z)
    m = int(rays_per_scan.sum())
    rays = np.empty((m, 2, 2))
    rays[:, 0] = origins[scan[:m]]
    rays[:, 1] = ends[:m]
    first = np.zeros(len(poses), dtype=np.int64)  # each scan's first measurement
    np.cumsum(rays_per_scan[:-1], out=first[1:])
    links_per_scan = np.array([len(k) for k in rows.link_from], dtype=np.int64)
    links = np.empty((int(links_per_scan.sum()), 2, 2))
    if len(links):
        picked = np.concatenate(rows.link_from) + np.repeat(first, links_per_scan)
        links[:, 0] = ends[picked]
        links[:, 1] = np.concatenate(rows.link_to).reshape(-1, 2)
    gates = np.zeros((0, 2, 2))
    if len(z) > m:
        jacobians = l_D_z[m:]
        covs = jacobians @ np.concatenate(rows.gate_covs) @ jacobians.transpose(0, 2, 1)
        threshold = np.repeat(np.array(rows.gate_threshold, dtype=np.float64), gates_per_scan)
        values = np.unique(threshold)
        if len(values) == 1:
            gates = ellipse_outlines(ends[m:], covs, n_sigma=math.sqrt(float(values[0])))
        else:  # scans of several gates: each group at its own size
            gates = np.empty((len(covs), N_POINTS, 2))
            for value in values.tolist():
                at = np.flatnonzero(threshold == value)
                gates[at] = ellipse_outlines(ends[m:][at], covs[at], n_sigma=math.sqrt(value))
    return _Geometry(rays, rays_per_scan, links, links_per_scan, gates, gates_per_scan)


def _one_colour_strips(
    polylines: FloatArray, per_scan: IntArray, color: tuple[int, int, int], ones: IntArray
) -> list[rr.ComponentColumn]:
    """Polylines (k, n, 2), ``per_scan`` of them a scan, as line strips of one colour."""
    return [
        arrow.column(rr.LineStrips2D.descriptor_strips(), _strips(polylines), per_scan),
        arrow.column(
            rr.LineStrips2D.descriptor_colors(),
            _colors(np.repeat([color], len(per_scan), axis=0)),
            ones,
        ),
    ]


def _strips(polylines: FloatArray) -> pa.Array:
    """Polylines (k, n, 2) as Rerun's line strips."""
    offsets = np.arange(len(polylines) + 1, dtype=np.int32) * np.int32(polylines.shape[1])
    points = polylines.reshape(-1, 2)
    return pa.ListArray.from_arrays(pa.array(offsets), arrow.xy(points), type=arrow.STRIP)


def _colors(rgb: npt.NDArray[np.integer]) -> pa.Array:
    """(K, 3) colours as Rerun's packed RGBA."""
    return rr.components.ColorBatch(np.asarray(rgb, dtype=np.uint8)).as_arrow_array()


def _time_column(times: FloatArray) -> rr.TimeColumn:
    """The ``time`` timeline of some rows, of the type the recorder chose for the log."""
    if len(times) and time_is_epoch(float(times[0])):
        return rr.TimeColumn(style.TIME, timestamp=times)
    return rr.TimeColumn(style.TIME, duration=times)


def _rounded_time_column(times: FloatArray) -> rr.TimeColumn:
    """:func:`_time_column` rounded to the nanosecond as ``set_time`` rounds (the SDK's
    columns truncate: 8.543 s would become 8.542999999 s), for rows once logged one by one."""
    nanos = np.round(times * 1e9).astype(np.int64)
    if len(times) and time_is_epoch(float(times[0])):
        return rr.TimeColumn(style.TIME, timestamp=nanos.astype("datetime64[ns]"))
    return rr.TimeColumn(style.TIME, duration=nanos.astype("timedelta64[ns]"))


def _inverse_at(
    origins: FloatArray, headings: FloatArray, z: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """:meth:`RangeBearing.inverse` and its ``l_D_z`` of many measurements at once, each
    from its own sensor position and heading.

    :param origins: (K, 2) the sensor's position; :param headings: (K,) the vehicle's
    :param z: (K, 2) (bearing, range)
    :return: landmarks (K, 2), l_D_z (K, 2, 2)
    """
    rng = z[:, 1]
    phi = headings + z[:, 0]
    c, s = np.cos(phi), np.sin(phi)
    points = np.empty((len(z), 2))
    points[:, 0] = origins[:, 0] + rng * c
    points[:, 1] = origins[:, 1] + rng * s
    l_D_z = np.empty((len(z), 2, 2))
    l_D_z[:, 0, 0] = -rng * s
    l_D_z[:, 0, 1] = c
    l_D_z[:, 1, 0] = rng * c
    l_D_z[:, 1, 1] = s
    return points, l_D_z


class _RowLookup:
    """:func:`_rows_of` for the records of a run: a table from id to row, kept while the
    records hand the same ids array (the filter shares one until its map changes, and
    a scan's records ask twice); ids that are negative or sparse go by :func:`_rows_of`."""

    def __init__(self) -> None:
        self._ids: IntArray | None = None
        self._table: IntArray | None = None

    def rows(self, ids: IntArray, wanted: IntArray) -> IntArray:
        if ids is not self._ids:
            self._ids, self._table = ids, None  # held: the array cannot be another's
            if len(ids) and int(ids.min()) >= 0 and int(ids.max()) < 4 * len(ids) + 1024:
                self._table = np.full(int(ids.max()) + 1, -1, dtype=np.int64)
                self._table[ids] = np.arange(len(ids))
        table = self._table
        if table is None:
            return _rows_of(ids, wanted)
        wanted = np.asarray(wanted, dtype=np.int64)
        rows: IntArray = np.full(len(wanted), -1, dtype=np.int64)
        inside = (wanted >= 0) & (wanted < len(table))
        rows[inside] = table[wanted[inside]]
        return rows


def _rows_of(ids: IntArray, wanted: IntArray) -> IntArray:
    """The row of each of ``wanted`` in ``ids`` (distinct), -1 where it is not there."""
    wanted = np.asarray(wanted, dtype=np.int64)
    if not len(ids) or not len(wanted):
        return np.full(len(wanted), -1, dtype=np.int64)
    order = None if bool((ids[1:] > ids[:-1]).all()) else np.argsort(ids, kind="stable")
    ordered = ids if order is None else ids[order]
    at = np.minimum(np.searchsorted(ordered, wanted), len(ids) - 1)
    found = ordered[at] == wanted
    rows = at if order is None else order[at]
    return np.where(found, rows, -1).astype(np.int64)


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
