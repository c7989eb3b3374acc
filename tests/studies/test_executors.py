"""Executors of studies: local processes and a Dask cluster on loopback give the same
results as one process, in the items' order, with every result reported once."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.studies.executors import (
    DaskExecutor,
    ExecutorError,
    LocalExecutor,
    make_executor,
)

runner = CliRunner()


def square_of(k: int) -> int:
    return k * k


def test_local_executor_keeps_the_order_and_reports_every_result() -> None:
    seen: list[int] = []
    items = list(range(12))
    assert LocalExecutor(workers=2).map(square_of, items, done=seen.append) == [
        k * k for k in items
    ]
    assert sorted(seen) == [k * k for k in items]
    assert LocalExecutor(workers=1).map(square_of, items) == [k * k for k in items]


def test_make_executor_refuses_what_cannot_run() -> None:
    with pytest.raises(ExecutorError, match="needs --scheduler"):
        make_executor("dask")
    with pytest.raises(ExecutorError, match="is for --executor dask"):
        make_executor("local", "tcp://127.0.0.1:8786")
    assert isinstance(make_executor("dask", "tcp://127.0.0.1:8786"), DaskExecutor)
    with pytest.raises(ExecutorError, match="--workers is for --executor local"):
        make_executor("dask", "tcp://127.0.0.1:8786", workers=4)  # dropped without a word


def test_an_absent_scheduler_is_a_one_line_error() -> None:
    with pytest.raises(ExecutorError, match="cannot reach a Dask scheduler") as error:
        DaskExecutor("tcp://127.0.0.1:9", timeout_s=1.0).map(square_of, [1])
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("address", ["tls://127.0.0.1:9", "workerless"])
def test_a_scheduler_without_workers_or_its_tls_context_is_a_one_line_error(
    address: str,
) -> None:
    """A scheduler with no worker held the study for ever without a word; a TLS address
    without its context was a TypeError traceback after a minute."""
    from distributed import LocalCluster

    if address != "workerless":
        with pytest.raises(ExecutorError, match="cannot reach a Dask scheduler") as error:
            DaskExecutor(address, timeout_s=1.0).map(square_of, [1])
        assert "\n" not in str(error.value)
        return
    with (
        LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=0, processes=True, host="127.0.0.1", dashboard_address=None
        ) as cluster,
        pytest.raises(ExecutorError, match="the Dask scheduler has no workers"),
    ):
        DaskExecutor(str(cluster.scheduler_address), timeout_s=1.0).map(square_of, [1])


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """A Dask scheduler and two worker processes on loopback."""
    from distributed import LocalCluster

    with LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        yield str(cluster.scheduler_address)


def report_of(tmp_path: Path, name: str, *args: str) -> dict[str, object]:
    report = tmp_path / f"{name}.json"
    result = runner.invoke(app, [*args, "--report", str(report)])
    assert result.exit_code == 0, result.output
    document: dict[str, object] = json.loads(report.read_text())
    return document


def untimed(document: dict[str, object], key: str) -> list[dict[str, object]]:
    """The rows of a study's report without their wall times, the one thing that differs."""
    rows = document[key]
    assert isinstance(rows, list)
    return [{k: v for k, v in row.items() if k not in ("seconds", "ms_per_step")} for row in rows]


@pytest.mark.slow
def test_consistency_on_a_dask_cluster_equals_the_local_run(tmp_path: Path, scheduler: str) -> None:
    args = ["consistency", "--scenario", "classic", "--runs", "6", "--seed", "4"]
    local = report_of(tmp_path, "local", *args, "--workers", "2")
    dask = report_of(tmp_path, "dask", *args, "--executor", "dask", "--scheduler", scheduler)
    assert dask["nees"] == local["nees"] and dask["verdict"] == local["verdict"]
    assert dask["mean_nees"] == local["mean_nees"] and dask["nis"] == local["nis"]


def test_sweep_on_a_dask_cluster_equals_the_local_run(tmp_path: Path, scheduler: str) -> None:
    data = Path(__file__).parents[2] / "data"
    args = [
        "sweep", str(data / "classic.txt"), "--truth", str(data / "classic_truth.json"),
        "--vary", "sigma_x=x10,/10",
    ]  # fmt: skip

    local = report_of(tmp_path, "local", *args, "--save", str(tmp_path / "l.rrd"))
    dask = report_of(
        tmp_path, "dask", *args, "--save", str(tmp_path / "d.rrd"),
        "--executor", "dask", "--scheduler", scheduler,
    )  # fmt: skip
    assert len(untimed(local, "variants")) == 3
    assert untimed(dask, "variants") == untimed(local, "variants")


@pytest.mark.slow
def test_compare_on_a_dask_cluster_equals_the_local_run(tmp_path: Path, scheduler: str) -> None:
    root = Path(__file__).parents[2]
    args = [
        "compare", str(root / "data" / "classic.txt"), "--filter", "ekf", "--filter",
        f"{root / 'tests' / 'plugins' / 'textbook.py'}:Textbook",
    ]  # fmt: skip

    local = report_of(tmp_path, "local", *args, "--save", str(tmp_path / "l.rrd"))
    dask = report_of(
        tmp_path, "dask", *args, "--save", str(tmp_path / "d.rrd"),
        "--executor", "dask", "--scheduler", scheduler,
    )  # fmt: skip
    assert [row["label"] for row in untimed(dask, "filters")] == ["ekf", "Textbook"]
    assert untimed(dask, "filters") == untimed(local, "filters")


def test_dask_without_a_scheduler_is_a_one_line_error() -> None:
    result = runner.invoke(app, ["consistency", "--runs", "2", "--executor", "dask"])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and "--scheduler" in result.output
