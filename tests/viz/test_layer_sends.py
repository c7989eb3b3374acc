"""The recorder's sends, made in a few numpy calls for a whole batch of events, say
exactly what the plain definitions of one event at a time say: the text log's lines,
the landmark errors, the updates whose map is logged, the map's ellipses and first
sightings; on random batches of every kind of event, and against known answers read back
from a recording."""

from __future__ import annotations

import math
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import rerun as rr
from conftest import entity_rows

from ekfviz.core.batch import INIT, PREDICT, UPDATE, BatchBuilder, EventBatch, Extras, StateParts
from ekfviz.core.records import EventKind, EventRecord, Observations, ScanAssociation
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import Recorder, style
from ekfviz.viz.ellipses import ellipse_outlines, ellipse_shape_columns, ellipse_shapes
from ekfviz.viz.layers.batch import Batch, Maps, landmark_rows
from ekfviz.viz.layers.canvas import Clock
from ekfviz.viz.layers.landmarks import INITIAL_POINTS, MAP_POINTS, MAP_TOLERANCE, MapLayer
from ekfviz.viz.layers.map_rows import IdRows, joined_rows, root_norms
from ekfviz.viz.layers.text import TextLayer


def seeds(count: int, fast: int) -> list[Any]:
    """The seeds ``0 .. count - 1``, those from ``fast`` on under ``-m slow``."""
    return [pytest.param(seed, marks=pytest.mark.slow) if seed >= fast else seed
            for seed in range(count)]  # fmt: skip


def random_covs(rng: np.random.Generator, n: int) -> FloatArray:
    roots = rng.normal(size=(n, 2, 2)) * 10.0 ** rng.integers(-4, 2, size=(n, 1, 1))
    covs: FloatArray = roots @ np.swapaxes(roots, 1, 2)
    return covs


def parts(rng: np.random.Generator, ids: IntArray) -> StateParts:
    """A state of the map ``ids`` (an array a batch may keep)."""
    n = len(ids)
    return StateParts(
        rng.normal(size=3), np.eye(3) * 0.1, ids, rng.normal(size=(n, 2)) * 10,
        random_covs(rng, n),
    )  # fmt: skip


def observations(rng: np.random.Generator, pool: IntArray, most: int) -> Observations:
    """Random observations of ids of ``pool``: NIS sometimes not used, some new, some
    skipped."""
    seen = rng.choice(pool, size=min(int(rng.integers(0, most)), len(pool)), replace=False)
    m = len(seen)
    nis = rng.uniform(0, 9, m)
    nis[rng.random(m) < 0.3] = math.nan
    z = rng.normal(size=(m, 2))
    return Observations.of(
        ids=seen.astype(np.int64), z=z, z_pred=z, innovation=z * 0,
        S=np.tile(np.eye(2), (m, 1, 1)), nis=nis, initialised=rng.random(m) < 0.3,
        skipped=rng.random(m) < 0.1,
    )  # fmt: skip


def random_batch(seed: int) -> Batch:
    """A batch of an initialisation, predicts and updates in some order (steps with and
    without both), warnings, maps that grow."""
    rng = np.random.default_rng(seed)
    builder = BatchBuilder()
    ids = np.arange(1, 5, dtype=np.int64)
    state = parts(rng, ids)
    whole = [True]
    builder.add(state, event=0, step=0, kind=INIT, observations=observations(rng, ids, 4))
    step, kind = 0, INIT
    for event in range(1, int(rng.integers(6, 61))):
        line = int(rng.choice([0, event + 1, 10**6 + event]))
        warnings = tuple(f"warning {j}" for j in range(int(rng.choice([0, 0, 0, 1, 2]))))
        extras = Extras(warnings) if warnings else None
        if rng.random() < 0.45:  # a predict: a new step, the map of the event before
            step, kind = step + 1, PREDICT
            control = None if rng.random() < 0.2 else (float(rng.normal()), 0.3 * rng.normal())
            if control is not None and rng.random() < 0.1:
                control = (-0.0, control[1])  # a signed zero prints as "-0.000"
            state = state._replace(pose=rng.normal(size=3))
            builder.add(state, event=event, step=step, kind=PREDICT, line=line,
                        control=control, extras=extras)  # fmt: skip
            whole.append(False)
            continue
        if kind is not PREDICT:  # an update: a step of its own after an update
            step += 1
        kind = UPDATE
        if rng.random() < 0.2:
            ids = np.arange(1, len(ids) + 2, dtype=np.int64)  # the map grew
        state = parts(rng, ids)
        found = None if rng.random() < 0.1 else observations(rng, ids, 4)
        builder.add(state, event=event, step=step, kind=UPDATE, line=line,
                    observations=found, extras=extras)  # fmt: skip
        whole.append(bool(rng.random() < 0.5))
    return Batch.of(builder.build(), np.array(whole), Clock())


