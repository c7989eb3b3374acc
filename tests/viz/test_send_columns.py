"""The recorder's sends built from columns say exactly what a record at a time said.

The text log's lines and the map's logged updates are made in a few numpy calls a batch
(see ``ekfviz.viz.layers.text`` and ``landmarks``); these tests hold them to the plain
per-record definitions they replaced, on batches of every kind of event, and to known
answers read back from a recording.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
from conftest import entity_rows

from ekfviz.core.records import EventKind, EventRecord, EventRows, Observations
from ekfviz.core.types import FloatArray
from ekfviz.viz import Recorder, style
from ekfviz.viz.ellipses import ellipse_shapes
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Clock
from ekfviz.viz.layers.text import TextLayer

# -- the per-record definitions (the text layer's before its lines were made in columns) --


def describe(record: EventRecord, seen: int, new: int, nis: float, nis_used: int) -> str:
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


def describe_predict(step: int, line: int, control: tuple[float, float]) -> str:
    where = f"step {step} predict line {line}" if line else f"step {step} predict"
    return f"{where}: d {control[0]:.3f}, alpha {control[1]:.4f}"


def reference_lines(batch: Batch) -> list[tuple[int, str, str]]:
    """(row, text, level) of the text log of a batch, a record at a time."""
    records, observed = batch.records, batch.observed
    steps = batch.rows.steps.tolist()
    out: list[tuple[int, str, str]] = []
    held: tuple[str, tuple[str, ...]] | None = None
    for k, record in enumerate(records):
        if record is None:
            control = (float(batch.controls[k, 0]), float(batch.controls[k, 1]))
            line = describe_predict(steps[k], int(batch.lines[k]), control)
            warnings: tuple[str, ...] = ()
        else:
            line = describe(
                record,
                int(observed.seen[k]),
                int(observed.new[k]),
                float(observed.nis_sum[k]),
                int(observed.nis_used[k]),
            )
            warnings = record.warnings
        following = records[k + 1] if k + 1 < len(records) else None
        if (
            bool(batch.is_predict[k])
            and following is not None
            and following.kind is EventKind.UPDATE
            and steps[k + 1] == steps[k]
        ):
            held = (line, warnings)
            continue
        if held is not None:
            line = f"{held[0]}; {line.split(' ', 2)[2]}"
            warnings = held[1] + warnings
            held = None
        out.append((k, line, "INFO"))
        for warning in warnings:
            assert record is not None
            out.append((k, f"step {record.step} line {record.line}: {warning}", "WARN"))
    return out


# -- random batches of every kind of event ---------------------------------------------------


def _record(
    rng: np.random.Generator,
    kind: EventKind,
    event: int,
    step: int,
    ids: Any,
    *,
    observations: bool = True,
) -> EventRecord:
    n = len(ids)
    covs = np.tile(np.eye(2) * 0.01, (n, 1, 1)) + rng.uniform(0, 1e-3, (n, 1, 1)) * np.eye(2)
    common: dict[str, Any] = {
        "event": event,
        "step": step,
        "kind": kind,
        "line": int(rng.choice([0, event + 1, 10**6 + event])),
        "pose": rng.normal(size=3),
        "pose_cov": np.eye(3) * 0.1,
        "landmark_ids": ids,
        "landmarks_xy": rng.normal(size=(n, 2)) * 10,
        "landmark_covs": covs,
        "warnings": tuple(f"warning {j}" for j in range(int(rng.choice([0, 0, 0, 1, 2])))),
    }
    if kind is EventKind.PREDICT:
        control = None if rng.random() < 0.2 else rng.normal(size=2) * [1.0, 0.3]
        if control is not None and rng.random() < 0.1:
            control[0] = -0.0  # a signed zero prints as "-0.000"
        return EventRecord(**common, control=control)
    if not observations or rng.random() < 0.1:
        return EventRecord(**common)
    m = int(rng.integers(0, 4))
    seen = rng.choice(ids, size=min(m, n), replace=False) if n else np.zeros(0, np.int64)
    m = len(seen)
    nis = rng.uniform(0, 9, m)
    nis[rng.random(m) < 0.3] = math.nan
    z = rng.normal(size=(m, 2))
    S = np.tile(np.eye(2), (m, 1, 1))
    return EventRecord(
        **common,
        observations=Observations(
            ids=seen.astype(np.int64), z=z, z_pred=z, innovation=z * 0, S=S, nis=nis,
            initialised=rng.random(m) < 0.3, skipped=rng.random(m) < 0.1,
        ),
    )  # fmt: skip


def random_batch(seed: int) -> Batch:
    """A batch of inits, predicts (records and rows) and updates in some order, steps
    with and without both."""
    rng = np.random.default_rng(seed)
    pending: list[tuple[EventRecord, bool]] = []
    rows = EventRows(8)
    ids = np.arange(1, 5, dtype=np.int64)
    step = 0
    pending.append((_record(rng, EventKind.INIT, 0, 0, ids), True))
    for event in range(1, int(rng.integers(6, 61))):
        choice = rng.random()
        if choice < 0.45:  # a predict: a new step
            step += 1
            if rng.random() < 0.6:
                control = (float(rng.normal()), float(rng.normal()) * 0.3)
                line = int(rng.choice([0, event + 1]))
                rows.add(event, step, line, None, control, rng.normal(size=3), np.eye(3))
            else:
                pending.append((_record(rng, EventKind.PREDICT, event, step, ids), False))
        else:  # an update: a step of its own after an update, else the predict's
            if pending[-1][0].kind is not EventKind.PREDICT and (
                not len(rows) or rows.events[-1] != event - 1
            ):
                step += 1
            if rng.random() < 0.2:
                ids = np.arange(1, len(ids) + 2, dtype=np.int64)  # the map grew
            record = _record(rng, EventKind.UPDATE, event, step, ids)
            pending.append((record, bool(rng.random() < 0.5)))
    return Batch.of(pending, Clock(), rows, len(rows))


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
def test_the_text_log_of_a_batch_is_its_records_lines(seed: int) -> None:
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


# -- the map's changes ----------------------------------------------------------------------


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


def test_the_norms_of_the_maps_window_search_are_numpys() -> None:
    """The window search sums the squares a row per entry: numpy's norms to the bit."""
    from ekfviz.viz.layers.map_rows import root_norms as _root_norms

    rng = np.random.default_rng(5)
    for shape in ((1, 1, 6), (16, 6, 6), (300, 40, 6), (7, 1000, 6)):
        ahead = rng.normal(size=shape) * 10.0 ** rng.integers(-12, 3, size=shape)
        by_row = np.moveaxis(ahead * ahead, 2, 0)  # (6, w, n): a row per entry
        for part, rows in ((ahead[:, :, :2], by_row[:2]), (ahead[:, :, 2:], by_row[2:])):
            assert _root_norms(rows).tobytes() == np.linalg.norm(part, axis=2).tobytes()
        flat = ahead.reshape(-1, 6)[:, 2:]  # the tolerances' norms: (K, 4) rows
        assert (
            _root_norms(np.ascontiguousarray((flat * flat).T)).tobytes()
            == np.linalg.norm(flat, axis=1).tobytes()
        )


