"""A recording of a Monte-Carlo consistency study: mean NEES and NIS per step, with bounds."""

from __future__ import annotations

import json
import uuid
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ekfviz import __version__
from ekfviz.io.files import replaced_whole
from ekfviz.studies.montecarlo import MonteCarlo
from ekfviz.viz import style
from ekfviz.viz.recording import any_values

REPORT = "run/consistency"


def save_monte_carlo(
    path: Path,
    result: MonteCarlo,
    name: str,
    markdown: str,
    *,
    command: str = "",
    settings: Mapping[str, object] | None = None,
) -> None:
    """Write the averaged curves, their bounds and the verdict document to ``path``.

    :param markdown: the study's settings and verdict, shown beside the plots
    :param command: the command line that made it, for ``ekfviz info``
    :param settings: the study's settings (scenario, runs, filter, ...), likewise
    """
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(
                    name="Mean NEES (blue) and 95% bounds",
                    origin=style.NEES,
                    plot_legend=rrb.PlotLegend(visible=False),
                ),
                rrb.TimeSeriesView(
                    name="Mean NIS (blue) and 95% bounds",
                    origin=style.NIS,
                    plot_legend=rrb.PlotLegend(visible=False),
                ),
            ),
            rrb.TextDocumentView(name="Consistency", origin=REPORT),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=style.STEP, state="collapsed"),
        collapse_panels=True,
    )
    with replaced_whole(path) as temporary:
        rec = rr.RecordingStream("ekfviz", recording_id=str(uuid.uuid4()), send_properties=False)
        rec.set_log_time_enabled(False)
        rec.save(temporary, default_blueprint=blueprint)
        rec.send_recording_name(name)
        properties = any_values({
            "version": __version__,
            "kind": "consistency",
            "command": command,
            "parameters": json.dumps(dict(settings or {})),
        })  # fmt: skip
        rec.send_property("ekfviz", properties)
        rec.log(REPORT, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)
        steps = np.arange(len(result.mean_nees))
        for path_, label, mean, bounds in (
            (style.NEES, "mean NEES", result.mean_nees, result.nees_bounds),
            (style.NIS, "mean NIS", result.mean_nis, result.nis_bounds),
        ):
            for entity, values, color, series in (
                (path_, mean, style.STATISTIC_COLOR, label),
                (f"{path_}/{style.LOWER}", bounds[:, 0], style.BOUND_COLOR, "95% lower"),
                (f"{path_}/{style.UPPER}", bounds[:, 1], style.BOUND_COLOR, "95% upper"),
            ):
                rec.log(entity, rr.SeriesLines(colors=color, names=series), static=True)
                keep = np.isfinite(values)
                rec.send_columns(
                    entity,
                    indexes=[rr.TimeColumn(style.STEP, sequence=steps[keep])],
                    columns=rr.Scalars.columns(scalars=values[keep]),
                )
        rec.flush()
        rec.disconnect()
