"""The association view sends its scans in batches: the recording holds the
same rows, at the same times, whatever the batch size, one per scan."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import entity_rows
from hypothesis import given, settings
from hypothesis import strategies as st
from parks import make_park
from typer.testing import CliRunner

import ekfviz.viz.association as view
from ekfviz.cli import app
from ekfviz.core.records import EventKind, EventRecord, Fate, ScanAssociation

runner = CliRunner()
ENTITIES = (
    "/world/association/rays",
    "/world/association/links",
    "/world/association/gates",
    "/world/landmarks/tentative",
    "/world/landmarks/sizes",
    "/log",
)


@pytest.fixture(scope="module")
def park(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("view") / "VictoriaPark"
    folder.mkdir()
    make_park(folder, seed=1, seconds=40.0)  # 200 scans
    return folder


def _replay(park: Path, rrd: Path, every: int, monkeypatch: pytest.MonkeyPatch) -> None:
    with monkeypatch.context() as patched:
        patched.setattr(view, "SCANS_EVERY", every)
        done = runner.invoke(app, ["replay", str(park), "--save", str(rrd)])
    assert done.exit_code == 0, done.output


def _nanos(path: Path, entity: str) -> list[int]:
    """The ``time`` of every row of an entity, in nanoseconds, in row order."""
    import pyarrow as pa  # type: ignore[import-untyped]
    from rerun.chunk import RrdReader

    times: list[int] = []
    for chunk in RrdReader(path).stream().filter(content=entity, is_static=False):
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            times += batch.column("time").cast(pa.int64()).to_pylist()
    return sorted(times)


@pytest.mark.slow
def test_batches_of_any_size_record_the_same_rows(
    park: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    small, whole = tmp_path / "small.rrd", tmp_path / "whole.rrd"
    _replay(park, small, 7, monkeypatch)  # 200 scans: 28 sends and a rest at the end
    _replay(park, whole, 10**6, monkeypatch)  # one send at the end
    scan_times = np.unique(np.loadtxt(park / "measurements.dat")[:, 0])
    for entity in ENTITIES:
        rows = entity_rows(small, entity)
        # the same rows (the log's at one event, the recorder's and the view's, in any order)
        assert sorted(map(repr, rows)) == sorted(map(repr, entity_rows(whole, entity))), entity
        if entity == "/log":
            rows = [row for row in rows if "scan line" in str(row["TextLog:text"])]
        # one row a scan, each at its own step
        assert len(rows) == len(scan_times), entity
        assert len({row["step"] for row in rows}) == len(rows), entity
    rays = entity_rows(small, "/world/association/rays")
    matched = entity_rows(small, "/metrics/association/matched")
    links = entity_rows(small, "/world/association/links")
    for ray, count, link in zip(rays, matched, links, strict=True):
        colors = ray["LineStrips2D:colors"]
        assert isinstance(colors, list) and len(colors) == len(ray["LineStrips2D:strips"])  # type: ignore[arg-type]
        green = int.from_bytes(bytes([*view.FATE_COLORS[0], 255]), "big")
        n_matched = count["Scalars:scalars"][0]  # type: ignore[index]
        assert colors.count(green) == n_matched
        assert len(link["LineStrips2D:strips"]) == n_matched  # type: ignore[arg-type]
    sizes = entity_rows(small, "/world/landmarks/sizes")
    assert max(len(row["Points2D:positions"]) for row in sizes) > 10  # type: ignore[arg-type]
    # each row at its scan's time to the nanosecond, as logging it alone put it (1000.025
    # s is 1000024999999 ns if truncated)
    expected = [round(float(t) * 1e9) for t in scan_times]
    for entity in ENTITIES[:-1]:
        assert _nanos(small, entity) == expected, entity


def test_a_batchs_geometry_is_each_scans_through_the_inverse_model() -> None:
    """The rays, links and gates of two buffered scans (the second's gates at another
    threshold), computed for the batch at once, against each scan's own: the sensor's
    inverse model at its pose, and the gates' ellipses of l_D_z S l_D_z^T."""
    from ekfviz.models.range_bearing import RangeBearing
    from ekfviz.viz.ellipses import ellipse_outlines

    sensor = RangeBearing(3.78, 0.5)
    Scan = tuple[tuple[float, float, float], list[list[float]], list[int], list[list[float]], float]
    scans: list[Scan] = [
        ((1.0, 2.0, 0.3), [[0.1, 10.0], [-0.4, 7.0]], [1], [[4.0, 9.0]], 9.21),
        ((-3.0, 5.0, -2.9), [[1.2, 4.0]], [0], [[0.5, 1.0]], 13.8),
    ]
    # the scans joined: each link from its measurement (among all) to its landmark's row
    firsts = np.cumsum([0] + [len(z) for _, z, _, _, _ in scans])
    gate_covs = [np.tile([[0.01, 0.002], [0.002, 0.3]], (len(z), 1, 1)) for _, z, _, _, _ in scans]
    rows = view._Scans(
        poses=np.array([pose for pose, _, _, _, _ in scans]),
        z=[np.array(z) for _, z, _, _, _ in scans],
        fate=np.zeros(int(firsts[-1]), dtype=np.int64),
        owner=np.repeat(np.arange(len(scans)), np.diff(firsts)),
        landmark=np.zeros(int(firsts[-1]), dtype=np.int64),
        map_starts=np.arange(len(scans) + 1),
        landmarks_xy=np.array([xy for _, _, _, link_to, _ in scans for xy in link_to]),
        landmark_ids=np.arange(len(scans)),
        link_from=np.array([firsts[k] + i for k, scan in enumerate(scans) for i in scan[2]]),
        link_to=np.arange(len(scans)),
        links_per_scan=np.ones(len(scans), dtype=np.int64),
        gate_z=[np.array(z) + 0.05 for _, z, _, _, _ in scans],  # a gate near each measurement
        gate_covs=gate_covs,
        gate_threshold=[threshold for *_, threshold in scans],
    )
    geometry = view._geometry(sensor, rows)
    assert geometry.rays_per_scan.tolist() == [2, 1] and geometry.gates_per_scan.tolist() == [2, 1]
    assert geometry.links_per_scan.tolist() == [1, 1]
    ray, gate = 0, 0
    for k, (pose, z, link_from, link_to, threshold) in enumerate(scans):
        origin = sensor.sensor(np.array(pose))[:2]
        for i, zi in enumerate(z):
            point = sensor.inverse(np.array(pose), np.array(zi))
            assert np.allclose(
                geometry.rays[ray + i], np.array([origin, point]), rtol=0, atol=1e-12
            )
            centre = sensor.inverse(np.array(pose), np.array(zi) + 0.05)
            _, l_D_z = sensor.inverse_jacobians(np.array(pose), np.array(zi) + 0.05)
            cov = l_D_z @ gate_covs[k][i] @ l_D_z.T
            outline = ellipse_outlines(centre[None], cov[None], n_sigma=np.sqrt(threshold))[0]
            assert np.allclose(geometry.gates[gate + i], outline, rtol=0, atol=1e-9)
        start = sensor.inverse(np.array(pose), np.array(z[link_from[0]]))
        assert np.allclose(geometry.links[k], np.array([start, link_to[0]]), rtol=0, atol=1e-12)
        ray += len(z)
        gate += len(z)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.integers(-5, 3000), unique=True, max_size=60),
    st.lists(st.integers(-10, 3100), max_size=12),
)
def test_the_id_table_finds_what_a_search_finds(ids: list[int], wanted: list[int]) -> None:
    """A map's table (dense, where ids are small and non-negative) and the sorted search
    agree, and say what a row is."""
    from ekfviz.viz.association import _dense_table, _rows_of

    array = np.array(ids, dtype=np.int64)
    asked = np.array(wanted, dtype=np.int64)
    expected = _rows_of(array, asked)
    assert expected.dtype == np.int64
    assert expected.tolist() == [ids.index(i) if i in ids else -1 for i in wanted]
    table = _dense_table(array)
    if table is not None:
        assert min(ids) >= 0
        inside = (asked >= 0) & (asked < len(table))
        got = np.full(len(asked), -1, dtype=np.int64)
        got[inside] = table[asked[inside]]
        np.testing.assert_array_equal(got, expected)


