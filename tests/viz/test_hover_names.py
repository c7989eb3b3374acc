"""Every mark of a map is named on hover, read back from the recording: each entity that
draws points, lines, arrows or boxes holds class ids that the annotation context in scope
(its own or its nearest ancestor's) names, or labels of its own."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import every_entity_rows, few_by_default
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.viz.legend import KIND_NAMES

DATA = Path(__file__).resolve().parents[2] / "data"
CLASSIC, TRUTH = DATA / "classic.txt", DATA / "classic_truth.json"
PLUGINS = Path(__file__).resolve().parents[1] / "plugins" / "textbook.py"
runner = CliRunner()

DRAWN = ("Points2D:positions", "LineStrips2D:strips", "Arrows2D:vectors", "Boxes2D:half_sizes")
CONTEXT = "AnnotationContext:context"


def column_values(rows: list[dict[str, object]], ending: str) -> list[object]:
    """Every value given in the rows' column whose name ends with ``ending``, flattened."""
    found: list[object] = []
    for row in rows:
        for name, value in row.items():
            if name.endswith(ending) and isinstance(value, list):
                found += value
    return found


def contexts(static: dict[str, list[dict[str, object]]]) -> dict[str, dict[int, str]]:
    """The last annotation context logged to each entity: class id -> label."""
    found: dict[str, dict[int, str]] = {}
    for entity, rows in static.items():
        for row in rows:
            value = row.get(CONTEXT)
            if isinstance(value, list) and value:
                found[entity] = {
                    int(entry["class_id"]): str(entry["class_description"]["info"]["label"])
                    for entry in value[0]
                }
    return found


def unnamed(rrd: Path) -> dict[str, list[int]]:
    """The entities drawing marks that hovering would not name, with their class ids
    that no context in scope labels."""
    static = every_entity_rows(rrd, static=True)
    temporal = every_entity_rows(rrd)
    named = contexts(static)
    missing: dict[str, list[int]] = {}
    for entity in set(static) | set(temporal):
        rows = static.get(entity, []) + temporal.get(entity, [])
        if not any(column_values(rows, drawn) for drawn in DRAWN):
            continue
        labels = [label for label in column_values(rows, ":labels") if label]
        if labels:
            continue
        scope = entity
        while scope not in named and scope.count("/") > 1:
            scope = scope.rpartition("/")[0]
        classes = named.get(scope, {})
        ids = sorted({int(i) for i in column_values(rows, ":class_ids")})
        if not ids or any(not classes.get(i) for i in ids):
            missing[entity] = [i for i in ids if not classes.get(i)]
    return missing


def saved(args: list[str], save: Path, code: int = 0) -> Path:
    result = runner.invoke(app, [*args, "--save", str(save)])
    assert result.exit_code == code, result.output
    return save


KINDS = {
    "replay": (["replay", str(CLASSIC), "--truth", str(TRUTH)], 0),
    "replay-history": (["replay", str(CLASSIC), "--history"], 0),
    "check-all": (["check", str(CLASSIC), "--filter", f"{PLUGINS}:NoRInS", "--all"], 1),
    "compare-2": (
        ["compare", str(CLASSIC), "--truth", str(TRUTH), "--filter", "ekf",
         "--filter", f"{PLUGINS}:Textbook", "--workers", "1"],
        0,
    ),
}  # fmt: skip


@pytest.mark.parametrize("kind", few_by_default(list(KINDS), 2))
def test_every_mark_of_a_map_is_named_on_hover(kind: str, tmp_path: Path) -> None:
    args, code = KINDS[kind]
    rrd = saved(args, tmp_path / f"{kind}.rrd", code)
    assert unnamed(rrd) == {}


def test_the_names_are_the_legends_and_say_whose_in_a_comparison(tmp_path: Path) -> None:
    args, _ = KINDS["compare-2"]
    rrd = saved(args, tmp_path / "compare.rrd")
    named = contexts(every_entity_rows(rrd, static=True))
    for name in ("ekf", "Textbook"):
        labels = set(named[f"/filters/{name}/world"].values())
        assert {f"{text} ({name})" for _, text in KIND_NAMES} <= labels
        assert "L1" in labels  # the landmarks' own, beside them
    classic = contexts(every_entity_rows(saved(["replay", str(CLASSIC)], tmp_path / "r.rrd"),
                                         static=True))  # fmt: skip
    assert "the estimated path" in classic["/world"].values()


def test_a_watch_runs_ghost_is_named_on_hover(tmp_path: Path) -> None:
    from ekfviz import viz
    from ekfviz.app.check import Recorded, check_log, check_recording
    from ekfviz.core.params import FilterParams
    from ekfviz.filters.spec import FilterSpec
    from ekfviz.viz.ghost import Ghost, record_failure

    spec = FilterSpec(f"{PLUGINS}:NoRInS")
    params = FilterParams()
    result, _ = check_log(CLASSIC, None, spec, params, tolerance=1e-6, save=None)
    shown = check_recording(Recorded(CLASSIC, None, [], [CLASSIC], "ekfviz watch"), spec,
                            params, result)  # fmt: skip
    ghost = Ghost(
        "run 2",
        np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 0.0]]),
        np.array([[1.0, 2.0], [3.0, 1.0]]),
        np.tile(np.eye(2) * 0.1, (3, 1, 1)),
    )
    failed = tmp_path / "failed.rrd"
    with viz.open_recording(shown.info, viz.Sinks(save=failed)) as recording:
        record_failure(recording, "filters/NoRInS", spec.label, ghost, ["it failed"])
    assert unnamed(failed) == {}
    named = contexts(every_entity_rows(failed, static=True))
    assert set(named["/filters/NoRInS/world/previous"].values()) == {
        "run 2: its estimated path", "run 2: its landmarks at the end", "run 2: its 3σ at the end"
    }  # fmt: skip
