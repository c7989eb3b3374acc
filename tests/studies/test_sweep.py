"""Parameter sweeps: parsing, variants, equality with a plain replay, the recording."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.params import FilterParams
from ekfviz.studies.sweep import Change, SweepError, build_variants, parse_vary, tuning_preset

DATA = Path(__file__).parents[2] / "data"
SAMPLE, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
runner = CliRunner()


def test_parse_vary_reads_absolute_values_and_factors() -> None:
    assert parse_vary("sigma-x=x10,/10,0.5,*2") == [
        Change("sigma_x", "x", 10.0),
        Change("sigma_x", "/", 10.0),
        Change("sigma_x", "", 0.5),
        Change("sigma_x", "x", 2.0),
    ]
    assert [c.apply(0.25) for c in parse_vary("sigma_x=x10,/10,0.5")] == [2.5, 0.025, 0.5]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("sigma_x", "--vary sigma_x: expected NAME=V1,V2"),
        ("sigma_q=x10", "--vary sigma_q=x10: unknown parameter 'sigma_q'"),
        ("sigma_x=x10,y3", "--vary sigma_x=x10,y3: found 'y3', expected a number"),
        ("sigma_x=/0", "--vary sigma_x=/0: '/0' is not a usable value"),
    ],
)
def test_parse_errors_name_the_option(text: str, message: str) -> None:
    with pytest.raises(SweepError, match="^" + message.replace("(", r"\(").replace("*", r"\*")):
        parse_vary(text)


def test_grid_and_one_at_a_time() -> None:
    varies = [parse_vary("sigma_x=x2,x3"), parse_vary("sigma_range=/2")]
    grid = build_variants(FilterParams(), varies, one_at_a_time=False)
    single = build_variants(FilterParams(), varies, one_at_a_time=True)
    assert [v.label for v in grid] == [
        "baseline", "sigma_x x2, sigma_range /2", "sigma_x x3, sigma_range /2",
    ]  # fmt: skip
    assert [v.label for v in single] == ["baseline", "sigma_x x2", "sigma_x x3", "sigma_range /2"]
    assert grid[2].params.sigma_x == pytest.approx(0.75) and grid[2].params.sigma_range == 0.04
    preset = tuning_preset(FilterParams())
    assert len(preset) == 11 and preset[0].label == "baseline"
    assert len({v.key for v in preset}) == 11 and all("/" not in v.key for v in preset)


def test_cli_error_names_the_option(tmp_path: Path) -> None:
    result = runner.invoke(app, ["sweep", str(SAMPLE), "--vary", "sigma_x=x1O",
                                 "--save", str(tmp_path / "s.rrd")])  # fmt: skip
    assert result.exit_code == 2
    assert "--vary sigma_x=x1O: found 'x1O'" in result.output
    assert not (tmp_path / "s.rrd").exists()


def test_sweep_baseline_equals_replay_and_holds_every_variant(tmp_path: Path) -> None:
    rrd, report, replay_report = tmp_path / "s.rrd", tmp_path / "s.json", tmp_path / "r.json"
    result = runner.invoke(
        app,
        ["sweep", str(SAMPLE), "--truth", str(TRUTH), "--preset", "tuning", "--save", str(rrd),
         "--report", str(report), "--workers", "2"],
        env={"COLUMNS": "200"},
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert all(column in result.output for column in ("worst", "aligned", "3σ axis"))
    result = runner.invoke(
        app, ["replay", str(SAMPLE), "--truth", str(TRUTH), "--save", str(tmp_path / "r.rrd"),
              "--report", str(replay_report)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    variants = json.loads(report.read_text())["variants"]
    plain = json.loads(replay_report.read_text())
    assert len(variants) == 11 and variants[0]["label"] == "baseline"
    for key in ("final_pose", "final_pose_cov", "landmarks"):
        assert variants[0][key] == plain[key]  # exactly: same code, same numbers
    assert all(
        {"label", "parameters", "landmarks", "final_pose", "mean_nis"} <= set(v) for v in variants
    )
    assert variants[1]["parameters"]["sigma_x"] == pytest.approx(2.5)
    # the new columns: the same figures as the replay's summary, in the table too
    assert variants[0]["mean_semi_major"] == pytest.approx(
        plain["summary"]["mean_semi_major_3sigma"]
    )
    assert variants[0]["aligned_mean_error"] == pytest.approx(
        plain["summary"]["aligned_mean_error"]
    )
    assert variants[0]["max_error"] == pytest.approx(plain["summary"]["worst_error"])
    assert all(v["mean_semi_major"] > 0 for v in variants)
    for variant in variants:
        key = variant["label"].replace(" /", "-div").replace(" x", "-x")
        rows = entity_rows(rrd, f"/variants/{key}/world/robot")
        assert len(rows) == 59, key  # one robot position per event of the log


def test_sweep_does_not_depend_on_the_number_of_workers(tmp_path: Path) -> None:
    reports = []
    for workers in ("1", "2"):
        report = tmp_path / f"{workers}.json"
        result = runner.invoke(
            app, ["sweep", str(SAMPLE), "--vary", "sigma_x=x2,/2", "--save",
                  str(tmp_path / f"{workers}.rrd"), "--report", str(report), "--workers", workers],
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        variants = json.loads(report.read_text())["variants"]
        for variant in variants:  # the wall time is the only thing allowed to differ
            assert variant.pop("seconds") > 0
            variant.pop("ms_per_step")
        reports.append(variants)
    assert reports[0] == reports[1]


@pytest.mark.parametrize(
    ("vary", "message"),
    [
        ([f"{name}=" + ",".join(str(1 + k / 100) for k in range(100))
          for name in ("sigma_x", "sigma_y", "sigma_alpha", "sigma_bearing", "sigma_range")],
         "--vary asks for 10,000,000,000 variants, more than a sweep runs (1,000)"),
        (["sigma_bearing=0"], "gives sigma_bearing = 0, expected a positive sigma"),
        (["sigma_range=/1e-320"], "gives sigma_range = inf, expected at most 1e+18"),
        (["sigma_x=0.1,0.1000001"], "names two values that print alike"),
    ],
)  # fmt: skip
def test_a_vary_that_cannot_run_as_asked_is_one_line(
    tmp_path: Path, vary: list[str], message: str
) -> None:
    """A 2 KB command line asked for 10^10 variants and was built whole (memory); a zero
    R ran (errors of 80 km); an infinite sigma blamed line 1 of the log; two values that
    print alike ran as one."""
    options = [part for text in vary for part in ("--vary", text)]
    result = runner.invoke(app, ["sweep", str(SAMPLE), *options, "--save", str(tmp_path / "x.rrd")])
    assert result.exit_code == 2, result.output
    assert message in result.output and len(result.output.strip().splitlines()) == 1
