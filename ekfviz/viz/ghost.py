"""The run before this one, greyed in the map: what an edit changed shows at a glance.

``ekfviz watch`` records every run of a check as a recording of its own. Each holds the
previous run's path and final map as a ghost, static, in the checked filter's map:

| entity | what |
|---|---|
| ``<prefix>/world/previous/trajectory`` | the previous run's path, grey, labelled with its run |
| ``<prefix>/world/previous/landmarks`` | its final landmark means, grey |
| ``<prefix>/world/previous/ellipses`` | its final 3-sigma outlines (landmarks and pose), grey |
| ``<prefix>/world/previous`` | the classes naming the three on hover (its annotation context) |
| ``log/watch`` | the run's verdict, causes or error, for the log view |

A run that could not check anything (a syntax error) is a recording of the ghost, the
error and the layout only (:func:`record_failure`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ekfviz.core.batch import EventBatch
from ekfviz.core.types import FloatArray
from ekfviz.viz import style
from ekfviz.viz.annotations import annotation_context
from ekfviz.viz.blueprint import log_view, map_view, with_panels
from ekfviz.viz.ellipses import ellipse_outlines
from ekfviz.viz.recording import Recording, finish_recorders

TRAJECTORY = f"{style.PREVIOUS}/trajectory"
LANDMARKS = f"{style.PREVIOUS}/landmarks"
ELLIPSES = f"{style.PREVIOUS}/ellipses"
LOG = f"{style.LOG}/watch"  # under the log: its view shows it

# lighter than the check's "expected" outlines (110) and the true path (150): behind all
GHOST_COLOR: style.Rgb = (185, 185, 185)
# the class id of each part of the ghost, in the context of ``world/previous``
GHOST_CLASS = {TRAJECTORY: 0, LANDMARKS: 1, ELLIPSES: 2}


@dataclass(frozen=True, slots=True)
class Ghost:
    """A run's path and final map, to draw behind a later run.

    :param label: which run it was (``run 3``)
    :param path_xy: (K, 2) the robot's position at every event
    :param landmarks_xy: (N, 2) the final landmark means
    :param covs: (N + 1, 2, 2) their final covariances, then the final pose's (x, y)
    """

    label: str
    path_xy: FloatArray
    landmarks_xy: FloatArray
    covs: FloatArray

    @classmethod
    def of(cls, records: EventBatch, label: str) -> Ghost | None:
        """The ghost of a run's records; None for a run without any."""
        if not len(records):
            return None
        last = records.last
        path = np.array(records.poses[:, :2], dtype=np.float64)
        covs = np.concatenate([last.landmark_covs.reshape(-1, 2, 2), last.pose_cov[None, :2, :2]])
        return cls(label, path, np.asarray(last.landmarks_xy).reshape(-1, 2), covs)

    @property
    def means_xy(self) -> FloatArray:
        """(N + 1, 2) the centres of :attr:`covs`: the landmarks, then the final pose."""
        return np.vstack([self.landmarks_xy, self.path_xy[-1:]])


def map_note(ghost: Ghost | None) -> str:
    """What a map's title says of the ghost drawn in it (its legend)."""
    return "" if ghost is None else f" (grey: {ghost.label})"


def log_ghost(rec: rr.RecordingStream, prefix: str, ghost: Ghost) -> None:
    """Log ``ghost`` under ``<prefix>/world/previous``, static and grey."""
    root = f"{prefix.strip('/')}/" if prefix.strip("/") else ""
    rec.log(  # what hovering each part names it, "<label>: ..." ("run 3: its path")
        f"{root}{style.PREVIOUS}",
        annotation_context(
            list(GHOST_CLASS.values()),
            [
                f"{ghost.label}: its estimated path",
                f"{ghost.label}: its landmarks at the end",
                f"{ghost.label}: its 3σ at the end",
            ],
        ),
        static=True,
    )
    rec.log(
        f"{root}{TRAJECTORY}",
        rr.LineStrips2D(
            [ghost.path_xy],
            colors=[GHOST_COLOR],
            radii=rr.Radius.ui_points(style.LINE_RADIUS_UI),
            labels=[ghost.label],
            show_labels=True,
            class_ids=GHOST_CLASS[TRAJECTORY],
        ),
        static=True,
    )
    if len(ghost.landmarks_xy):
        rec.log(
            f"{root}{LANDMARKS}",
            rr.Points2D(
                ghost.landmarks_xy,
                colors=[GHOST_COLOR],
                radii=rr.Radius.ui_points(style.POINT_RADIUS_UI),
                class_ids=GHOST_CLASS[LANDMARKS],
                show_labels=False,
            ),
            static=True,
        )
    rec.log(
        f"{root}{ELLIPSES}",
        rr.LineStrips2D(
            list(ellipse_outlines(ghost.means_xy, ghost.covs)),
            colors=[GHOST_COLOR],
            radii=rr.Radius.ui_points(style.THIN_LINE_RADIUS_UI),
            class_ids=GHOST_CLASS[ELLIPSES],
            show_labels=False,
        ),
        static=True,
    )


def log_lines(rec: rr.RecordingStream, lines: Sequence[str], level: str) -> None:
    """The run's verdict (or error) as lines of the log view, at its first event: the
    first at ``level`` (``INFO``, ``WARN``, ``ERROR``), the rest its continuation."""
    rec.set_time(style.STEP, sequence=0)
    rec.set_time(style.EVENT, sequence=0)
    said = level
    for line in lines:
        for part in style.wrapped(line):
            rec.log(LOG, rr.TextLog(part, level=said))
            said = ""  # (a continuation: no level of its own, as check's lines)


def record_failure(
    recording: Recording,
    prefix: str,
    label: str,
    ghost: Ghost | None,
    lines: Sequence[str],
) -> None:
    """A run that checked nothing: its error in the log, the ghost of the run before in
    an otherwise empty map (``prefix``: where the checked filter's map is), the layout;
    the recording is then complete."""
    rec = recording.rec
    root = prefix.strip("/")
    # as a run's own recorder does: a 2-D view draws y down, the world is mirrored
    rec.log(f"{root}/{style.WORLD}", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
    if ghost is not None:
        log_ghost(rec, prefix, ghost)
    log_lines(rec, lines, "ERROR")
    finish_recorders(recording, [])
    rec.send_blueprint(
        with_panels(  # a run of ``ekfviz watch``: the list of runs shown
            rrb.Horizontal(
                map_view(prefix=prefix, name=f"{label}{map_note(ghost)}"),
                rrb.Vertical(
                    log_view(),
                    rrb.TextDocumentView(name="Run", origin=style.RUN_INFO),
                    row_shares=[2, 1],
                ),
                column_shares=[3, 2],
            ),
            rrb.TimePanel(timeline=style.EVENT, state="collapsed"),
            runs_list=True,
        )
    )