# -- the text log ---------------------------------------------------------------------------


def describe(record: EventRecord, seen: int, new: int, nis: float, nis_used: int) -> str:
    """One event's part of a line, by the definition."""
    where = f"step {record.step} {record.kind.value}"
    if record.line:
        where += f" line {record.line}"
    if record.kind is EventKind.PREDICT:
        control = record.control
        if control is None:
            return where
        return f"{where}: d {control[0]:.3f}, alpha {control[1]:.4f}"
    if record.observations is None:
        return f"{where}: {record.n_landmarks} landmarks in the map"
    text = f"{where}: {seen} landmarks"
    if new:
        text += f" ({new} new)"
    if nis_used:
        text += f", NIS {nis:.2f}"
    return text


def reference_lines(batch: Batch) -> list[tuple[int, str, str]]:
    """(row, text, level) of the text log of a batch, an event at a time."""
    records, observed = list(batch.events), batch.observed
    out: list[tuple[int, str, str]] = []
    held: tuple[str, tuple[str, ...]] | None = None
    for k, record in enumerate(records):
        line = describe(
            record, int(observed.seen[k]), int(observed.new[k]), float(observed.nis_sum[k]),
            int(observed.nis_used[k]),
        )  # fmt: skip
        warnings = record.warnings
        following = records[k + 1] if k + 1 < len(records) else None
        if (
            record.kind is EventKind.PREDICT
            and following is not None
            and following.kind is EventKind.UPDATE
            and following.step == record.step
        ):
            held = (line, warnings)
            continue
        if held is not None:
            line = f"{held[0]}; {line.split(' ', 2)[2]}"
            warnings = held[1] + warnings
            held = None
        out.append((k, line, "INFO"))
        out += [(k, f"step {record.step} line {record.line}: {w}", "WARN") for w in warnings]
    return out


class _Sent:
    """A canvas that keeps what is sent to it."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, Any, Any]] = []

    def send(self, entity: str, times: Any, columns: Any) -> None:
        self.sent.append((entity, times, columns))


def sent_lines(batch: Batch) -> list[tuple[int, str, str]]:
    canvas = _Sent()
    TextLayer(canvas).send(batch)  # type: ignore[arg-type]
    ((entity, times, (text, level)),) = canvas.sent
    assert entity == style.LOG
    events = times[1].as_arrow_array().to_pylist()
    at = np.searchsorted(batch.rows.events, events).tolist()
    texts, levels = (c.as_arrow_array().to_pylist() for c in (text, level))  # a value a row
    return [(k, t, v) for k, [t], [v] in zip(at, texts, levels, strict=True)]


@pytest.mark.parametrize("seed", range(40))
def test_the_text_log_of_a_batch_is_each_events_lines(seed: int) -> None:
    batch = random_batch(seed)
    assert sent_lines(batch) == reference_lines(batch)


def test_the_random_batches_hold_every_kind_of_line() -> None:
    """The batches above meet every variant of a line (else the test proves little)."""
    lines = [text for seed in range(40) for _, text, _ in reference_lines(random_batch(seed))]
    for piece in (
        "; update line", "; update: ", "predict line", "predict: d", " (", "new), NIS",
        "landmarks in the map", "step 0 init", "d -0.000", ": warning 1",
    ):  # fmt: skip
        assert any(piece in line for line in lines), piece
    assert any(re.fullmatch(r"step \d+ predict( line \d+)?", line) for line in lines)
    assert any(re.fullmatch(r"step \d+ update( line \d+)?: \d+ landmarks", line) for line in lines)


def test_a_steps_line_read_back_from_a_recording(tmp_path: Path) -> None:
    """Known answers: a predict's line joins its update's, at the update's event."""
    out = tmp_path / "lines.rrd"
    rec = rr.RecordingStream("lines")
    rec.save(out)
    recorder = Recorder(rec, blueprint=False)
    x: FloatArray = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 2.0, 0.5])
    P: FloatArray = np.eye(7) * 0.01
    z = np.array([[0.7, 1.4], [0.2, 2.1]])
    recorder.initialise(x[:5], P[:5, :5], landmark_ids=[7], z=z[:1], line=1)
    recorder.predict(x[:5], P[:5, :5], control=(0.1, 0.01), line=2)
    S = np.tile(np.eye(2) * 0.5, (2, 1, 1))
    z_pred = z - [[0.5, 0.5], [0.0, 0.0]]
    recorder.update(x, P, landmark_ids=[7, 9], z=z, z_pred=z_pred, S=S, line=3)
    recorder.predict(x, P, control=(1.23456, -0.00005), line=4)
    recorder.finish()
    rec.disconnect()
    lines = [(row["event"], row["TextLog:text"]) for row in entity_rows(out, f"/{style.LOG}")]
    assert lines == [
        (0, ["step 0 init line 1: 1 landmarks (1 new)"]),
        (2, ["step 1 predict line 2: d 0.100, alpha 0.0100; "
             "update line 3: 2 landmarks (1 new), NIS 1.00"]),
        (3, ["step 2 predict line 4: d 1.235, alpha -0.0001"]),
    ]  # fmt: skip


