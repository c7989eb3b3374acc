"""The association of id-less scans on the timeline (a reference trajectory, GPS, is
:mod:`ekfviz.viz.reference`'s).

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

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.association.evaluation import AssociationTally, ScanScore
from ekfviz.core.batch import EventBatch, ranges
from ekfviz.core.records import EventRecord, Fate
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.viz import style
from ekfviz.viz.ellipses import N_POINTS, ellipse_outlines
from ekfviz.viz.layers import arrow
from ekfviz.viz.layers.arrow import time_is_epoch  # the recorder's choice of the time's type
from ekfviz.viz.legend import KIND_CLASS

RAYS = "world/association/rays"
LINKS = "world/association/links"
GATES = "world/association/gates"
TENTATIVE = "world/landmarks/tentative"
SIZES = "world/landmarks/sizes"
SERIES = "metrics/association"

FATE_COLORS = np.array([(0, 160, 0), (255, 140, 0), (220, 0, 0)], dtype=np.uint8)
LINK_COLOR = (0, 160, 0)
GATE_COLOR = (120, 120, 220)
TENTATIVE_COLOR = (255, 140, 0)
_SERIES_FLUSH = 1024
_MATCHED, _REJECTED = int(Fate.MATCHED), int(Fate.REJECTED)
# the scans' shapes and texts are sent every this many scans: one send per entity instead of
# a log per scan (7,200 scans x 6 entities cost Victoria Park a third of its time), in
# chunks small enough for ``rerun rrd verify`` (see recorder.SHAPES_EVERY)
SCANS_EVERY = 256


class AssociationView:
    """Logs each scan's association; the recorder calls :meth:`log` with its events.

    A scan is only held at :meth:`log` (and scored: the tally reads every scan in
    order); its rays, links, gates, tentative landmarks, sizes, series and text line are
    made at the send, for the ``SCANS_EVERY`` scans held at once, in a few numpy calls
    each (a numpy call per scan and entity cost Victoria Park more than half a second).

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
        # each landmark's smoothed object size, by id (known: it has one); Python lists,
        # read and written an id at a time
        self._size_value: list[float] = []
        self._size_known: list[bool] = []
        self._held: list[EventRecord] = []  # the scans not sent yet
        self._times: list[float] = []  # and their times (nan: the log has none)
        self._scores: list[ScanScore | None] = []  # and the tally's scores
        self._series = _Series()
        # named by their class on hover, their class's name not drawn
        rays = rr.LineStrips2D(
            [], radii=rr.Radius.ui_points(0.75), class_ids=KIND_CLASS[RAYS], show_labels=False
        )
        rec.log(path(RAYS), rays, static=True)
        tentative = rr.Points2D(
            [], colors=[TENTATIVE_COLOR], class_ids=KIND_CLASS[TENTATIVE], show_labels=False
        )
        rec.log(path(TENTATIVE), tentative, static=True)

    def log(self, events: EventBatch) -> None:
        """Hold the association of each scan of ``events``; sent every ``SCANS_EVERY``
        scans and at :meth:`flush`."""
        for row in sorted(events.extras):
            if events.extras[row].association is not None:
                self._hold(events.event(row))

    def _hold(self, record: EventRecord) -> None:
        """Hold one scan's association (its event's view)."""
        assert record.association is not None
        time = math.nan if record.time is None else record.time
        if self._held and math.isnan(self._times[-1]) != (record.time is None):
            self._send_scans()  # a batch's rows all have a time or none has
        self._held.append(record)
        self._times.append(time)
        self._scores.append(self.tally.add(record.association, record.pose))
        if len(self._held) >= SCANS_EVERY:
            self._send_scans()

    def _grow_sizes(self, largest_id: int) -> None:
        """Room in the size lists for ids up to ``largest_id``."""
        n = len(self._size_known)
        if largest_id < n:
            return
        grown = max(largest_id + 1, 2 * n, 64)
        self._size_value += [0.0] * (grown - n)
        self._size_known += [False] * (grown - n)

    def flush(self) -> None:
        """Send everything held: the scans' shapes and texts, and the series."""
        self._send_scans()
        self._send_series(everything=True)

    def _send_scans(self) -> None:
        """The scans held, one column per component of each entity."""
        records, times_held, scores = self._held, self._times, self._scores
        self._held, self._times, self._scores = [], [], []
        if not records:
            return
        self._set_clock(records[-1], times_held[-1])
        scans = self._scans(records)
        steps = np.array([record.step for record in records], dtype=np.int64)
        events = np.array([record.event for record in records], dtype=np.int64)
        times = np.array(times_held, dtype=np.float64)
        send = _ScanSender(self._rec, self._path, steps, events, times)
        everything = np.arange(len(steps))
        ones = np.ones(len(steps), dtype=np.int64)
        geometry = _geometry(self._sensor, scans)
        send(RAYS, everything, _ray_columns(geometry, scans))
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
        tentative_rows, tentative_counts = self._tentative(records, scans)
        send(TENTATIVE, everything, _tentative_columns(scans, tentative_rows, tentative_counts))
        sized = [k for k, record in enumerate(records) if record.association.diameters is not None]  # type: ignore[union-attr]
        if sized:
            at = np.array(sized, dtype=np.int64)
            size_rows, radii, counts = self._sizes(records, scans, at)
            send(SIZES, at, _size_columns(scans, size_rows, radii, counts))
        values = _scan_values(records, scans, scores)
        texts, levels = _texts(records, scans, values)
        send(style.LOG, everything, list(rr.TextLog.columns(text=texts, level=levels)))
        self._series.add(steps, events, times, values, scores)
        self._send_series(everything=False)

    def _set_clock(self, last: EventRecord, last_time: float) -> None:
        """The stream's clock at the last scan, as a log per scan left it, for whatever
        is logged next without setting it."""
        rec = self._rec
        rec.set_time(style.STEP, sequence=last.step)
        rec.set_time(style.EVENT, sequence=last.event)
        if not math.isnan(last_time):
            if time_is_epoch(last_time):
                rec.set_time(style.TIME, timestamp=last_time)
            else:
                rec.set_time(style.TIME, duration=last_time)

    def _scans(self, records: list[EventRecord]) -> _Scans:
        """The held scans' measurements and maps joined, and their links."""
        associations = [record.association for record in records]
        assert all(association is not None for association in associations)
        fates = [association.fate for association in associations]  # type: ignore[union-attr]
        per_scan = np.fromiter(map(len, fates), np.int64, len(fates))
        owner = np.repeat(np.arange(len(records)), per_scan)
        fate = np.concatenate(fates).astype(np.int64)
        landmark = np.concatenate(
            [association.landmark for association in associations]  # type: ignore[union-attr]
        ).astype(np.int64)
        map_sizes = np.fromiter(
            map(len, [record.landmark_ids for record in records]), np.int64, len(records)
        )
        map_starts = np.zeros(len(records) + 1, dtype=np.int64)
        np.cumsum(map_sizes, out=map_starts[1:])
        scans = _Scans(
            poses=np.concatenate([record.pose for record in records]).reshape(-1, 3),
            z=[association.z for association in associations],  # type: ignore[union-attr]
            fate=fate,
            owner=owner,
            landmark=landmark,
            map_starts=map_starts,
            landmarks_xy=np.concatenate([record.landmarks_xy for record in records]).reshape(-1, 2),
            landmark_ids=np.concatenate([record.landmark_ids for record in records]),
            link_from=np.zeros(0, dtype=np.int64),
            link_to=np.zeros(0, dtype=np.int64),
            links_per_scan=np.zeros(len(records), dtype=np.int64),
            gate_z=[association.gate_z for association in associations],  # type: ignore[union-attr]
            gate_covs=[association.gate_S for association in associations],  # type: ignore[union-attr]
            gate_threshold=[association.gate_threshold for association in associations],  # type: ignore[union-attr]
        )
        # each matched measurement to the landmark it was paired with, where the map has it
        matched = np.flatnonzero(fate == _MATCHED)
        rows = self._joined_rows(records, scans, owner[matched], landmark[matched])
        found = rows >= 0
        return replace(
            scans,
            link_from=matched[found],
            link_to=rows[found],
            links_per_scan=np.bincount(owner[matched[found]], minlength=len(records)),
        )

    def _joined_rows(
        self, records: list[EventRecord], scans: _Scans, owners: IntArray, wanted: IntArray
    ) -> IntArray:
        """The row in the joined maps (``scans.landmarks_xy``) of each landmark id of
        ``wanted`` in the map of its scan ``owners`` (ascending), -1 where it has none.

        One lookup per run of scans that share a map (the filter's records share one
        ids array until the map changes): the tables of small non-negative ids
        (:func:`_dense_table`) joined into one array and read at once, a sorted search
        per map otherwise (:func:`_rows_of`)."""
        rows: IntArray = np.full(len(wanted), -1, dtype=np.int64)
        if not len(wanted):
            return rows
        bounds = np.searchsorted(owners, np.arange(len(records) + 1)).tolist()
        tables: list[IntArray] = []
        offset = np.zeros(len(records), dtype=np.int64)  # each scan's table in the joined
        width = np.zeros(len(records), dtype=np.int64)  # and its length (0: none)
        cursor, k = 0, 0
        while k < len(records):
            ids = records[k].landmark_ids
            end = k + 1
            while end < len(records) and records[end].landmark_ids is ids:
                end += 1
            lo, hi = bounds[k], bounds[end]
            if hi > lo:
                table = _dense_table(ids)
                if table is not None:
                    tables.append(table)
                    offset[k:end], width[k:end] = cursor, len(table)
                    cursor += len(table)
                else:
                    found = _rows_of(ids, wanted[lo:hi])
                    hit = found >= 0
                    rows[lo:hi][hit] = scans.map_starts[owners[lo:hi][hit]] + found[hit]
            k = end
        if tables:
            joined = np.concatenate(tables)
            asked = np.flatnonzero((wanted >= 0) & (wanted < width[owners]))
            found = joined[offset[owners[asked]] + wanted[asked]]
            hit = found >= 0
            rows[asked[hit]] = scans.map_starts[owners[asked[hit]]] + found[hit]
        return rows

    def _tentative(self, records: list[EventRecord], scans: _Scans) -> tuple[IntArray, IntArray]:
        """The joined rows of each scan's tentative landmarks in its map, and their count
        per scan."""
        tentative = [record.association.tentative for record in records]  # type: ignore[union-attr]
        per_scan = np.fromiter(map(len, tentative), np.int64, len(tentative))
        owners = np.repeat(np.arange(len(records)), per_scan)
        rows = self._joined_rows(records, scans, owners, np.concatenate(tentative).astype(np.int64))
        found = rows >= 0
        return rows[found], np.bincount(owners[found], minlength=len(records))

    def _sizes(
        self, records: list[EventRecord], scans: _Scans, sized: IntArray
    ) -> tuple[IntArray, FloatArray, IntArray]:
        """The landmarks drawn at their objects' size at the scans ``sized`` (those with
        diameters): their joined rows, radii and count per scan.

        Each landmark's size is smoothed over the scans that measured it (not rejected),
        0.8 old + 0.2 new, and forgotten when the association removes it: one loop over
        these changes in scan order (a scan's measurements, then its removals), each
        kept; a scan's landmarks then take their last change at or before it, or the
        state before the batch.
        """
        value, known = self._size_value, self._size_known
        before_value = np.array(value, dtype=np.float64)
        before_known = np.array(known, dtype=bool)
        first = scans.first_measurement
        measured = ranges(first[sized], first[sized + 1])
        diameters = np.concatenate(
            [np.zeros(0), *(records[k].association.diameters for k in sized.tolist())]
        )
        kept = scans.fate[measured] != _REJECTED
        kept_scans = scans.owner[measured][kept]
        kept_ids = scans.landmark[measured][kept]
        # the lists' length at each scan, grown as each scan's largest id asks: a negative
        # id indexes from the end of the list as it was (numpy's and Python's indexing)
        bounds = [*np.searchsorted(kept_scans, sized).tolist(), len(kept_scans)]
        kept_list, length, lengths = kept_ids.tolist(), len(known), []
        for lo, hi in itertools.pairwise(bounds):
            if hi > lo:
                largest = max(kept_list[lo:hi])
                if largest >= length:
                    length = max(largest + 1, 2 * length, 64)
            lengths.append(length)
        if length > len(known):
            self._grow_sizes(length - 1)
        at_length = np.repeat(np.array(lengths, dtype=np.int64), np.diff(bounds))
        kept_ids = np.where(kept_ids < 0, kept_ids + at_length, kept_ids)
        removed = [records[k].association.removed for k in sized.tolist()]
        removed_ids = np.concatenate([np.zeros(0, dtype=np.int64), *removed]).astype(np.int64)
        removed_scans = np.repeat(sized, np.fromiter(map(len, removed), np.int64, len(removed)))
        valid = removed_ids >= 0
        removed_ids, removed_scans = removed_ids[valid], removed_scans[valid]
        # every change in order: by scan, a scan's measurements before its removals
        change_scan = np.concatenate([kept_scans, removed_scans])
        change_id = np.concatenate([kept_ids, removed_ids])
        change_known = np.concatenate(
            [np.ones(len(kept_ids), dtype=bool), np.zeros(len(removed_ids), dtype=bool)]
        )
        order = np.lexsort((~change_known, change_scan))  # stable within each
        change_scan, change_id, change_known = (
            change_scan[order],
            change_id[order],
            change_known[order],
        )
        sizes = np.zeros(len(order))
        sizes[: len(kept_ids)] = diameters[kept]
        change_value: list[float] = []
        for i, size, is_update in zip(
            change_id.tolist(), sizes[order].tolist(), change_known.tolist(), strict=True
        ):
            if is_update:
                size = 0.8 * value[i] + 0.2 * size if known[i] else size
                value[i] = size
                known[i] = True
            elif i < len(known):
                known[i] = False
            change_value.append(size)  # a removal's is never read
        # every landmark of every sized scan's map, and its state after that scan
        per_scan = scans.map_starts[sized + 1] - scans.map_starts[sized]
        rows = ranges(scans.map_starts[sized], scans.map_starts[sized + 1])
        ids = scans.landmark_ids[rows].astype(np.int64)
        has = np.zeros(len(ids), dtype=bool)
        radius = np.zeros(len(ids))
        before = (ids >= 0) & (ids < len(before_known))
        has[before] = before_known[ids[before]]
        radius[before] = before_value[ids[before]]
        if len(change_id):
            # the landmarks some change touched take the last at or before their scan
            touched = np.zeros(len(known), dtype=bool)
            touched[change_id] = True
            asked = np.flatnonzero((ids >= 0) & (ids < len(known)))
            asked = asked[touched[ids[asked]]]
            span = len(records) + 1
            keys = change_id * span + change_scan
            by_key = np.argsort(keys, kind="stable")  # the last of equal keys: the latest
            sorted_keys = keys[by_key]
            scan_of = np.repeat(sized, per_scan)[asked]
            at = np.searchsorted(sorted_keys, ids[asked] * span + scan_of, side="right") - 1
            valid = at >= 0
            valid[valid] = sorted_keys[at[valid]] // span == ids[asked][valid]
            latest = by_key[at[valid]]
            has[asked[valid]] = change_known[latest]
            radius[asked[valid]] = np.array(change_value, dtype=np.float64)[latest]
        radii = np.maximum(radius[has], 0.05) / 2
        # how many each scan has: its map's rows are consecutive
        taken = np.zeros(len(has) + 1, dtype=np.int64)
        np.cumsum(has, out=taken[1:])
        ends = np.cumsum(per_scan)
        counts = taken[ends] - taken[ends - per_scan]
        return rows[has], radii, counts

    def _send_series(self, *, everything: bool) -> None:
        """Send the series of every ``_SERIES_FLUSH`` scans held (all, with
        ``everything``), one column each."""
        while self._series.scans >= _SERIES_FLUSH or (everything and self._series.scans):
            for name, (steps, events, times, values) in self._series.take(_SERIES_FLUSH):
                indexes = [
                    rr.TimeColumn(style.STEP, sequence=steps),
                    rr.TimeColumn(style.EVENT, sequence=events),
                ]
                if np.isfinite(times).all():
                    indexes.append(arrow.time_column(times))
                self._rec.send_columns(
                    self._path(f"{SERIES}/{name}"),
                    indexes=indexes,
                    columns=rr.Scalars.columns(scalars=values),
                )


