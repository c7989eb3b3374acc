"""The association view sends its scans in batches (issue 26.3): the recording holds the
same rows, at the same times, whatever the batch size, one per scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
from hypothesis import given, settings
from hypothesis import strategies as st
from test_victoria import make_park
from typer.testing import CliRunner

import ekfviz.viz.association as view
from ekfviz.cli import app

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
    rows = view._ScanRows()
    Scan = tuple[tuple[float, float, float], list[list[float]], list[int], list[list[float]], float]
    scans: list[Scan] = [
        ((1.0, 2.0, 0.3), [[0.1, 10.0], [-0.4, 7.0]], [1], [[4.0, 9.0]], 9.21),
        ((-3.0, 5.0, -2.9), [[1.2, 4.0]], [0], [[0.5, 1.0]], 13.8),
    ]
    for pose, z, link_from, link_to, threshold in scans:
        rows.poses.append(pose)
        rows.z.append(np.array(z))
        rows.fates.append(np.zeros(len(z), dtype=np.int64))
        rows.link_from.append(np.array(link_from))
        rows.link_to.append(np.array(link_to))
        rows.gate_z.append(np.array(z) + 0.05)  # a gate near each measurement
        rows.gate_covs.append(np.tile([[0.01, 0.002], [0.002, 0.3]], (len(z), 1, 1)))
        rows.gate_threshold.append(threshold)
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
            cov = l_D_z @ rows.gate_covs[k][i] @ l_D_z.T
            outline = ellipse_outlines(centre[None], cov[None], n_sigma=np.sqrt(threshold))[0]
            assert np.allclose(geometry.gates[gate + i], outline, rtol=0, atol=1e-9)
        start = sensor.inverse(np.array(pose), np.array(z[link_from[0]]))
        assert np.allclose(geometry.links[k], np.array([start, link_to[0]]), rtol=0, atol=1e-12)
        ray += len(z)
        gate += len(z)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.integers(-5, 3000), unique=True, max_size=60),
    st.lists(st.lists(st.integers(-10, 3100), max_size=12), min_size=1, max_size=4),
    st.booleans(),
)
def test_the_row_lookup_finds_what_a_search_finds(
    ids: list[int], asks: list[list[int]], same_array: bool
) -> None:
    """Kept per ids array (dense, sparse, negative ids alike) and rebuilt for another."""
    from ekfviz.viz.association import _RowLookup, _rows_of

    lookup = _RowLookup()
    shared = np.array(ids, dtype=np.int64)
    for wanted in asks:
        array = shared if same_array else np.array(ids, dtype=np.int64)
        got = lookup.rows(array, np.array(wanted, dtype=np.int64))
        expected = _rows_of(array, np.array(wanted, dtype=np.int64))
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == np.int64
        for k, landmark in enumerate(wanted):  # and what a row means
            assert got[k] == (ids.index(landmark) if landmark in ids else -1)