# -- the landmark errors --------------------------------------------------------------------


class _Series:
    """A series buffer that keeps every value given, by path, in order."""

    def __init__(self) -> None:
        self.values: dict[str, list[tuple[int, int, float, float | None]]] = {}

    def add(self, path: str, step: int, event: int, value: float, time: float | None) -> None:
        self.extend(path, [step], [event], [value], [math.nan if time is None else time])

    def extend(
        self, path: str, steps: list[int], events: list[int], values: list[float],
        times: list[float],
    ) -> None:  # fmt: skip
        # (a NaN time as None: NaN equals nothing, itself included)
        kept = [None if math.isnan(time) else time for time in times]
        self.values.setdefault(path, []).extend(zip(steps, events, values, kept, strict=True))


@pytest.mark.parametrize("seed", range(30))
def test_the_landmark_errors_of_a_batch_are_each_updates(seed: int) -> None:
    """The errors against the true landmarks sent for a batch at once are, value for
    value, what each update's own (``log_landmark_errors``) were: the whole map's, or
    the observed landmarks', a mean and worst of the whole map's known ones (summed in
    numpy's order, in pairs from 8 landmarks on), none of a landmark the truth lacks."""
    from ekfviz.core.truth import GroundTruth
    from ekfviz.viz.layers.truth import TruthLayer

    batch = random_batch(seed)
    rng = np.random.default_rng(seed + 1000)
    known = np.array([i for i in range(1, 13) if rng.random() < 0.8], dtype=np.int64)
    truth = GroundTruth(ids=known, landmarks_xy=rng.normal(size=(len(known), 2)))

    class Canvas:
        def __init__(self) -> None:
            self.truth, self.series = truth, _Series()

    at_once, one_by_one = Canvas(), Canvas()
    TruthLayer(at_once).send_landmark_errors(batch)  # type: ignore[arg-type]
    reference = TruthLayer(one_by_one)  # type: ignore[arg-type]
    for k in batch.corrected.tolist():
        which = None if batch.whole[k] else "observed"
        reference.log_landmark_errors(batch.events.event(k), which, False)
    assert at_once.series.values == one_by_one.series.values
    assert any("summary" in path for path in at_once.series.values)


def test_the_random_batches_hold_maps_numpy_sums_in_pairs() -> None:
    """Some maps of the batches above have 8 landmarks or more (numpy's sums go in pairs)."""
    assert max(int(random_batch(seed).maps.counts.max()) for seed in range(30)) >= 8


# -- the updates whose map is logged --------------------------------------------------------


def test_the_shapes_of_a_batch_are_each_maps_shapes() -> None:
    """The map's shapes are taken for a whole batch at once: each landmark's are the
    ones of its own map alone, to the bit (the updates logged do not depend on it)."""
    rng = np.random.default_rng(3)
    maps = [rng.normal(size=(n, 2, 2)) for n in (1, 6, 6, 40)]
    covs = [c @ np.swapaxes(c, 1, 2) * 0.01 for c in maps]
    means = [rng.normal(size=(len(c), 2)) for c in covs]
    joined = ellipse_shapes(np.concatenate(means), np.concatenate(covs))
    alone = np.concatenate([ellipse_shapes(m, c) for m, c in zip(means, covs, strict=True)])
    assert joined.tobytes() == alone.tobytes()
    by_map = np.linalg.norm(joined[:, 2:].reshape(-1, 1, 4), axis=2).reshape(-1)
    assert np.linalg.norm(joined[:, 2:], axis=1).tobytes() == by_map.tobytes()


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


