"""Entity paths and colours of an ekfviz recording, in one place.

Colours follow the classic matplotlib EKF-SLAM plots (white background): magenta
predicted pose ellipse, blue updated one, green landmark ellipses, red ellipse at a
landmark's first sighting, black true landmarks.
"""

from __future__ import annotations

import textwrap

APPLICATION_ID = "ekfviz"  # every recording ekfviz writes

# -- entity paths ----------------------------------------------------------------------

WORLD = "world"
# The robot: a Points2D at its position in the world at every event (what a reader of the
# recording takes as the estimated path), in the same rows a Transform3D (translation,
# rotation) placing the robot frame; the point itself stays in the world's frame (a
# CoordinateFrame in its first row). Everything under ROBOT_FRAME (which holds no data
# of its own) is drawn in the robot frame.
ROBOT = "world/robot"
ROBOT_FRAME = "world/robot/frame"
HEADING = "world/robot/frame/heading"  # Arrows2D along the robot's x axis (static)
# Static unit circle LineStrips2D, mapped onto the 3-sigma ellipse by a Transform3D mat3x3
POSE_PREDICTED = "world/robot/frame/ellipse/predicted"  # at every predict
POSE_UPDATED = "world/robot/frame/ellipse/updated"  # at every update and the init
TRAJECTORY = "world/trajectory"  # LineStrips2D, the path of each step, at its update
LANDMARKS = "world/landmarks"  # Points2D, class id = landmark id
LANDMARK_LABELS = "world/landmarks/labels"  # Points2D: "L<id>" hanging from each landmark
LANDMARK_ELLIPSES = "world/landmarks/ellipses"  # LineStrips2D, the whole map (see recorder)
LANDMARK_ELLIPSES_OBSERVED = "world/landmarks/ellipses/observed"  # LineStrips2D, large maps
LANDMARK_INITIAL = "world/landmarks/initial"  # LineStrips2D, at first sighting only
# Arrows2D in the robot frame, robot -> measured landmark position, at updates
OBSERVATIONS = "world/robot/frame/observations"
TRUTH_LANDMARKS = "world/truth/landmarks"  # Points2D, static
# With true poses, at every step: the true position (Points2D) with the true robot frame
# (Transform3D, as for ROBOT), and the true path, one segment per step
TRUTH_ROBOT = "world/truth/robot"
TRUTH_ROBOT_FRAME = "world/truth/robot/frame"
TRUTH_TRAJECTORY = "world/truth/trajectory"  # LineStrips2D
# ``ekfviz watch``: the run before this one, static and grey (see ekfviz.viz.ghost)
PREVIOUS = "world/previous"

METRICS = "metrics"
NIS = "metrics/nis"  # with /lower_95 and /upper_95: the chi-square bounds of each update
NEES = "metrics/nees"  # with true poses; /lower_95 and /upper_95 likewise
LOWER = "lower_95"
UPPER = "upper_95"
POSE_SIGMA = "metrics/pose_sigma"  # Scalars x, y, theta (three series), every update
LANDMARK_ERROR = "metrics/landmark_error"  # /<id>, with truth
MEAN_LANDMARK_ERROR = "metrics/mean_landmark_error"  # with truth, in sweeps
MAHALANOBIS = "metrics/mahalanobis"  # /<id>, with truth
# mean and worst over the map, with truth, wherever the whole map's errors are logged
LANDMARK_ERROR_SUMMARY = "metrics/landmark_error_summary"  # /mean, /worst
MAHALANOBIS_SUMMARY = "metrics/mahalanobis_summary"  # /mean, /worst
MEAN, WORST = "mean", "worst"
HEALTH = "metrics/health"  # numerical health, see ekfviz.core.health
HEALTH_POSE_MIN_EIG = "metrics/health/pose_min_eigenvalue"  # every event
HEALTH_LANDMARK_MIN_EIG = "metrics/health/landmark_min_eigenvalue"  # every update
HEALTH_SKIPPED = "metrics/health/skipped_observations"  # every update
HEALTH_P_MIN_EIG = "metrics/health/P_min_eigenvalue"  # where the whole P was checked
HEALTH_P_ASYMMETRY = "metrics/health/P_asymmetry"  # likewise: max |P - P^T|
HEALTH_P_LOG10_CONDITION = "metrics/health/P_log10_condition"  # likewise