class _ScanSender:
    """Sends the columns of an entity for some of the scans held, on their step, event
    and (where the log has times: all or none, see :meth:`AssociationView._hold`) time."""

    def __init__(
        self,
        rec: rr.RecordingStream,
        path: Callable[[str], str],
        steps: IntArray,
        events: IntArray,
        times: FloatArray,
    ) -> None:
        self._rec, self._path = rec, path
        self._steps, self._events, self._times = steps, events, times
        self._timed = bool(np.isfinite(times).all())

    def __call__(self, entity: str, at: IntArray, columns: list[rr.ComponentColumn]) -> None:
        """``columns`` of ``entity`` at the scans ``at`` (indexes of the scans held)."""
        indexes = [
            rr.TimeColumn(style.STEP, sequence=self._steps[at]),
            rr.TimeColumn(style.EVENT, sequence=self._events[at]),
        ]
        if self._timed:
            indexes.append(arrow.rounded_time_column(self._times[at]))
        self._rec.send_columns(self._path(entity), indexes=indexes, columns=columns)


def _ray_columns(geometry: _Geometry, scans: _Scans) -> list[rr.ComponentColumn]:
    """Each scan's rays, sensor to measurement, coloured by the measurement's fate."""
    return [
        arrow.column(
            rr.LineStrips2D.descriptor_strips(), _strips(geometry.rays), geometry.rays_per_scan
        ),
        arrow.column(
            rr.LineStrips2D.descriptor_colors(),
            _colors(FATE_COLORS[scans.fate]),
            geometry.rays_per_scan,
        ),
    ]