def test_the_norms_of_the_maps_window_search_are_numpys() -> None:
    """The window search sums the squares a row per entry: numpy's norms to the bit."""
    rng = np.random.default_rng(5)
    for shape in ((1, 1, 6), (16, 6, 6), (300, 40, 6), (7, 1000, 6)):
        ahead = rng.normal(size=shape) * 10.0 ** rng.integers(-12, 3, size=shape)
        by_row = np.moveaxis(ahead * ahead, 2, 0)  # (6, w, n): a row per entry
        for part, rows in ((ahead[:, :, :2], by_row[:2]), (ahead[:, :, 2:], by_row[2:])):
            assert root_norms(rows).tobytes() == np.linalg.norm(part, axis=2).tobytes()
        flat = ahead.reshape(-1, 6)[:, 2:]  # the tolerances' norms: (K, 4) rows
        assert (
            root_norms(np.ascontiguousarray((flat * flat).T)).tobytes()
            == np.linalg.norm(flat, axis=1).tobytes()
        )


def reference_changes(
    records: list[EventRecord], forced: list[bool], shown: tuple[Any, FloatArray] | None
) -> list[int]:
    """The updates whose map is logged, by the definition, one update at a time: forced,
    a map of other landmarks than the last shown, or some landmark moved by more than
    MAP_TOLERANCE of its ellipse's semi-major axis since."""
    out = []
    for i, record in enumerate(records):
        every = ellipse_shapes(record.landmarks_xy, record.landmark_covs)
        due = forced[i] or shown is None or not np.array_equal(shown[0], record.landmark_ids)
        if not due:
            assert shown is not None
            tolerance = MAP_TOLERANCE * np.linalg.norm(every[:, 2:], axis=1) / math.sqrt(2.0)
            moved = np.linalg.norm(every[:, :2] - shown[1][:, :2], axis=1) + np.linalg.norm(
                every[:, 2:] - shown[1][:, 2:], axis=1
            )
            due = not np.all(moved <= tolerance)
        if due:
            out.append(i)
            shown = (record.landmark_ids, every)
    return out


@pytest.mark.parametrize("seed", seeds(12, fast=4))
def test_the_updates_whose_map_is_logged_are_the_definitions(seed: int) -> None:
    """The map's window search finds the very updates the plain definition does, across
    batches, with maps that grow, drift, jump and hold still."""
    rng = np.random.default_rng(seed)
    layer = MapLayer(SimpleNamespace(detail=False), None, thinned=False)  # type: ignore[arg-type]
    ids = np.arange(1, 4, dtype=np.int64)
    xy, covs = rng.normal(size=(3, 2)) * 10, np.tile(np.eye(2) * 0.04, (3, 1, 1))
    shown: tuple[Any, FloatArray] | None = None
    event = 0
    for _ in range(4):  # batches
        builder, whole, forced = BatchBuilder(), [], []
        for _ in range(int(rng.integers(1, 400))):
            event += 1
            if rng.random() < 0.01:  # the map grows
                ids = np.arange(1, len(ids) + 2, dtype=np.int64)
                xy = np.vstack([xy, rng.normal(size=(1, 2)) * 10])
                covs = np.concatenate([covs, np.eye(2)[None] * 0.04])
            pace = 10.0 ** rng.choice([-6.0, -4.0, -3.0, -1.0])  # still to jumping
            xy = xy + rng.normal(size=xy.shape) * pace
            covs = covs * (1.0 - rng.uniform(0, pace, size=(len(covs), 1, 1)))
            state = StateParts(np.zeros(3), np.eye(3), ids, xy.copy(), covs.copy())
            builder.add(state, event=event, step=event, kind=UPDATE)
            whole.append(bool(rng.random() < 0.02))
            forced.append(whole[-1] and len(ids) > 32)  # none here: a small map
        batch = Batch.of(builder.build(), np.array(whole), Clock())
        expected = reference_changes(list(batch.events), forced, shown)
        sparse = np.zeros(len(batch.events), dtype=bool)
        assert layer._map_changes(batch, sparse).tolist() == expected
        last = batch.events.event(expected[-1])
        shown = (last.landmark_ids, ellipse_shapes(last.landmarks_xy, last.landmark_covs))
    assert event > 0


