"""The map's sends made for a whole batch at once say exactly what an update at a time said.

``MapLayer.send`` finds the rows of every update's observed and new landmarks in the
batch's joined maps in a few numpy calls a map, and the window search reads the shapes a
row per quantity (see ``ekfviz.viz.layers.landmarks``); these tests hold them to the plain
per-update definitions (``landmark_rows``, ``ellipse_shapes``, ``np.linalg.norm``) on
random batches: maps that grow and shrink, ids sparse, negative or repeated, updates
without observations, ids observed twice or not in the map.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from ekfviz.core.records import EventKind, EventRecord, Observations, ScanAssociation
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.ellipses import ellipse_outlines, ellipse_shape_columns, ellipse_shapes
from ekfviz.viz.layers.batch import Batch, Maps, landmark_rows
from ekfviz.viz.layers.canvas import Clock
from ekfviz.viz.layers.landmarks import INITIAL_POINTS, MAP_POINTS, MapLayer
from ekfviz.viz.layers.map_rows import IdRows, joined_rows, ranges


def random_covs(rng: np.random.Generator, n: int) -> FloatArray:
    roots = rng.normal(size=(n, 2, 2)) * 10.0 ** rng.integers(-4, 2, size=(n, 1, 1))
    covs: FloatArray = roots @ np.swapaxes(roots, 1, 2)
    return covs


def test_the_shape_columns_are_the_shapes_transposed_to_the_bit() -> None:
    rng = np.random.default_rng(11)
    covs = random_covs(rng, 500)
    covs[:5] = 0.0  # no extent
    covs[5] = [[1.0, 1.0], [1.0, 1.0]]  # flat: det 0 (or a round-off below)
    covs[6] = [[4.0, -2.0], [-2.0, 1.0 + 1e-17]]
    covs[7, 0, 1] = covs[7, 1, 0] = -0.0
    covs[8] = np.nan  # stays NaN where the rows have NaN
    means = rng.normal(size=(500, 2)) * 100
    with np.errstate(invalid="ignore"):  # the NaN covariance's determinant
        rows = ellipse_shapes(means, covs)
        columns = ellipse_shape_columns(means, covs)
    assert columns.shape == (6, 500)
    assert np.ascontiguousarray(columns.T).tobytes() == rows.tobytes()
    assert ellipse_shape_columns(np.zeros((0, 2)), np.zeros((0, 2, 2))).shape == (6, 0)


@pytest.mark.parametrize("seed", range(4))
def test_ranges_are_the_ranges_joined(seed: int) -> None:
    rng = np.random.default_rng(seed)
    starts = np.sort(rng.integers(0, 1000, size=int(rng.integers(0, 30))))
    ends = starts + rng.integers(0, 5, size=len(starts))
    expected = [k for a, b in zip(starts.tolist(), ends.tolist(), strict=True) for k in range(a, b)]
    assert ranges(starts, ends).tolist() == expected


def test_an_id_lookup_is_the_rows_of_its_ids() -> None:
    for ids in ([3, 1, 2], [5, -7, 10**9, 0], [], [4]):
        table = IdRows.of(np.array(ids, dtype=np.int64))
        assert table is not None
        wanted = np.array([*ids, -1, 6, 10**9 + 1, *ids[:1]], dtype=np.int64)
        expected = [ids.index(i) if i in ids else -1 for i in wanted.tolist()]
        assert table.rows(wanted).tolist() == expected
    assert IdRows.of(np.array([2, 1, 2])) is None  # not a map's ids: no lookup
    assert IdRows.of(np.array([10**9, -1, 10**9])) is None


def random_updates(rng: np.random.Generator, count: int) -> list[EventRecord]:
    """Updates of maps that grow, shrink and change ids, some sharing one ids array as
    the filter's records do, with observations of ids in and out of the map."""
    records: list[EventRecord] = []
    ids = np.arange(40, dtype=np.int64)
    for event in range(1, count + 1):
        change = rng.random()
        if change < 0.1:  # grows
            ids = np.concatenate([ids, [int(ids.max(initial=0)) + 1 + int(rng.integers(0, 3))]])
        elif change < 0.15 and len(ids) > 1:  # a landmark removed
            ids = np.delete(ids, int(rng.integers(0, len(ids))))
        elif change < 0.17:  # ids far apart or negative: a sorted search, not a table
            ids = rng.choice(np.arange(-50, 10**6), size=int(rng.integers(0, 60)), replace=False)
        elif change < 0.19:  # the same ids in a new array
            ids = ids.copy()
        elif change < 0.2:  # repeated ids: the per-update definition
            ids = np.concatenate([ids, ids[:2]])
        n = len(ids)
        observations = None
        if rng.random() < 0.9:
            pool = np.concatenate([ids, rng.integers(-5, 2 * n + 10, size=3)])
            seen = rng.choice(pool, size=int(rng.integers(0, 12))) if len(pool) else pool
            m = len(seen)
            nan2 = np.full((m, 2), np.nan)
            observations = Observations(
                ids=seen.astype(np.int64), z=rng.normal(size=(m, 2)), z_pred=nan2,
                innovation=nan2, S=np.full((m, 2, 2), np.nan), nis=np.full(m, np.nan),
                initialised=rng.random(m) < 0.3, skipped=np.zeros(m, dtype=bool),
            )  # fmt: skip
        record = EventRecord(
            event=event, step=event, kind=EventKind.UPDATE, line=event,
            pose=np.zeros(3), pose_cov=np.eye(3), landmark_ids=ids,
            landmarks_xy=rng.normal(size=(n, 2)) * 10, landmark_covs=random_covs(rng, n),
            observations=observations,
        )  # fmt: skip
        records.append(record)
    return records


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("which", ["observed", "initialised"])
def test_thejoined_rows_are_each_updates_landmark_rows(seed: int, which: str) -> None:
    rng = np.random.default_rng(seed)
    records = random_updates(rng, 300)
    maps = Maps.of_records(records)
    picks = np.flatnonzero(rng.random(len(records)) < 0.7)
    tables: dict[int, Any] = {}
    joined, counts = joined_rows(maps, picks, which, tables)
    expected = [maps.starts[i] + landmark_rows(records[i], which) for i in picks.tolist()]
    assert counts.tolist() == [len(rows) for rows in expected]
    assert joined.tolist() == np.concatenate([np.zeros(0, np.int64), *expected]).tolist()
    again, _ = joined_rows(maps, picks, which, tables)  # the lookups kept: the same rows
    assert again.tolist() == joined.tolist()
    none, no_counts = joined_rows(maps, picks[:0], which, {})
    assert none.tolist() == [] and no_counts.tolist() == []