def _tentative_columns(scans: _Scans, rows: IntArray, counts: IntArray) -> list[rr.ComponentColumn]:
    """Each scan's tentative landmarks (``rows`` of the scans' maps, ``counts`` a scan) as
    labelled orange crosses."""
    n = len(counts)
    ones = np.ones(n, dtype=np.int64)
    labels = [f"L{i} (tentative)" for i in scans.landmark_ids[rows].tolist()]
    return [
        arrow.column(rr.Points2D.descriptor_positions(),
                     arrow.xy(scans.landmarks_xy[rows].reshape(-1, 2)), counts),
        arrow.column(rr.Points2D.descriptor_radii(),
                     pa.array(np.full(n, -6.0, dtype=np.float32)), ones),
        arrow.column(rr.Points2D.descriptor_colors(),
                     _colors(np.repeat([TENTATIVE_COLOR], n, axis=0)), ones),
        arrow.column(rr.Points2D.descriptor_labels(), pa.array(labels, type=pa.utf8()), counts),
    ]  # fmt: skip


def _size_columns(
    scans: _Scans, rows: IntArray, radii: FloatArray, counts: IntArray
) -> list[rr.ComponentColumn]:
    """The landmarks of the scans with sizes (``rows`` of the scans' maps, ``counts`` a
    scan) drawn at their objects' radii."""
    return [
        arrow.column(rr.Points2D.descriptor_positions(),
                     arrow.xy(scans.landmarks_xy[rows].reshape(-1, 2)), counts),
        arrow.column(rr.Points2D.descriptor_radii(), pa.array(radii.astype(np.float32)), counts),
        arrow.column(rr.Points2D.descriptor_colors(),
                     _colors(np.repeat([style.LANDMARK_COLOR], len(counts), axis=0)),
                     np.ones(len(counts), dtype=np.int64)),
    ]  # fmt: skip


