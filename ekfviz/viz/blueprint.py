"""The default viewer layout sent with every recording: a large map, metric plots, the log."""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from ekfviz.core.consistency import chi2_bounds
from ekfviz.core.types import FloatArray
from ekfviz.viz import style

# The x axis of a plot on the ``time`` timeline spans the whole run. Without it a plot of
# a timestamped log (MRCLAM's Unix times) opens zoomed to an instant and looks empty;
# linked to nothing, each plot keeps its own zoom. On the sequence timelines (step,
# event) the default already fits, and the property would cost every plot a chunk.
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


def at_cursor() -> rrb.VisibleTimeRanges:
    """Show an entity only where it was logged at the time cursor's own step or event (on
    the ``time`` timeline the latest, as by default)."""
    return rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                timeline,
                start=rrb.TimeRangeBoundary.cursor_relative(),
                end=rrb.TimeRangeBoundary.cursor_relative(),
            )
            for timeline in (style.STEP, style.EVENT)
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
            **{
                f"{root}{path}": accumulated_range()
                for path in style.ACCUMULATED + (style.HISTORY if history else ())
            },
            f"{root}{style.OBSERVATIONS}": at_cursor(),  # see Recorder._send_rays
        },
    )


# Small plots: a legend would hide a third of one; it is shown only where the colours
# cannot be told from the title, small and in a corner.
NO_LEGEND = rrb.PlotLegend(visible=False)
SMALL_LEGEND = rrb.PlotLegend(corner=rrb.components.Corner2D.RightTop, visible=True)
HIDDEN = rrb.EntityBehavior(visible=False)


def summary_plot(
    name: str,
    summary: str,
    per_landmark: str,
    ids: Sequence[int],
    axis_x: rrb.archetypes.TimeAxis | None = None,
) -> rrb.View:
    """The mean and worst landmark of a per-landmark metric; the landmarks' own series
    are in the view too, hidden until shown (in the view's entity list): one override on
    their parent, which they inherit (one per landmark cost a blueprint chunk each)."""
    return rrb.TimeSeriesView(
        axis_x=axis_x,
        name=name,
        contents=[f"/{summary}/**", f"/{per_landmark}/**"],
        plot_legend=SMALL_LEGEND,
        overrides={f"/{per_landmark}": HIDDEN},
    )


def default_blueprint(
    *,
    has_truth: bool,
    has_run_info: bool,
    has_true_poses: bool = False,
    bounds_xy: FloatArray | None = None,
    has_time: bool = False,
    history: bool = False,
    landmark_ids: Sequence[int] = (),
) -> rrb.Blueprint:
    """The layout: the map on the left, plots above and documents below on the right.

    :param has_time: the run has a ``time`` timeline: the time panel shows it
    :param has_truth: add the landmark error and Mahalanobis distance plots
    :param has_run_info: add the run information, input and evaluation documents
    :param has_true_poses: add the NEES plot
    :param bounds_xy: (2, 2) world box the map frames, see :func:`map_view`
    :param history: the map accumulates every robot ellipse, see :func:`map_view`
    :param landmark_ids: the landmarks whose own error series the plots hide (they show
        the mean and the worst landmark)
    """
    axis = WHOLE_RUN if has_time else None  # the default fits a sequence timeline already
    plots: list[rrb.View] = [
        rrb.TimeSeriesView(
            axis_x=axis,
            name="NIS (blue) and 95% bounds",
            origin=style.NIS,
            plot_legend=NO_LEGEND,
        )
    ]
    if has_true_poses:
        plots.append(
            rrb.TimeSeriesView(
                axis_x=axis,
                name="NEES (blue) and 95% bounds",
                origin=style.NEES,
                plot_legend=NO_LEGEND,
            )
        )
    plots.append(
        rrb.TimeSeriesView(
            axis_x=axis, name="Pose sigma", origin=style.POSE_SIGMA, plot_legend=SMALL_LEGEND
        )
    )
    plots.append(
        rrb.TimeSeriesView(
            axis_x=axis,
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
            plot_legend=SMALL_LEGEND,
        )
    )
    if has_truth:
        plots += [
            summary_plot(
                "Landmark error [m]",
                style.LANDMARK_ERROR_SUMMARY,
                style.LANDMARK_ERROR,
                landmark_ids,
                axis,
            ),
            summary_plot(
                "Mahalanobis distance",
                style.MAHALANOBIS_SUMMARY,
                style.MAHALANOBIS,
                landmark_ids,
                axis,
            ),
        ]
    texts: list[rrb.Container | rrb.View] = [
        rrb.TextLogView(
            name="Log",
            origin=style.LOG,
            # level and text only: a line starts with its step, which a narrow timeline
            # column would cut ("#9..."); no entity path
            columns=rrb.TextLogColumns(
                timeline_columns=[
                    rrb.encodings.TimelineColumn(style.STEP, visible=False),
                    rrb.encodings.TimelineColumn(style.EVENT, visible=False),
                ],
                text_log_columns=[
                    rrb.encodings.TextLogColumn("EntityPath", visible=False),
                    rrb.encodings.TextLogColumn("LogLevel"),
                    rrb.encodings.TextLogColumn("Body"),
                ],
            ),
        ),
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
    nis_range: tuple[float, float] | None = None,
) -> rrb.Blueprint:
    """A grid of maps, one per run (baseline first), beside overlaid metric plots tall
    enough for a legend entry per run.

    :param variants: (label, prefix) of every run, in order
    :param what: what a run is called in the plot titles (``variant``, ``filter``)
    :param has_poses: the truth has poses: a NEES plot too
    :param nis_range: the NIS axis to show (a few times the first run's 95% bounds): the
        few wild runs would otherwise flatten every sensible one
    """
    maps = [map_view(bounds_xy, prefix=prefix, name=label) for label, prefix in variants]
    first = variants[0][1]
    plots = [
        rrb.TimeSeriesView(
            name=f"NIS per {what} (grey: {variants[0][0]}'s 95% bounds)",
            contents=[
                *(f"/{prefix}/{style.NIS}" for _, prefix in variants),
                f"/{first}/{style.NIS}/{style.LOWER}",
                f"/{first}/{style.NIS}/{style.UPPER}",
            ],
            axis_y=None if nis_range is None else rrb.ScalarAxis(range=nis_range),
            plot_legend=SMALL_LEGEND,
        )
    ]
    if has_poses:
        plots.append(
            rrb.TimeSeriesView(
                name=f"Pose NEES per {what} (colours as above)",
                contents=[f"/{prefix}/{style.NEES}" for _, prefix in variants],
                axis_y=rrb.ScalarAxis(range=(0.0, 3.0 * chi2_bounds(3)[1])),
                plot_legend=NO_LEGEND,
            )
        )
    if has_truth:
        plots.append(
            rrb.TimeSeriesView(
                name=f"Mean landmark error [m] per {what} (colours as above)",
                contents=[f"/{prefix}/{style.MEAN_LANDMARK_ERROR}" for _, prefix in variants],
                plot_legend=NO_LEGEND,
            )
        )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Grid(*maps),
            rrb.Vertical(*plots, row_shares=[2] + [1] * (len(plots) - 1)),  # room for the legend
            column_shares=[5, 2],
        ),
        rrb.TimePanel(timeline=style.STEP, play_state="following", state="collapsed"),
        collapse_panels=True,
    )