class StripsCanvas:
    """A canvas that keeps what is sent as line strips (and drops the rest)."""

    def __init__(self) -> None:
        self.detail = False
        self.strips: dict[str, list[tuple[list[int], FloatArray, list[int], list[int]]]] = {}

    def send(self, *args: object) -> None:
        pass

    def identify(self, *args: object) -> None:
        return None

    def grow_bounds(self, xy: FloatArray) -> None:
        pass

    def send_strips(
        self,
        entity: str,
        rows: object,
        at: IntArray,
        polylines: FloatArray,
        counts: IntArray,
        ids: IntArray,
    ) -> None:
        self.strips.setdefault(entity, []).append(
            (at.tolist(), polylines, counts.tolist(), ids.tolist())
        )


def association(confirmed: list[int], removed: list[int]) -> ScanAssociation:
    nothing = np.zeros(0, dtype=np.int64)
    return ScanAssociation(
        method="nn", z=np.zeros((0, 2)), fate=np.zeros(0, dtype=np.int8), landmark=nothing,
        gate_ids=nothing, gate_z=np.zeros((0, 2)), gate_S=np.zeros((0, 2, 2)),
        gate_threshold=9.21, hypotheses=0, joint_nis=0.0, exhausted=False, tentative=nothing,
        confirmed=np.array(confirmed, dtype=np.int64), removed=np.array(removed, dtype=np.int64),
    )  # fmt: skip


def with_associations(rng: np.random.Generator, records: list[EventRecord]) -> list[EventRecord]:
    """The updates as scans: each confirms or removes some ids seen new before."""
    out, new_ids = [], []
    for record in records:
        observations = record.observations
        if observations is not None:
            new_ids += observations.ids[observations.initialised].tolist()
        picked = rng.choice(new_ids, size=min(len(new_ids), 3)).tolist() if new_ids else []
        half = len(picked) // 2
        out.append(replace(record, association=association(picked[:half], picked[half:])))
    return out