@dataclass(frozen=True, slots=True)
class _Scans:
    """The scans of a send joined: their measurements, maps and links.

    :param poses: (s, 3) the vehicle's pose at each scan
    :param z: (k, 2) each scan's measurements; ``fate``, ``owner`` and ``landmark``:
        (sum k,) every measurement's fate, scan and landmark id
    :param map_starts: (s + 1,) where each scan's map starts in ``landmarks_xy`` (joined)
        and ``landmark_ids``
    :param link_from: (l,) the measurements (joined indices) linked to a landmark, and
        ``link_to`` (l,) the joined rows of those landmarks
    :param gate_z: (g, 2) each scan's gates' predicted measurements, ``gate_covs``
        (g, 2, 2) their S
    """

    poses: FloatArray
    z: list[FloatArray]
    fate: IntArray
    owner: IntArray
    landmark: IntArray
    map_starts: IntArray
    landmarks_xy: FloatArray
    landmark_ids: IntArray
    link_from: IntArray
    link_to: IntArray
    links_per_scan: IntArray
    gate_z: list[FloatArray]
    gate_covs: list[FloatArray]
    gate_threshold: list[float]

    @property
    def first_measurement(self) -> IntArray:
        """(s + 1,) where each scan's measurements start among all."""
        starts = np.zeros(len(self.z) + 1, dtype=np.int64)
        np.cumsum(np.bincount(self.owner, minlength=len(self.z)), out=starts[1:])
        return starts


