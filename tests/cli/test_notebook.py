"""examples/replay.ipynb runs in a real Jupyter kernel and shows Rerun's notebook viewer."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

EXAMPLES = Path(__file__).parents[2] / "examples"
WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"
WIDGET_STATE = "application/vnd.jupyter.widget-state+json"


@pytest.mark.slow
def test_the_example_notebook_replays_the_sample_into_the_rerun_viewer() -> None:
    import nbformat
    from nbclient import NotebookClient

    notebook = nbformat.read(EXAMPLES / "replay.ipynb", as_version=4)  # type: ignore[no-untyped-call]
    assert all(not cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code")
    NotebookClient(
        notebook,
        timeout=180,
        kernel_name="python3",
        resources={"metadata": {"path": str(EXAMPLES)}},
    ).execute()
    outputs = [out for cell in notebook.cells if cell.cell_type == "code" for out in cell.outputs]
    assert not [out for out in outputs if out.output_type == "error"]
    state: dict[str, Any] = notebook.metadata["widgets"][WIDGET_STATE]["state"]

    def widgets_under(model_id: str) -> list[dict[str, Any]]:
        """A widget and every widget it holds (a box's children)."""
        model = state[model_id]
        found = [model]
        for child in model["state"].get("children", []):
            found += widgets_under(str(child).removeprefix("IPY_MODEL_"))
        return found

    shown = [
        widget
        for out in outputs
        if out.output_type == "display_data" and WIDGET_VIEW in out.data
        for widget in widgets_under(out.data[WIDGET_VIEW]["model_id"])
    ]
    viewers = [w for w in shown if "rerun" in str(w["state"].get("_anywidget_id", "")).lower()]
    assert len(viewers) == 1, [w["model_name"] for w in shown]
    assert viewers[0]["state"]["_height"] == 700
    # the last cell: the evaluation of the replay, its six landmarks all inside 3 sigma
    evaluation = outputs[-1].data["text/markdown"]
    rows = [line for line in evaluation.splitlines() if line.startswith(("| 1 ", "| 6 "))]
    assert len(rows) == 2 and all(row.endswith("| yes |") for row in rows)