# -- the held scans joined against each scan's own (the view's code when it logged a scan
# at a time) ---------------------------------------------------------------------------------


def random_scans(seed: int, count: int) -> list[EventRecord]:
    """Scans whose maps grow and change (consecutive ones sharing an ids array, as the
    filter's do), with matched, new and rejected measurements, tentative landmarks, sizes
    (at most scans) and removals, ids sparse or missing from the map at times."""
    rng = np.random.default_rng(seed)
    ids = np.arange(20, dtype=np.int64)
    records = []
    for k in range(count):
        if rng.random() < 0.2:  # a new map: grown, thinned, or far apart ids
            grown = np.concatenate([ids, ids.max(initial=0) + 1 + np.arange(rng.integers(0, 4))])
            ids = rng.permutation(grown)[: max(1, len(grown) - int(rng.integers(0, 3)))]
            if rng.random() < 0.1:
                ids = rng.choice(10**6, size=len(ids), replace=False).astype(np.int64)
        m = int(rng.integers(0, 9))
        fate = rng.integers(0, 3, size=m).astype(np.int8)
        pool = np.concatenate([ids, [10**7, 3 * len(ids) + 5]])  # some not in the map
        landmark = np.where(fate == Fate.REJECTED, -1, rng.choice(pool, size=m))
        tentative = rng.choice(pool, size=int(rng.integers(0, 4)), replace=False)
        removed = rng.choice(np.concatenate([pool, [-3]]), size=int(rng.integers(0, 3)))
        nothing = np.zeros(0, dtype=np.int64)
        association = ScanAssociation(
            method="jcbb", z=rng.uniform(0.1, 20, size=(m, 2)), fate=fate, landmark=landmark,
            gate_ids=nothing, gate_z=np.zeros((0, 2)), gate_S=np.zeros((0, 2, 2)),
            gate_threshold=9.21, hypotheses=int(rng.integers(0, 50)), joint_nis=1.5,
            exhausted=bool(rng.random() < 0.1), tentative=tentative, confirmed=nothing,
            removed=removed.astype(np.int64),
            diameters=rng.uniform(0.05, 1.0, size=m) if rng.random() < 0.8 else None,
        )  # fmt: skip
        records.append(
            EventRecord(
                event=2 * k + 1,
                step=k + 1,
                kind=EventKind.UPDATE,
                line=k + 2,
                pose=rng.normal(size=3),
                pose_cov=np.eye(3),
                landmark_ids=ids,
                landmarks_xy=rng.normal(size=(len(ids), 2)) * 10,
                landmark_covs=np.tile(np.eye(2), (len(ids), 1, 1)),
                association=association,
            )
        )
    return records