_NAMES = ("matched", "new", "rejected", "confirmed", "removed", "landmarks", "fell_back")
_SCORES = ("correct", "wrong", "missed")


def _scan_values(
    records: list[EventRecord], scans: _Scans, scores: list[ScanScore | None]
) -> dict[str, list[int]]:
    """The per-scan series' values of the scans (the scores' only where there is one)."""
    associations = [record.association for record in records]
    valid = (scans.fate >= 0) & (scans.fate < 3)  # Fate's values
    fates = np.bincount(
        scans.owner[valid] * 3 + scans.fate[valid], minlength=3 * len(records)
    ).reshape(-1, 3)
    matched, new, rejected = fates.T.tolist()
    values: dict[str, list[int]] = {
        "matched": matched,
        "new": new,
        "rejected": rejected,
        "confirmed": [len(a.confirmed) for a in associations],  # type: ignore[union-attr]
        "removed": [len(a.removed) for a in associations],  # type: ignore[union-attr]
        "landmarks": [
            record.n_landmarks - len(a.tentative)  # type: ignore[union-attr]
            for record, a in zip(records, associations, strict=True)
        ],
        # JCBB's budget ran out at this scan
        "fell_back": [int(a.exhausted) for a in associations],  # type: ignore[union-attr]
    }
    return values