# -- the map's rows and ellipses ------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
def test_ranges_are_the_ranges_joined(seed: int) -> None:
    from ekfviz.core.batch import ranges

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


def random_updates(rng: np.random.Generator, count: int, scans: bool = False) -> EventBatch:
    """Updates of maps that grow, shrink and change ids, some sharing one ids array as
    a filter's do, with observations of ids in and out of the map; with ``scans``, each
    confirms or removes some ids seen new before (the association's decisions)."""
    builder = BatchBuilder()
    ids = np.arange(40, dtype=np.int64)
    new_ids: list[int] = []
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
        found = None
        if rng.random() < 0.9:
            pool = np.concatenate([ids, rng.integers(-5, 2 * len(ids) + 10, size=3)])
            found = observations(rng, pool, 12)
            new_ids += found.ids[found.initialised].tolist()
        extras = None
        if scans:
            picked = rng.choice(new_ids, size=min(len(new_ids), 3)).tolist() if new_ids else []
            half = len(picked) // 2
            extras = Extras(association=association(picked[:half], picked[half:]))
        builder.add(parts(rng, ids), event=event, step=event, kind=UPDATE, line=event,
                    observations=found, extras=extras)  # fmt: skip
    return builder.build()


def association(confirmed: list[int], removed: list[int]) -> ScanAssociation:
    nothing = np.zeros(0, dtype=np.int64)
    return ScanAssociation(
        method="nn", z=np.zeros((0, 2)), fate=np.zeros(0, dtype=np.int8), landmark=nothing,
        gate_ids=nothing, gate_z=np.zeros((0, 2)), gate_S=np.zeros((0, 2, 2)),
        gate_threshold=9.21, hypotheses=0, joint_nis=0.0, exhausted=False, tentative=nothing,
        confirmed=np.array(confirmed, dtype=np.int64), removed=np.array(removed, dtype=np.int64),
    )  # fmt: skip


@pytest.mark.parametrize("seed", seeds(8, fast=3))
@pytest.mark.parametrize("which", ["observed", "initialised"])
def test_the_joined_rows_are_each_updates_landmark_rows(seed: int, which: str) -> None:
    rng = np.random.default_rng(seed)
    events = random_updates(rng, 300)
    maps = Maps.of(events, events.corrected)
    picks = np.flatnonzero(rng.random(len(events)) < 0.7)
    tables: dict[int, Any] = {}
    joined, counts = joined_rows(maps, picks, which, tables)
    expected = [maps.starts[i] + landmark_rows(events.event(i), which) for i in picks.tolist()]
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


def reference_sends(
    batches: list[Batch], shown_of: list[list[int]]
) -> dict[str, list[tuple[list[int], FloatArray, list[int], list[int]]]]:
    """The observed ellipses and the confirmed first sightings of each batch, an update
    at a time."""
    out: dict[str, list[tuple[list[int], FloatArray, list[int], list[int]]]] = {}
    sightings: dict[int, tuple[FloatArray, FloatArray]] = {}
    for batch, shown in zip(batches, shown_of, strict=True):
        records = list(batch.events)
        whole = batch.whole.tolist()
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


@pytest.mark.parametrize("seed", seeds(6, fast=2))
def test_the_maps_sends_are_each_updates(seed: int) -> None:
    """Batches of large maps with observations and scans: the whole maps' ellipses, the
    observed landmarks' and the first sightings confirmed are sent as an update at a
    time sent them, to the bit."""
    rng = np.random.default_rng(100 + seed)
    events = random_updates(rng, 600, scans=True)
    layer = MapLayer(StripsCanvas(), SimpleNamespace(send=lambda *a: None), thinned=False)  # type: ignore[arg-type]
    canvas = layer._canvas
    assert isinstance(canvas, StripsCanvas)
    cuts = np.sort(rng.choice(np.arange(1, len(events)), size=3, replace=False)).tolist()
    batches, shown_of = [], []
    for lo, hi in zip([0, *cuts], [*cuts, len(events)], strict=True):
        part = events[lo:hi]
        batch = Batch.of(part, rng.random(len(part)) < 0.1, Clock())
        sparse = layer._sparse_maps(batch)
        before = (layer._map_shown, layer._map_shown_event)
        shown_of.append(layer._map_changes(batch, sparse).tolist())
        layer._map_shown, layer._map_shown_event = before  # send finds them again
        layer.send(batch)
        batches.append(batch)
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
