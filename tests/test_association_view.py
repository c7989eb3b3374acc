"""The association view sends its scans in batches (issue 26.3): the recording holds the
same rows, at the same times, whatever the batch size, one per scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows
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
