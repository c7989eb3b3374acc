"""The default viewer layout sent with every recording: a large map, metric plots, the log."""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

import rerun as rr
import rerun.blueprint as rrb

from ekfviz.core.types import FloatArray
from ekfviz.viz import style
from ekfviz.viz.axes import FittedAxis

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


# a study's maps, and its plots above its documents (the summary's tables fit the second)
STUDY_COLUMN_SHARES = (3, 2)


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


# On real data (a timestamped log) a first-sighting outline is drawn this long after the
# sighting: metres wide, the latest one stayed on the map for the rest of the run
FIRST_SIGHTING_S = 10.0
FIRST_SIGHTING_EVENTS = 600  # the same on the sequence timelines (MRCLAM: 67 Hz odometry)


def recent_range() -> rrb.VisibleTimeRanges:
    """Show an entity for ``FIRST_SIGHTING_S`` of log time (``FIRST_SIGHTING_EVENTS``
    steps or events) after it was logged."""
    return rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                style.TIME,
                start=rrb.TimeRangeBoundary.cursor_relative(seconds=-FIRST_SIGHTING_S),
                end=rrb.TimeRangeBoundary.cursor_relative(),
            ),
            *(
                rrb.VisibleTimeRange(
                    timeline,
                    start=rrb.TimeRangeBoundary.cursor_relative(seq=-FIRST_SIGHTING_EVENTS),
                    end=rrb.TimeRangeBoundary.cursor_relative(),
                )
                for timeline in (style.STEP, style.EVENT)
            ),
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
    exclude: Sequence[str] = (),
    all_first_sightings: bool = True,
) -> rrb.Spatial2DView:
    """The 2-D map: robot, ellipses, landmarks, observations and the trajectory so far.

    :param bounds_xy: (2, 2) [[x_min, y_min], [x_max, y_max]] in world coordinates to
        frame, or None to let the viewer choose
    :param prefix: the entity path the run was logged under (see ``Recorder(prefix=)``)
    :param history: also accumulate every predicted and updated robot ellipse up to the
        time cursor (``--history``: the classic figure)
    :param exclude: entities under the world (without the prefix) this map leaves out
    :param all_first_sightings: accumulate every landmark's first-sighting ellipse up to
        the cursor; else each is drawn for a few seconds after its sighting (on real data
        they are metres wide and a run's worth of them covers the map)
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
        contents=[f"+ {root}{style.WORLD}/**", *(f"- {root}{path}" for path in exclude)]
        if exclude
        else f"{root}{style.WORLD}/**",
        background=style.BACKGROUND,
        visual_bounds=visual_bounds,
        overrides={
            **{
                f"{root}{path}": accumulated_range()
                if all_first_sightings or path != style.LANDMARK_INITIAL
                else recent_range()
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
# The pose sigma entity holds three series, x and y in metres and theta in radians: two
# plots of it, each showing the series of one unit (a shared axis flattened theta).
LENGTHS_ONLY = rr.SeriesLines.from_fields(visible_series=[True, True, False])
ANGLE_ONLY = rr.SeriesLines.from_fields(visible_series=[False, False, True])
# the same for an offline filter's run, whose series are points (see Entities.style)
LENGTHS_ONLY_POINTS = rr.SeriesPoints.from_fields(visible_series=[True, True, False])
ANGLE_ONLY_POINTS = rr.SeriesPoints.from_fields(visible_series=[False, False, True])
# Series of the association of id-less scans and of a GPS reference (ekfviz.viz.association,
# ekfviz.viz.reference own them; named here so that the layout needs no import of them)
ASSOCIATION_SERIES = "metrics/association"
REFERENCE_SERIES = "metrics/reference"


def root_of(prefix: str) -> str:
    """The entity path a run was logged under, with slashes: ``/`` or ``/filters/ekf/``."""
    return f"/{prefix.strip('/')}/" if prefix.strip("/") else "/"


def tiles(views: Sequence[rrb.View | rrb.Container], columns: int = 2) -> rrb.Container:
    """Views in rows of ``columns``, the last row's views sharing its whole width: a grid
    of an odd number of views leaves no empty cell (a viewer draws it black)."""
    rows: list[rrb.View | rrb.Container] = [
        views[k] if len(views[k : k + columns]) == 1 else rrb.Horizontal(*views[k : k + columns])
        for k in range(0, len(views), columns)
    ]
    if len(rows) == 1 and isinstance(rows[0], rrb.Container):
        return rows[0]
    return rrb.Vertical(*rows)


def summary_plot(
    name: str,
    summary: str,
    per_landmark: str,
    ids: Sequence[int] = (),
    axis_x: rrb.archetypes.TimeAxis | None = None,
    prefix: str = "",
) -> rrb.View:
    """The mean and worst landmark of a per-landmark metric; the landmarks' own series
    are in the view too, hidden until shown (in the view's entity list): one override on
    their parent, which they inherit (one per landmark cost a blueprint chunk each)."""
    root = root_of(prefix)
    return rrb.TimeSeriesView(
        axis_x=axis_x,
        name=name,
        contents=[f"{root}{summary}/**", f"{root}{per_landmark}/**"],
        plot_legend=SMALL_LEGEND,
        overrides={f"{root}{per_landmark}": HIDDEN},
    )


def health_views(
    has: Collection[str], prefix: str = "", axis: rrb.archetypes.TimeAxis | None = None
) -> list[rrb.View]:
    """One plot per numerical-health series with data (each its own scale and unit)."""
    root = root_of(prefix)
    return [
        rrb.TimeSeriesView(axis_x=axis, name=name, origin=f"{root}{path}", plot_legend=NO_LEGEND)
        for path, name in (
            (style.HEALTH_POSE_MIN_EIG, "Smallest eigenvalue: pose block"),
            (style.HEALTH_LANDMARK_MIN_EIG, "Smallest eigenvalue: landmark blocks"),
            (style.HEALTH_P_MIN_EIG, "Smallest eigenvalue: whole P"),
            (style.HEALTH_P_LOG10_CONDITION, "log10 condition number of P"),
            (style.HEALTH_P_ASYMMETRY, "Asymmetry of P: max |P - P^T|"),
            (style.HEALTH_SKIPPED, "Skipped observations per update"),
        )
        if path in has
    ]


def run_plots(
    has: Collection[str],
    *,
    prefix: str = "",
    axis: rrb.archetypes.TimeAxis | None = None,
    landmark_ids: Sequence[int] = (),
    value_axes: Mapping[str, FittedAxis] | None = None,
    offline: bool = False,
) -> list[rrb.View | rrb.Container]:
    """The plots of one run, each only where its series have data (a plot of styling
    alone is an empty frame).

    :param has: the entity paths (without the prefix) that were given data
    :param offline: an offline filter's run, whose series are points
    :param value_axes: the y range of the NIS and NEES plots by entity path, fitted to
        their data and bounds (see :mod:`ekfviz.viz.axes`); its note goes in the title
    """
    root = root_of(prefix)
    lengths, angle = (
        (LENGTHS_ONLY_POINTS, ANGLE_ONLY_POINTS) if offline else (LENGTHS_ONLY, ANGLE_ONLY)
    )
    plots: list[rrb.View | rrb.Container] = []
    for path, name in (
        (style.NIS, "NIS (blue) and 95% bounds"),
        (style.NEES, "NEES (blue) and 95% bounds"),
    ):
        if path in has:
            fitted = value_axes.get(path) if value_axes else None
            plots.append(
                rrb.TimeSeriesView(
                    axis_x=axis,
                    axis_y=None if fitted is None else rrb.ScalarAxis(range=fitted.range),
                    name=f"{name} ({fitted.note})" if fitted is not None and fitted.note else name,
                    origin=f"{root}{path}",
                    plot_legend=NO_LEGEND,
                )
            )
    if style.POSE_SIGMA in has:
        plots.append(
            rrb.Tabs(
                rrb.TimeSeriesView(
                    axis_x=axis,
                    name="Pose sigma x, y [m]",
                    origin=f"{root}{style.POSE_SIGMA}",
                    plot_legend=SMALL_LEGEND,
                    overrides={f"{root}{style.POSE_SIGMA}": lengths},
                ),
                rrb.TimeSeriesView(
                    axis_x=axis,
                    name="Pose sigma theta [rad]",
                    origin=f"{root}{style.POSE_SIGMA}",
                    plot_legend=NO_LEGEND,
                    overrides={f"{root}{style.POSE_SIGMA}": angle},
                ),
                name="Pose sigma",
            )
        )
    health = health_views(has, prefix, axis)
    if health:
        plots.append(rrb.Tabs(*health, name="Numerical health") if len(health) > 1 else health[0])
    if f"{style.LANDMARK_ERROR_SUMMARY}/{style.MEAN}" in has:
        plots += [
            summary_plot(
                "Landmark error [m]",
                style.LANDMARK_ERROR_SUMMARY,
                style.LANDMARK_ERROR,
                landmark_ids,
                axis,
                prefix,
            ),
            summary_plot(
                "Mahalanobis distance",
                style.MAHALANOBIS_SUMMARY,
                style.MAHALANOBIS,
                landmark_ids,
                axis,
                prefix,
            ),
        ]
    if any(path.startswith(f"{ASSOCIATION_SERIES}/") for path in has):
        plots.append(
            rrb.TimeSeriesView(
                axis_x=axis,
                name="Association per scan (counts)",
                origin=f"{root}{ASSOCIATION_SERIES}",
                plot_legend=SMALL_LEGEND,
            )
        )
    if any(path.startswith(f"{REFERENCE_SERIES}/") for path in has):
        plots.append(
            rrb.TimeSeriesView(
                axis_x=axis,
                name="GPS error and its running RMSE [m]",
                origin=f"{root}{REFERENCE_SERIES}",
                plot_legend=SMALL_LEGEND,
            )
        )
    return plots


def log_view(contents: Sequence[str] = (f"/{style.LOG}/**",), name: str = "Log") -> rrb.View:
    """The text log: level and text only (a line starts with its step, which a narrow
    timeline column would cut: "#9..."), no entity path."""
    return rrb.TextLogView(
        name=name,
        origin="/",
        contents=list(contents),
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
    has: Collection[str] | None = None,
    value_axes: Mapping[str, FittedAxis] | None = None,
    offline: bool = False,
) -> rrb.Blueprint:
    """The layout: the map on the left, plots above and documents below on the right.

    :param has_time: the run has a ``time`` timeline: its plots span the whole run there
    :param has_truth: add the landmark error and Mahalanobis distance plots
    :param has_run_info: add the run information, input and evaluation documents
    :param has_true_poses: add the NEES plot
    :param bounds_xy: (2, 2) world box the map frames, see :func:`map_view`
    :param history: the map accumulates every robot ellipse, see :func:`map_view`
    :param landmark_ids: the landmarks whose own error series the plots hide (they show
        the mean and the worst landmark)
    :param has: the entity paths given data; a plot is laid out only where its series
        have some (None: those a run of this kind has, before any data)
    :param value_axes: the NIS and NEES plots' y ranges, see :func:`run_plots`
    :param offline: an offline filter's run, see :func:`run_plots`
    """
    axis = WHOLE_RUN if has_time else None  # the default fits a sequence timeline already
    final = has is not None
    if has is None:
        has = {style.NIS, style.POSE_SIGMA, style.HEALTH_POSE_MIN_EIG}
        if has_true_poses:
            has.add(style.NEES)
        if has_truth:
            has.add(f"{style.LANDMARK_ERROR_SUMMARY}/{style.MEAN}")
    plots = run_plots(
        has, axis=axis, landmark_ids=landmark_ids, value_axes=value_axes, offline=offline
    )
    texts: list[rrb.Container | rrb.View] = [log_view()]
    if style.CORRELATION_MATRIX in has or not final:
        texts.append(correlation_view())
    if has_run_info:
        texts += [
            rrb.TextDocumentView(name="Run", origin=style.RUN_INFO),
            rrb.TextDocumentView(name="Evaluation", origin=style.RUN_EVALUATION),
            rrb.TextDocumentView(name="Input", origin=style.RUN_INPUT),
        ]
    return rrb.Blueprint(
        rrb.Horizontal(
            with_legend(
                # a timestamped log is real data: its first sightings accumulate with --history
                map_view(bounds_xy, history=history, all_first_sightings=history or not has_time),
                style.RUN_LEGEND in has,
            ),
            rrb.Vertical(
                tiles(plots) if plots else rrb.Vertical(),
                rrb.Tabs(*texts),
                row_shares=[3, 2],
            ),
            # as wide as the map: a log line (an association's counts, a warning) fits, and
            # the map, framed square more often than not, is bounded by its height anyway
            column_shares=[1, 1],
        ),
        # steps, a timestamped log's too: Rerun labels a time axis every 1 s, 10 s, 1 min,
        # 10 min or 1 h and at least 150 px apart (a 17-minute run's plots get one label),
        # a sequence axis at powers of ten that fit, at any length; ``time`` is a click away
        rrb.TimePanel(
            timeline=style.STEP,
            play_state="following",
            state="collapsed",
        ),
        collapse_panels=True,
    )


def with_legend(
    view: rrb.View | rrb.Container, legend: bool, share: float = 8.0
) -> rrb.View | rrb.Container:
    """A map (or grid of maps) above a strip with the legend of its colours and marks
    (``run/legend``, see :mod:`ekfviz.viz.legend`), where there is one.

    :param share: the maps' height over the legend's (4 lines at 8 in a 1000 px window)
    """
    if not legend:
        return view
    return rrb.Vertical(
        view, rrb.TextDocumentView(name="Legend", origin=style.RUN_LEGEND), row_shares=[share, 1]
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


def run_details(
    label: str,
    prefix: str,
    has: Collection[str],
    axis: rrb.archetypes.TimeAxis | None = None,
    *,
    log: bool = False,
    offline: bool = False,
) -> rrb.Container:
    """A tab of one run of a study: its own plots, correlation matrix and evaluation (and
    its log, with ``log``); ``offline``: see :func:`run_plots`."""
    plots = run_plots(has, prefix=prefix, axis=axis, offline=offline)
    below: list[rrb.View | rrb.Container] = []
    if style.CORRELATION_MATRIX in has:
        below.append(correlation_view(prefix))
    if log and style.LOG in has:
        below.append(log_view([f"{root_of(prefix)}{style.LOG}/**"], name=f"Log: {label}"))
    if style.RUN_EVALUATION in has:
        below.append(
            rrb.TextDocumentView(
                name=f"Evaluation: {label}", origin=f"{root_of(prefix)}{style.RUN_EVALUATION}"
            )
        )
    parts: list[rrb.View | rrb.Container] = [tiles(plots)] if plots else []
    if below:
        parts.append(rrb.Horizontal(*below) if len(below) > 1 else below[0])
    return rrb.Vertical(*parts, row_shares=[3, 2] if len(parts) == 2 else None, name=label)


def study_documents(
    prefixes: Sequence[str], summary: str | None, *, first: Sequence[rrb.View] = ()
) -> list[rrb.View]:
    """The documents of a study: its summary, the log of every run in ``prefixes`` in one
    view, how it was run."""
    views: list[rrb.View] = list(first)
    if summary is not None:
        views.append(rrb.TextDocumentView(name="Summary", origin=summary))
    views += [
        log_view([f"/{style.LOG}/**", *(f"{root_of(p)}{style.LOG}/**" for p in prefixes)]),
        rrb.TextDocumentView(name="Run", origin=style.RUN_INFO),
        rrb.TextDocumentView(name="Input", origin=style.RUN_INPUT),
    ]
    return views


def map_tiles(maps: Sequence[rrb.View]) -> rrb.Container:
    """Maps in rows of about the square root of their number (no empty cell)."""
    columns = max(1, round(len(maps) ** 0.5 + 0.49))
    return tiles(maps, columns=columns)


def _overlaid_plots(
    variants: list[tuple[str, str]],
    what: str,
    *,
    has_truth: bool,
    has_poses: bool,
    axes: Mapping[str, FittedAxis],
    identical: str,
    colours: Sequence[str],
) -> list[rrb.View]:
    """A study's plots of every run overlaid: NIS (with the baseline's 95% bounds), the
    pose NEES where the truth has poses, the mean landmark error where there is truth
    (see :func:`sweep_blueprint` for the arguments)."""
    first = variants[0][1]

    def titled(title: str, path: str | None = None) -> str:
        notes = [axes[path].note] if path is not None and path in axes and axes[path].note else []
        return (
            f"{title} ({'; '.join([*notes, identical] if identical else notes)})"
            if (notes or identical)
            else title
        )

    def overlaid(path: str) -> list[str]:
        return [
            *(f"/{prefix}/{path}" for _, prefix in variants),
            f"/{first}/{path}/{style.LOWER}",
            f"/{first}/{path}/{style.UPPER}",
        ]

    def y_axis(path: str) -> rrb.ScalarAxis | None:
        return rrb.ScalarAxis(range=axes[path].range) if path in axes else None

    plots: list[rrb.View] = [
        rrb.TimeSeriesView(
            name=titled(f"NIS per {what}; grey: {variants[0][0]}'s 95% bounds", style.NIS),
            contents=overlaid(style.NIS),
            axis_y=y_axis(style.NIS),
            plot_legend=NO_LEGEND if colours else SMALL_LEGEND,
        )
    ]
    if has_poses:
        plots.append(
            rrb.TimeSeriesView(
                name=titled(f"Pose NEES per {what}", style.NEES),
                contents=overlaid(style.NEES),
                axis_y=y_axis(style.NEES),
                plot_legend=NO_LEGEND,
            )
        )
    if has_truth:
        plots.append(
            rrb.TimeSeriesView(
                name=titled(f"Mean landmark error [m] per {what}"),
                contents=[f"/{prefix}/{style.MEAN_LANDMARK_ERROR}" for _, prefix in variants],
                plot_legend=NO_LEGEND,
            )
        )
    return plots


def sweep_blueprint(
    variants: list[tuple[str, str]],
    *,
    has_truth: bool,
    bounds_xy: FloatArray | None = None,
    what: str = "variant",
    has_poses: bool = False,
    value_axes: Mapping[str, FittedAxis] | None = None,
    has: Mapping[str, Collection[str]] | None = None,
    summary: str | None = None,
    offline: Collection[str] = (),
    colours: Sequence[str] = (),
    identical: str = "",
    legend: bool = True,
) -> rrb.Blueprint:
    """A grid of maps, one per run (baseline first) and titled with its colour, beside
    overlaid metric plots without legends (they would cover the lines), the study's
    documents and a tab per run.

    :param variants: (label, prefix) of every run, in order
    :param what: what a run is called in the plot titles (``variant``, ``filter``)
    :param has_poses: the truth has poses: a NEES plot too
    :param value_axes: the NIS and NEES axes, fitted to every run's values (see
        :func:`ekfviz.viz.study.study_axes`): the few wild runs would otherwise flatten
        every sensible one; their notes go in the titles
    :param has: per prefix, the entity paths given data (see :func:`run_plots`); None
        leaves out the tabs of the runs
    :param summary: the entity of the study's summary document
    :param offline: the prefixes of offline filters' runs (see :func:`run_plots`)
    :param colours: the name of each run's colour in the plots, for the maps' titles
    :param identical: a note naming the runs whose lines coincide, for the plots' titles
    :param legend: the maps' legend (``run/legend``) is logged: shown beneath them
    """
    maps = [
        map_view(
            bounds_xy,
            prefix=prefix,
            name=f"{label} ({colours[k]})" if k < len(colours) else label,
        )
        for k, (label, prefix) in enumerate(variants)
    ]
    plots = _overlaid_plots(
        variants, what, has_truth=has_truth, has_poses=has_poses, axes=value_axes or {},
        identical=identical, colours=colours,
    )  # fmt: skip
    prefixes = [prefix for _, prefix in variants]
    tabs: list[rrb.View | rrb.Container] = [*study_documents(prefixes, summary)]
    if has is not None:
        tabs += [
            run_details(label, prefix, has[prefix], offline=prefix in offline)
            for label, prefix in variants
        ]
    return rrb.Blueprint(
        rrb.Horizontal(
            # the legend lists every run's colour too: more lines for many runs
            with_legend(map_tiles(maps), legend, share=8.0 if len(variants) <= 4 else 4.0),
            rrb.Vertical(
                *plots,
                rrb.Tabs(*tabs),
                row_shares=[1] * len(plots) + [2],
            ),
            # the summary's table as wide as a comparison's needs at 1600 px (at 5:3 it
            # was cut; a sweep's wider one can be maximised: narrower maps cut their titles)
            column_shares=list(STUDY_COLUMN_SHARES),
        ),
        rrb.TimePanel(timeline=style.STEP, play_state="following", state="collapsed"),
        collapse_panels=True,
    )


def with_panels(
    root: rrb.Container, time_panel: rrb.TimePanel, *, runs_list: bool = False
) -> rrb.Blueprint:
    """A layout with Rerun's side panels collapsed, or with ``runs_list`` the left one
    (the recordings, above the views' tree) shown and only the selection panel collapsed:
    where each run is a recording of its own (``ekfviz watch``), that list is how a user
    goes back to an earlier run."""
    if not runs_list:
        return rrb.Blueprint(root, time_panel, collapse_panels=True)
    return rrb.Blueprint(
        root,
        rrb.BlueprintPanel(state="expanded"),
        rrb.SelectionPanel(state="collapsed"),
        time_panel,
    )