def reference_changes(
    records: list[EventRecord], forced: list[bool], shown: tuple[Any, FloatArray] | None
) -> list[int]:
    """The updates whose map is logged, by the definition, one update at a time: forced,
    a map of other landmarks than the last shown, or some landmark moved by more than
    MAP_TOLERANCE of its ellipse's semi-major axis since."""
    from ekfviz.viz.layers.landmarks import MAP_TOLERANCE

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


@pytest.mark.parametrize("seed", range(12))
def test_the_updates_whose_map_is_logged_are_the_definitions(seed: int) -> None:
    """The map's window search finds the very updates the plain definition does, across
    batches, with maps that grow, drift, jump and hold still."""
    from types import SimpleNamespace

    from ekfviz.viz.layers.landmarks import MapLayer

    rng = np.random.default_rng(seed)
    layer = MapLayer(SimpleNamespace(detail=False), None, thinned=False)  # type: ignore[arg-type]
    ids = np.arange(1, 4, dtype=np.int64)
    xy, covs = rng.normal(size=(3, 2)) * 10, np.tile(np.eye(2) * 0.04, (3, 1, 1))
    shown: tuple[Any, FloatArray] | None = None
    event = 0
    for _ in range(4):  # batches
        pending, forced = [], []
        for _ in range(int(rng.integers(1, 400))):
            event += 1
            if rng.random() < 0.01:  # the map grows
                ids = np.arange(1, len(ids) + 2, dtype=np.int64)
                xy = np.vstack([xy, rng.normal(size=(1, 2)) * 10])
                covs = np.concatenate([covs, np.eye(2)[None] * 0.04])
            pace = 10.0 ** rng.choice([-6.0, -4.0, -3.0, -1.0])  # still to jumping
            xy = xy + rng.normal(size=xy.shape) * pace
            covs = covs * (1.0 - rng.uniform(0, pace, size=(len(covs), 1, 1)))
            record = EventRecord(
                event=event, step=event, kind=EventKind.UPDATE, line=0, pose=np.zeros(3),
                pose_cov=np.eye(3), landmark_ids=ids, landmarks_xy=xy.copy(),
                landmark_covs=covs.copy(),
            )  # fmt: skip
            whole = bool(rng.random() < 0.02)
            pending.append((record, whole))
            forced.append(whole and len(ids) > 32)  # none here: a small map
        batch = Batch.of(pending, Clock())
        expected = reference_changes([r for r, _ in pending], forced, shown)
        sparse = np.zeros(len(pending), dtype=bool)
        assert layer._map_changes(batch, sparse).tolist() == expected
        last = pending[expected[-1]][0]
        shown = (last.landmark_ids, ellipse_shapes(last.landmarks_xy, last.landmark_covs))
    assert event > 0


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
        record = batch.records[k]
        assert record is not None
        reference.log_landmark_errors(record, None if batch.whole[k] else "observed", False)
    assert at_once.series.values == one_by_one.series.values
    assert any("summary" in path for path in at_once.series.values)


def test_the_random_batches_hold_maps_numpy_sums_in_pairs() -> None:
    """Some maps of the batches above have 8 landmarks or more (numpy's sums go in pairs)."""
    assert max(int(random_batch(seed).maps.counts.max()) for seed in range(30)) >= 8
