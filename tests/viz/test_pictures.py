"""What a user sees, read back from the recording: a legend of the map's marks, labels at
their landmarks inside the frame, every landmark's current ellipse, comparisons whose
identical runs are told apart, and check recordings whose reference is its own over the
whole run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from blueprints import read_layout
from conftest import entity_rows
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.evaluation.consistency import chi2_bounds
from ekfviz.viz import check as check_viz
from ekfviz.viz import style
from ekfviz.viz.axes import HEADROOM
from ekfviz.viz.layers.labels import LABEL_DROP, LABEL_HEIGHT, LABEL_WIDTH

DATA = Path(__file__).resolve().parents[2] / "data"
CLASSIC, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
PLUGINS = Path(__file__).resolve().parents[1] / "plugins" / "textbook.py"
runner = CliRunner()
WIDTHS = "SeriesLines:widths"


def saved(args: list[str], save: Path, code: int = 0) -> Path:
    result = runner.invoke(app, [*args, "--save", str(save)])
    assert result.exit_code == code, result.output
    return save


def legend_text(rrd: Path) -> str:
    (row,) = entity_rows(rrd, f"/{style.RUN_LEGEND}", static=True)
    return str(row["TextDocument:text"])


@pytest.fixture(scope="module")
def classic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("classic")
    return saved(["replay", str(CLASSIC), "--truth", str(TRUTH)], folder / "classic.rrd")


def test_the_map_has_a_legend_of_the_marks_it_draws(classic: Path, tmp_path: Path) -> None:
    layout = read_layout(classic)
    (legend,) = [view for view in layout.views if view.name == "Legend"]
    assert legend.kind == "TextDocument" and legend.shown == {f"/{style.RUN_LEGEND}"}
    text = legend_text(classic)
    for words in ("blue line", "magenta ellipse", "green dots", "red ellipse", "orange rays",
                  "black dots**: the true landmarks", "grey line"):  # fmt: skip
        assert words in text, words
    untruthful = saved(["replay", str(CLASSIC)], tmp_path / "plain.rrd")
    text = legend_text(untruthful)
    assert "blue line" in text and "true landmarks" not in text and "grey line" not in text
    # a log of scans: the head of the bundled one (its header with it) is enough for a legend
    head = tmp_path / "scans.txt"
    head.write_text("".join((DATA / "scans.txt").read_text().splitlines(keepends=True)[:300]))
    scans = saved(["replay", str(head), "--association", "nn"], tmp_path / "s.rrd")
    assert "green: matched, orange: new, red: rejected" in legend_text(scans)


def test_labels_hang_just_below_their_landmarks_inside_the_frame(classic: Path) -> None:
    points = entity_rows(classic, f"/{style.LANDMARKS}")[-1]
    labels = entity_rows(classic, f"/{style.LANDMARK_LABELS}")[-1]
    assert points["event"] == labels["event"]
    landmarks_xy = np.array(points["Points2D:positions"])
    labels_xy = np.array(labels["Points2D:positions"])
    assert labels["Points2D:class_ids"] == points["Points2D:class_ids"]
    (world,) = [view for view in read_layout(classic).views if view.name == "Map"]
    (bounds,) = world.properties["VisualBounds2D"]["VisualBounds2D:range"]
    x_min, x_max = bounds["x_range"]
    y_min, y_max = -bounds["y_range"][1], -bounds["y_range"][0]  # the view's y is mirrored
    span = max(x_max - x_min, y_max - y_min)
    np.testing.assert_allclose(labels_xy[:, 0], landmarks_xy[:, 0], atol=1e-5)
    drop = landmarks_xy[:, 1] - labels_xy[:, 1]
    # just below: by the drop (in label heights of the map's span), two if stacked; the
    # 3-sigma outline's depth was up to 4 m here
    assert (drop > 0).all() and (drop < 2.5 * LABEL_HEIGHT * span).all(), drop
    assert np.median(drop) < 1.5 * LABEL_DROP * LABEL_HEIGHT * span
    half = np.array([0.5 * LABEL_WIDTH, 0.5 * LABEL_HEIGHT]) * span * 0.9
    assert (labels_xy - half >= [x_min, y_min]).all() and (labels_xy + half <= [x_max, y_max]).all()


@pytest.fixture(scope="module")
def mrclam_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("mrclam")
    result = runner.invoke(
        app, ["simulate", "--layout", "mrclam", "-o", str(folder / "MRCLAM_Sim"), "--seed", "3",
              "--duration", "60"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return saved(["replay", str(folder / "MRCLAM_Sim"), "--robot", "1"], folder / "run.rrd")


def latest(rows: list[dict[str, Any]], event: int) -> dict[str, Any] | None:
    """The row with the largest event at or before ``event`` (the viewer's latest-at)."""
    before = [row for row in rows if int(row["event"]) <= event]
    return before[-1] if before else None


def test_every_mapped_landmark_has_its_ellipse_at_every_update(mrclam_run: Path) -> None:
    points = entity_rows(mrclam_run, f"/{style.LANDMARKS}")
    whole = entity_rows(mrclam_run, f"/{style.LANDMARK_ELLIPSES}")
    observed = entity_rows(mrclam_run, f"/{style.LANDMARK_ELLIPSES_OBSERVED}")
    assert observed and len(whole) < len(points)  # thinned: the whole map now and then
    events = sorted({int(row["event"]) for row in [*points, *whole, *observed]})
    checked = 0
    for event in events:
        mapped = latest(points, event)
        if mapped is None:
            continue
        shown: set[int] = set()
        for rows in (whole, observed):
            row = latest(rows, event)
            if row is not None and row["LineStrips2D:class_ids"]:
                shown |= set(row["LineStrips2D:class_ids"])
        assert set(mapped["Points2D:class_ids"] or []) <= shown, event
        checked += 1
    assert checked > 20


def test_a_first_sighting_on_real_data_shows_for_a_while_only(mrclam_run: Path) -> None:
    (world,) = [view for view in read_layout(mrclam_run).views if view.name == "Map"]
    ranges = world.properties[f"ViewContents/overrides/{style.LANDMARK_INITIAL}/visualizers"]
    by_timeline = {r["timeline"]: r["range"] for r in ranges["VisibleTimeRanges:ranges"]}
    # from 10 s before the cursor to the cursor (in nanoseconds), not from the start
    assert by_timeline["time"]["start"] == -10_000_000_000
    assert by_timeline["time"]["end"] == 0


def test_identical_filters_of_a_comparison_are_told_apart(tmp_path: Path) -> None:
    textbook = f"{PLUGINS}:Textbook"
    args = ["compare", str(CLASSIC), "--truth", str(TRUTH), "--filter", "ekf", "--filter", textbook]
    rrd = saved([*args, "--workers", "1"], tmp_path / "c.rrd")
    layout = read_layout(rrd)
    names = [view.name for view in layout.views]
    assert "ekf (blue)" in names and "Textbook (orange)" in names
    plots = [
        view for view in layout.views if view.kind == "TimeSeries" and "per filter" in view.name
    ]
    assert plots and all("ekf = Textbook identical" in view.name for view in plots)
    widths = {}
    for key in ("ekf", "Textbook"):
        rows = entity_rows(rrd, f"/filters/{key}/{style.NIS}", static=True)
        (widths[key],) = [
            row["SeriesLines:widths"] for row in rows if row.get("SeriesLines:widths")
        ]
    assert widths["ekf"][0] > widths["Textbook"][0]  # the earlier wide, beneath
    # the NIS axis fits the values and the bounds near them
    (nis,) = [view for view in plots if view.name.startswith("NIS")]
    ((_, top),) = nis.properties["ScalarAxis"]["ScalarAxis:range"]
    values = [row["Scalars:scalars"][0] for row in entity_rows(rrd, f"/filters/ekf/{style.NIS}")]
    upper = chi2_bounds(12)[1]  # 6 landmarks in every update of the sample
    assert max(values) < top == pytest.approx(HEADROOM * max(upper, max(values)))
    assert top < 3.0 * upper / 2  # the old frame, to three times the bound, is halved


def test_a_check_that_goes_on_draws_the_reference_alone_over_the_whole_run(
    tmp_path: Path,
) -> None:
    rrd = saved(["check", str(CLASSIC), "--filter", f"{PLUGINS}:NoRInS", "--all"],
                tmp_path / "all.rrd", code=1)  # fmt: skip
    layout = read_layout(rrd)
    assert layout.unshown() == [] and layout.empty() == []
    names = [view.name for view in layout.views if view.kind == "2D"]
    assert "reference (ekf)" in names and "At event 2" in names
    alone = saved(["replay", str(CLASSIC)], tmp_path / "alone.rrd")  # the reference alone
    for entity in ("world/robot", "world/landmarks"):
        drawn = entity_rows(rrd, f"/filters/reference/{entity}")
        replayed = entity_rows(alone, f"/{entity}")
        assert [row["event"] for row in drawn] == [row["event"] for row in replayed]
        for got, expected in zip(drawn, replayed, strict=True):
            np.testing.assert_allclose(
                np.asarray(got["Points2D:positions"]),
                np.asarray(expected["Points2D:positions"]),
                rtol=0.0,
                atol=1e-9,
            )
    checked = entity_rows(rrd, "/filters/NoRInS/world/robot")
    assert drawn[-1]["event"] == checked[-1]["event"] > 2  # both to the end of the log
    marks = {
        key: entity_rows(rrd, f"/filters/{key}/{check_viz.DIVERGENCE}", static=True)[0]
        for key in ("reference", "NoRInS")
    }
    assert len(marks["reference"]["Points2D:positions"]) == 1  # the first divergence only
    assert len(marks["NoRInS"]["Points2D:positions"]) > 1
    assert marks["NoRInS"]["Points2D:labels"][0] == "event 2"


def test_a_divergence_at_the_first_event_has_its_difference_drawn(tmp_path: Path) -> None:
    rrd = saved(["check", str(CLASSIC), "--filter", f"{PLUGINS}:NoCrossCovariances"],
                tmp_path / "init.rrd", code=1)  # fmt: skip
    differences = entity_rows(rrd, f"/{check_viz.DIFFERENCE}")
    assert [row["event"] for row in differences] == [0]
    (look,) = entity_rows(rrd, f"/{check_viz.DIFFERENCE}", static=True)
    assert "SeriesPoints:marker_sizes" in look  # a point: one value draws no line
    layout = read_layout(rrd)
    assert layout.showing(f"/{check_viz.DIFFERENCE}") and layout.empty() == []