def _texts(
    records: list[EventRecord], scans: _Scans, values: dict[str, list[int]]
) -> tuple[list[str], list[rr.TextLogLevel]]:
    """Each scan's line in the log: what the association chose, and its level."""
    texts, levels = [], []
    measured = np.bincount(scans.owner, minlength=len(records)).tolist()
    for k, record in enumerate(records):
        association = record.association
        assert association is not None
        text = (
            f"step {record.step} scan line {record.line}: {association.method}"
            f" matched {values['matched'][k]} of {measured[k]}, {values['new'][k]} new,"
            f" {values['rejected'][k]} rejected"
        )
        if association.method == "jcbb":
            text += f"; {association.hypotheses} hypotheses"
            if association.exhausted:
                text += f" (budget exhausted: fell back to {association.fallback or 'best found'})"
            text += f", joint NIS {association.joint_nis:.2f}"
        if len(association.confirmed) or len(association.removed):
            confirmed, removed = association.confirmed.tolist(), association.removed.tolist()
            text += f"; confirmed {confirmed}, removed {removed}"
        texts.append(text)
        levels.append(rr.TextLogLevel.WARN if association.exhausted else rr.TextLogLevel.DEBUG)
    return texts, levels


class _Series:
    """The per-scan series not sent yet: each series' rows, and how many scans they span
    (a series has a row per scan, the scores' only where a scan has one)."""

    def __init__(self) -> None:
        self.scans = 0
        # per series: (scan number, step, event, time, value) arrays, joined as they come
        self._rows: dict[str, list[FloatArray]] = {}
        self._first = 0  # the number of the first scan held

    def add(
        self,
        steps: IntArray,
        events: IntArray,
        times: FloatArray,
        values: dict[str, list[int]],
        scores: list[ScanScore | None],
    ) -> None:
        numbers = np.arange(self._first + self.scans, self._first + self.scans + len(steps))
        self.scans += len(steps)
        columns = (numbers, steps, events, times)
        for name in _NAMES:
            self._rows.setdefault(name, []).append(
                np.column_stack([*columns, np.array(values[name], dtype=np.float64)])
            )
        scored = [k for k, score in enumerate(scores) if score is not None]
        if scored:
            at = np.array(scored, dtype=np.int64)
            by_name = {
                "correct": [scores[k].correct for k in scored],  # type: ignore[union-attr]
                "wrong": [scores[k].wrong for k in scored],  # type: ignore[union-attr]
                "missed": [scores[k].missed for k in scored],  # type: ignore[union-attr]
            }
            for name in _SCORES:
                self._rows.setdefault(name, []).append(
                    np.column_stack(
                        [*(column[at] for column in columns), np.array(by_name[name], np.float64)]
                    )
                )

    def take(
        self, most: int
    ) -> list[tuple[str, tuple[IntArray, IntArray, FloatArray, FloatArray]]]:
        """The rows of the first ``most`` scans held, per series (steps, events, times,
        values); they are held no more."""
        end = self._first + most
        out = []
        for name, parts in self._rows.items():
            table = np.concatenate(parts) if parts else np.zeros((0, 5))
            cut = int(np.searchsorted(table[:, 0], end))
            if cut:
                rows = table[:cut]
                out.append(
                    (
                        name,
                        (
                            rows[:, 1].astype(np.int64),
                            rows[:, 2].astype(np.int64),
                            rows[:, 3],
                            rows[:, 4],
                        ),
                    )
                )
            self._rows[name] = [table[cut:]] if cut < len(table) else []
        taken = min(most, self.scans)
        self._first += taken
        self.scans -= taken
        return out


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