def reference_sends(
    batches: list[list[tuple[EventRecord, bool]]], shown_of: list[list[int]]
) -> dict[str, list[tuple[list[int], FloatArray, list[int], list[int]]]]:
    """The observed ellipses and the confirmed first sightings of each batch, an update
    at a time (the layer's code before it worked on the joined maps)."""
    out: dict[str, list[tuple[list[int], FloatArray, list[int], list[int]]]] = {}
    sightings: dict[int, tuple[FloatArray, FloatArray]] = {}
    for pending, shown in zip(batches, shown_of, strict=True):
        records = [record for record, _ in pending]
        whole = [is_whole for _, is_whole in pending]
        picked = [np.zeros(0, np.int64) if whole[i] else landmark_rows(r, "observed")
                  for i, r in enumerate(records)]  # fmt: skip
        for entity, at, rows in (
            (style.LANDMARK_ELLIPSES, [i for i in shown if whole[i]], None),
            # beyond a small map (SMALL_MAP = 32 landmarks)
            (
                style.LANDMARK_ELLIPSES_OBSERVED,
                [i for i, r in enumerate(records) if r.n_landmarks > 32],
                picked,
            ),
        ):
            if not at:
                continue
            chosen = [np.arange(records[i].n_landmarks) if rows is None else rows[i] for i in at]
            counts = [len(c) for c in chosen]
            means = np.concatenate(
                [records[i].landmarks_xy[c] for i, c in zip(at, chosen, strict=True)]
            )
            covs = np.concatenate(
                [records[i].landmark_covs[c] for i, c in zip(at, chosen, strict=True)]
            )
            ids = np.concatenate(
                [records[i].landmark_ids[c] for i, c in zip(at, chosen, strict=True)]
            )
            n_points = max(16, min(MAP_POINTS, 16384 // max(max(counts), 1)))
            outlines = ellipse_outlines(means, covs, n_points=n_points)
            out.setdefault(entity, []).append((at, outlines, counts, ids.tolist()))
        at, means_of, covs_of, ids_of = [], [], [], []
        for k, record in enumerate(records):
            assert record.association is not None
            if record.observations is not None and record.observations.initialised.any():
                for row in landmark_rows(record, "initialised").tolist():
                    sightings[int(record.landmark_ids[row])] = (
                        record.landmarks_xy[row], record.landmark_covs[row]
                    )  # fmt: skip
            for i in record.association.removed.tolist():
                sightings.pop(i, None)
            confirmed = [(i, sightings.pop(i)) for i in record.association.confirmed.tolist()
                         if i in sightings]  # fmt: skip
            if confirmed:
                at.append(k)
                ids_of.append([i for i, _ in confirmed])
                means_of += [mean for _, (mean, _) in confirmed]
                covs_of += [cov for _, (_, cov) in confirmed]
        if at:
            counts = [len(group) for group in ids_of]
            n_points = max(16, min(INITIAL_POINTS, 16384 // max(counts)))
            outlines = ellipse_outlines(np.array(means_of), np.array(covs_of), n_points=n_points)
            flat = [i for group in ids_of for i in group]
            out.setdefault(style.LANDMARK_INITIAL, []).append((at, outlines, counts, flat))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_the_maps_sends_are_each_updates(seed: int) -> None:
    """Batches of large maps with observations and scans: the whole maps' ellipses, the
    observed landmarks' and the first sightings confirmed are sent as an update at a
    time sent them, to the bit."""
    rng = np.random.default_rng(100 + seed)
    records = with_associations(rng, random_updates(rng, 600))
    layer = MapLayer(StripsCanvas(), SimpleNamespace(send=lambda *a: None), thinned=False)  # type: ignore[arg-type]
    canvas = layer._canvas
    assert isinstance(canvas, StripsCanvas)
    cuts = np.sort(rng.choice(np.arange(1, len(records)), size=3, replace=False)).tolist()
    batches, shown_of = [], []
    for lo, hi in zip([0, *cuts], [*cuts, len(records)], strict=True):
        pending = [(record, bool(rng.random() < 0.1)) for record in records[lo:hi]]
        batch = Batch.of(pending, Clock())
        sparse = layer._sparse_maps(batch)
        before = (layer._map_shown, layer._map_shown_event)
        shown_of.append(layer._map_changes(batch, sparse).tolist())
        layer._map_shown, layer._map_shown_event = before  # send finds them again
        layer.send(batch)
        batches.append(pending)
    expected = reference_sends(batches, shown_of)
    assert (
        set(canvas.strips)
        == set(expected)
        == {
            style.LANDMARK_ELLIPSES,
            style.LANDMARK_ELLIPSES_OBSERVED,
            style.LANDMARK_INITIAL,
        }
    )
    for entity, sends in expected.items():
        got = canvas.strips[entity]
        assert len(got) == len(sends), entity
        for (at, outlines, counts, ids), (at2, outlines2, counts2, ids2) in zip(
            sends, got, strict=True
        ):
            assert (at, counts, ids) == (at2, counts2, ids2), entity
            assert outlines.tobytes() == outlines2.tobytes(), entity
