"""The default viewer layout sent with every recording: a large map, metric plots, the log."""

from __future__ import annotations

import rerun.blueprint as rrb

from ekfviz.core.types import FloatArray
from ekfviz.viz import style

# The x axis of every plot spans the whole run, on whichever timeline is shown. Without it
# a plot of a timestamped log (MRCLAM's Unix times) opens zoomed to an instant and looks
# empty; linked to nothing, each plot keeps its own zoom.
WHOLE_RUN = rrb.archetypes.TimeAxis(
    link=rrb.components.LinkAxis.Independent,
    view_range=rrb.TimeRange(
        start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite()
    ),
)


def accumulated_range() -> rrb.VisibleTimeRanges:
    """Show an entity from the infinite past up to the time cursor, on every timeline."""
    return rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                timeline,
                start=rrb.TimeRangeBoundary.infinite(),
                end=rrb.TimeRangeBoundary.cursor_relative(),
            )
            for timeline in (style.STEP, style.EVENT, style.TIME)
        ]
    )


def map_view(
    bounds_xy: FloatArray | None = None,
    *,
    prefix: str = "",
    name: str = "Map",
    history: bool = False,
) -> rrb.Spatial2DView:
    """The 2-D map: robot, ellipses, landmarks, observations and the trajectory so far.

    :param bounds_xy: (2, 2) [[x_min, y_min], [x_max, y_max]] in world coordinates to
        frame, or None to let the viewer choose
    :param prefix: the entity path the run was logged under (see ``Recorder(prefix=)``)
    :param history: also accumulate every predicted and updated robot ellipse up to the
        time cursor (``--history``: the classic figure)
    """
    root = f"/{prefix.strip('/')}/" if prefix.strip("/") else "/"
    visual_bounds = None
    if bounds_xy is not None:
        (x_min, y_min), (x_max, y_max) = bounds_xy
        # the view shows the root frame, where "world" is mirrored in y
        visual_bounds = rrb.VisualBounds2D(x_range=[x_min, x_max], y_range=[-y_max, -y_min])
    return rrb.Spatial2DView(
        name=name,
        origin=root,  # the display frame: y up, through the static transform of "world"
        contents=f"{root}{style.WORLD}/**",
        background=style.BACKGROUND,
        visual_bounds=visual_bounds,
        overrides={
            f"{root}{path}": accumulated_range()
            for path in style.ACCUMULATED + (style.HISTORY if history else ())
        },
    )


def default_blueprint(
    *,
    has_truth: bool,
    has_run_info: bool,
    has_true_poses: bool = False,
    bounds_xy: FloatArray | None = None,
    has_time: bool = False,
    history: bool = False,
) -> rrb.Blueprint:
    """The layout: the map on the left, plots above and documents below on the right.

    :param has_time: the run has a ``time`` timeline: the time panel shows it
    :param has_truth: add the landmark error and Mahalanobis distance plots
    :param has_run_info: add the run information, input and evaluation documents
    :param has_true_poses: add the NEES plot
    :param bounds_xy: (2, 2) world box the map frames, see :func:`map_view`
    :param history: the map accumulates every robot ellipse, see :func:`map_view`
    """
    plots: list[rrb.View] = [
        rrb.TimeSeriesView(axis_x=WHOLE_RUN, name="NIS and 95% bounds", origin=style.NIS)
    ]
    if has_true_poses:
        plots.append(
            rrb.TimeSeriesView(axis_x=WHOLE_RUN, name="NEES and 95% bounds", origin=style.NEES)
        )
    plots.append(rrb.TimeSeriesView(axis_x=WHOLE_RUN, name="Pose sigma", origin=style.POSE_SIGMA))
    plots.append(
        rrb.TimeSeriesView(
            axis_x=WHOLE_RUN,
            name="Smallest eigenvalue of P",
            origin=style.HEALTH,
            contents=[
                f"$origin/{path.rsplit('/', 1)[1]}"
                for path in (
                    style.HEALTH_POSE_MIN_EIG,
                    style.HEALTH_LANDMARK_MIN_EIG,
                    style.HEALTH_P_MIN_EIG,
                )
            ],
        )
    )
    if has_truth:
        plots += [
            rrb.TimeSeriesView(
                axis_x=WHOLE_RUN, name="Landmark error [m]", origin=style.LANDMARK_ERROR
            ),
            rrb.TimeSeriesView(
                axis_x=WHOLE_RUN, name="Mahalanobis distance", origin=style.MAHALANOBIS
            ),
        ]
    texts: list[rrb.Container | rrb.View] = [
        rrb.TextLogView(name="Log", origin=style.LOG),
        correlation_view(),
    ]
    if has_run_info:
        texts += [
            rrb.TextDocumentView(name="Run", origin=style.RUN_INFO),
            rrb.TextDocumentView(name="Evaluation", origin=style.RUN_EVALUATION),
            rrb.TextDocumentView(name="Input", origin=style.RUN_INPUT),
        ]
    return rrb.Blueprint(
        rrb.Horizontal(
            map_view(bounds_xy, history=history),
            rrb.Vertical(
                rrb.Grid(*plots, grid_columns=2),
                rrb.Tabs(*texts),
                row_shares=[3, 2],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(
            timeline=style.TIME if has_time else style.STEP,
            play_state="following",
            state="collapsed",
        ),
        collapse_panels=True,
    )


def correlation_view(prefix: str = "") -> rrb.Vertical:
    """The correlation matrix of P with its labelled blocks, above what it shows."""
    root = f"/{prefix.strip('/')}/" if prefix.strip("/") else "/"
    return rrb.Vertical(
        rrb.Spatial2DView(
            name="Correlation",
            origin=f"{root}{style.CORRELATION}",
            contents=[f"{root}{style.CORRELATION_MATRIX}", f"{root}{style.CORRELATION_BLOCKS}"],
        ),
        rrb.TextDocumentView(name="Correlation", origin=f"{root}{style.CORRELATION_NOTE}"),
        row_shares=[6, 1],
        name="Correlation",
    )


def sweep_blueprint(
    variants: list[tuple[str, str]],
    *,
    has_truth: bool,
    bounds_xy: FloatArray | None = None,
    what: str = "variant",
    has_poses: bool = False,
) -> rrb.Blueprint:
    """A grid of maps, one per run (baseline first), above overlaid metric plots.

    :param variants: (label, prefix) of every run, in order
    :param what: what a run is called in the plot titles (``variant``, ``filter``)
    :param has_poses: the truth has poses: a NEES plot too
    """
    maps = [map_view(bounds_xy, prefix=prefix, name=label) for label, prefix in variants]
    plots = [
        rrb.TimeSeriesView(
            axis_x=WHOLE_RUN,
            name=f"NIS per {what}",
            contents=[f"/{prefix}/{style.NIS}" for _, prefix in variants],
        )
    ]
    if has_poses:
        plots.append(
            rrb.TimeSeriesView(
                axis_x=WHOLE_RUN,
                name=f"Pose NEES per {what}",
                contents=[f"/{prefix}/{style.NEES}" for _, prefix in variants],
            )
        )
    if has_truth:
        plots.append(
            rrb.TimeSeriesView(
                axis_x=WHOLE_RUN,
                name=f"Mean landmark error [m] per {what}",
                contents=[f"/{prefix}/{style.MEAN_LANDMARK_ERROR}" for _, prefix in variants],
            )
        )
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Grid(*maps),
            rrb.Horizontal(*plots),
            row_shares=[3, 1],
        ),
        rrb.TimePanel(timeline=style.STEP, play_state="following", state="collapsed"),
        collapse_panels=True,
    )