CORRELATION = "correlation"  # the correlation matrix of P, see ekfviz.viz.correlation
CORRELATION_MATRIX = "correlation/matrix"  # Image (RGB), where the replay took it
CORRELATION_BLOCKS = "correlation/blocks"  # Boxes2D: the diagonal blocks, labelled
CORRELATION_NOTE = "correlation/note"  # TextDocument: what is shown (block-averaged?)

LOG = "log"  # TextLog, one line per event, and one per warning
# the characters of a log line that a layout's log view shows whole at 1600 px (the view
# cuts a line at its edge, and cannot wrap it): a long message goes on several lines
LOG_WIDTH = 80
RUN_INFO = "run/info"  # TextDocument (markdown), static
RUN_INPUT = "run/input"  # TextDocument (the input log itself), static
RUN_EVALUATION = "run/evaluation"  # TextDocument (markdown), static, at the end
RUN_LEGEND = "run/legend"  # TextDocument (markdown), static: the map's colours and marks

# Entities drawn from the infinite past up to the time cursor instead of latest-at.
ACCUMULATED = (TRAJECTORY, LANDMARK_INITIAL, TRUTH_TRAJECTORY)
# ... and with --history also every robot ellipse: the classic figure (the robot frame's
# own ellipses are one unit circle under a transform, which cannot accumulate: with
# --history each is also logged as an outline in the world)
POSE_PREDICTED_HISTORY = "world/history/predicted"  # LineStrips2D, with --history
POSE_UPDATED_HISTORY = "world/history/updated"  # LineStrips2D, with --history
HISTORY = (POSE_PREDICTED_HISTORY, POSE_UPDATED_HISTORY)

# -- timelines -------------------------------------------------------------------------

STEP = "step"
EVENT = "event"
# the log's time in seconds, for timestamped logs: a timestamp for Unix times (MRCLAM),
# else a duration (see ekfviz.viz.recorder.time_is_epoch)
TIME = "time"

# -- colours (RGB) and sizes -----------------------------------------------------------

Rgb = tuple[int, int, int]

BACKGROUND: Rgb = (255, 255, 255)
ROBOT_COLOR: Rgb = (0, 0, 0)
TRAJECTORY_COLOR: Rgb = (0, 0, 255)  # "b-"
PREDICTED_COLOR: Rgb = (255, 0, 255)  # "m"
UPDATED_COLOR: Rgb = (0, 0, 255)  # "b"
LANDMARK_COLOR: Rgb = (0, 128, 0)  # "g"
INITIAL_COLOR: Rgb = (255, 0, 0)  # "r"
OBSERVATION_COLOR: Rgb = (255, 165, 0)
STATISTIC_COLOR: Rgb = (31, 119, 180)  # NIS and NEES
BOUND_COLOR: Rgb = (150, 150, 150)  # their chi-square bounds
TRUTH_COLOR: Rgb = (0, 0, 0)  # "k"
TRUTH_PATH_COLOR: Rgb = (150, 150, 150)  # the true path and robot, thin and grey
# one colour per pose-sigma series (matplotlib's tab10 blue, orange, green)
POSE_SIGMA_COLORS: dict[str, Rgb] = {
    "x": (31, 119, 180),
    "y": (255, 127, 14),
    "theta": (44, 160, 44),
}
SUMMARY_COLORS: dict[str, Rgb] = {"mean": (31, 119, 180), "worst": (214, 39, 40)}
CORRELATION_BLOCK_COLOR: Rgb = (60, 60, 60)

# Negative radii are UI points, so the map looks the same at any scale.
POINT_RADIUS_UI = 4.0
TRUTH_RADIUS_UI = 3.0
ROBOT_RADIUS_UI = 6.0
LINE_RADIUS_UI = 1.0
THIN_LINE_RADIUS_UI = 0.5
LABEL_ANCHOR_RADIUS_UI = 0.5  # the point a landmark's label hangs from


def wrapped(text: str, width: int = LOG_WIDTH) -> list[str]:
    """``text`` cut at spaces into lines of at most ``width`` characters (a word longer
    than that stays whole), later lines indented."""
    lines = textwrap.wrap(
        text, width, subsequent_indent="  ", break_long_words=False, break_on_hyphens=False
    )
    return lines or [text]