def reference_scans(records: list[EventRecord]) -> list[dict[str, Any]]:
    """Each scan's links, tentative landmarks and sizes, a scan at a time."""
    value, known = np.zeros(0), np.zeros(0, dtype=bool)
    out = []
    for record in records:
        association = record.association
        assert association is not None
        ids = record.landmark_ids
        fate = association.fate.astype(np.int64)
        matched = np.flatnonzero(fate == Fate.MATCHED)
        rows = view._rows_of(ids, association.landmark[matched])
        tentative = view._rows_of(ids, association.tentative)
        tentative = tentative[tentative >= 0]
        scan: dict[str, Any] = {
            "link_from": matched[rows >= 0].tolist(),
            "link_to": record.landmarks_xy[rows[rows >= 0]].tolist(),
            "tentative": record.landmarks_xy[tentative].tolist(),
            "labels": [f"L{i} (tentative)" for i in ids[tentative].tolist()],
        }
        if association.diameters is not None:
            kept = fate != Fate.REJECTED
            largest = int(association.landmark[kept].max(initial=-1))
            if largest >= len(known):
                grown = max(largest + 1, 2 * len(known), 64)
                value = np.concatenate([value, np.zeros(grown - len(value))])
                known = np.concatenate([known, np.zeros(grown - len(known), dtype=bool)])
            for i, size in zip(
                association.landmark[kept].tolist(),
                association.diameters[kept].tolist(),
                strict=True,
            ):
                value[i] = 0.8 * value[i] + 0.2 * size if known[i] else size
                known[i] = True
            removed = association.removed
            known[removed[(removed >= 0) & (removed < len(known))]] = False
            inside = (ids >= 0) & (ids < len(known))
            has = np.zeros(len(ids), dtype=bool)
            has[inside] = known[ids[inside]]
            picked = np.flatnonzero(has)
            scan["sizes"] = record.landmarks_xy[picked].tolist()
            scan["radii"] = (np.maximum(value[ids[picked]], 0.05) / 2).tolist()
        out.append(scan)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8))
def test_the_held_scans_joined_are_each_scans_own(seed: int) -> None:
    """Links, tentative landmarks and the smoothed sizes of batches of scans, found for
    each batch at once, against each scan's own (sizes carried from batch to batch)."""
    from ekfviz.models.range_bearing import RangeBearing

    records = random_scans(seed, 400)
    expected = reference_scans(records)
    own = view.AssociationView(_NoStream(), str, RangeBearing(), None)  # type: ignore[arg-type]
    got: list[dict[str, Any]] = []
    for lo in range(0, len(records), 37):
        batch = records[lo : lo + 37]
        scans = own._scans(batch)
        first = scans.first_measurement
        links = np.cumsum([0, *scans.links_per_scan.tolist()])
        tentative, per_scan = own._tentative(batch, scans)
        ends = np.cumsum([0, *per_scan.tolist()])
        sized = np.array(
            [k for k, r in enumerate(batch) if r.association.diameters is not None],  # type: ignore[union-attr]
            dtype=np.int64,
        )
        size_rows, radii, counts = own._sizes(batch, scans, sized)
        size_ends = np.cumsum([0, *counts.tolist()])
        for k in range(len(batch)):
            rows = tentative[ends[k] : ends[k + 1]]
            scan: dict[str, Any] = {
                "link_from": (scans.link_from[links[k] : links[k + 1]] - first[k]).tolist(),
                "link_to": scans.landmarks_xy[scans.link_to[links[k] : links[k + 1]]].tolist(),
                "tentative": scans.landmarks_xy[rows].tolist(),
                "labels": [f"L{i} (tentative)" for i in scans.landmark_ids[rows].tolist()],
            }
            if k in sized:
                n = int(np.searchsorted(sized, k))
                picked = size_rows[size_ends[n] : size_ends[n + 1]]
                scan["sizes"] = scans.landmarks_xy[picked].tolist()
                scan["radii"] = radii[size_ends[n] : size_ends[n + 1]].tolist()
            got.append(scan)
    assert got == expected
    assert sum(len(scan.get("radii", [])) for scan in expected) > 100  # sizes were drawn
    assert sum(len(scan["link_from"]) for scan in expected) > 100


class _NoStream:
    """A recording stream that drops what it is given."""

    def log(self, *args: object, **kwargs: object) -> None:
        pass