def _geometry(sensor: RangeBearing, scans: _Scans) -> _Geometry:
    """The rays, links and gates of the held scans, a few array operations for all.

    Each measurement and each gate's centre through the sensor's inverse model at its
    scan's pose; each gate's covariance mapped to the plane through that model's Jacobian
    (``l_D_z S l_D_z^T``); a link from its measurement's point to its landmark.
    """
    poses = scans.poses
    origins = np.array([sensor.sensor(pose)[:2] for pose in poses], dtype=np.float64)
    rays_per_scan = np.array([len(z) for z in scans.z], dtype=np.int64)
    gates_per_scan = np.array([len(z) for z in scans.gate_z], dtype=np.int64)
    z = np.concatenate([*scans.z, *scans.gate_z]).reshape(-1, 2)
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
    links = np.empty((len(scans.link_from), 2, 2))
    if len(links):
        links[:, 0] = ends[scans.link_from]
        links[:, 1] = scans.landmarks_xy[scans.link_to]
    gates = np.zeros((0, 2, 2))
    if len(z) > m:
        jacobians = l_D_z[m:]
        covs = jacobians @ np.concatenate(scans.gate_covs) @ jacobians.transpose(0, 2, 1)
        threshold = np.repeat(np.array(scans.gate_threshold, dtype=np.float64), gates_per_scan)
        values = np.unique(threshold)
        if len(values) == 1:
            gates = ellipse_outlines(ends[m:], covs, n_sigma=math.sqrt(float(values[0])))
        else:  # scans of several gates: each group at its own size
            gates = np.empty((len(covs), N_POINTS, 2))
            for value in values.tolist():
                at = np.flatnonzero(threshold == value)
                gates[at] = ellipse_outlines(ends[m:][at], covs[at], n_sigma=math.sqrt(value))
    return _Geometry(rays, rays_per_scan, links, scans.links_per_scan, gates, gates_per_scan)


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


def _dense_table(ids: IntArray) -> IntArray | None:
    """A table of a map's ids: by id, its row (-1: none); None where the ids are negative
    or too sparse for one (:func:`_rows_of` then)."""
    if len(ids) and int(ids.min()) >= 0 and int(ids.max()) < 4 * len(ids) + 1024:
        table: IntArray = np.full(int(ids.max()) + 1, -1, dtype=np.int64)
        table[ids] = np.arange(len(ids))
        return table
    return None


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
