"""Entity paths and colours of an ekfviz recording, in one place.

Colours follow the classic matplotlib EKF-SLAM plots (white background): magenta
predicted pose ellipse, blue updated one, green landmark ellipses, red ellipse at a
landmark's first sighting, black true landmarks.
"""

from __future__ import annotations

# -- entity paths ----------------------------------------------------------------------

WORLD = "world"
ROBOT = "world/robot"  # Points2D: the current position
HEADING = "world/robot/heading"  # Arrows2D: the heading
POSE_PREDICTED = "world/robot/ellipse/predicted"  # LineStrips2D, at every predict
POSE_UPDATED = "world/robot/ellipse/updated"  # LineStrips2D, at every update and the init
TRAJECTORY = "world/trajectory"  # LineStrips2D, one new segment per event
LANDMARKS = "world/landmarks"  # Points2D, class id = landmark id
LANDMARK_LABELS = "world/landmarks/labels"  # Points2D: "L<id>" just below each 3-sigma outline
LANDMARK_ELLIPSES = "world/landmarks/ellipses"  # LineStrips2D, the whole map (see recorder)
LANDMARK_ELLIPSES_OBSERVED = "world/landmarks/ellipses/observed"  # LineStrips2D, large maps
LANDMARK_INITIAL = "world/landmarks/initial"  # LineStrips2D, at first sighting only
OBSERVATIONS = "world/observations"  # LineStrips2D, robot -> measured landmark position
TRUTH_LANDMARKS = "world/truth/landmarks"  # Points2D, static

METRICS = "metrics"
NIS = "metrics/nis"  # with /lower_95 and /upper_95: the chi-square bounds of each update
NEES = "metrics/nees"  # with true poses; /lower_95 and /upper_95 likewise
LOWER = "lower_95"
UPPER = "upper_95"
POSE_SIGMA = "metrics/pose_sigma"  # /x, /y, /theta
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
RUN_INFO = "run/info"  # TextDocument (markdown), static
RUN_INPUT = "run/input"  # TextDocument (the input log itself), static
RUN_EVALUATION = "run/evaluation"  # TextDocument (markdown), static, at the end

# Entities drawn from the infinite past up to the time cursor instead of latest-at.
ACCUMULATED = (TRAJECTORY, LANDMARK_INITIAL)
# ... and with --history also every robot ellipse: the classic figure
HISTORY = (POSE_PREDICTED, POSE_UPDATED)

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
