"""Simulated classic runs with what the tests of a run's batches vary in them (a map that
grows, a skipped observation, times, a stretch of predicts alone), and their truth."""

from __future__ import annotations

import numpy as np

from ekfviz.core.records import Control, LogEvent, Sighting
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, classic_controls, simulate


def classic_run(
    steps: int,
    landmarks_xy: FloatArray = CLASSIC_LANDMARKS_XY,
    *,
    seed: int,
    timed: bool = False,
    only_controls_from: int | None = None,
    first_seen: int = 0,
    zero_range_at: int | None = None,
) -> list[LogEvent]:
    """The classic route among ``landmarks_xy`` for ``steps`` controls: with times (a
    tenth of a second a control: the thinning drops some predicts), with its observations
    left out from step ``only_controls_from`` on (a long stretch of predicts alone), with
    the second half of the landmarks left out of the observations before step
    ``first_seen`` (the map grows there), or with one observation of range 0 at step
    ``zero_range_at`` (skipped, with a warning)."""
    controls = np.tile(classic_controls(), (steps // 29 + 1, 1))[:steps]
    sim = simulate(controls, landmarks_xy, seed=seed)
    half = len(landmarks_xy) // 2
    out: list[LogEvent] = []
    step = 0
    for event in sim.events:
        if isinstance(event, Control):
            step += 1
            if timed:
                event = Control(event.line, event.d, event.alpha, 0.1 * step, 0.1)
            out.append(event)
            continue
        assert isinstance(event, Sighting)
        if only_controls_from is not None and step >= only_controls_from:
            continue
        ids, z = event.ids, event.z
        if step < first_seen:
            ids, z = ids[:half], z[:half]
        if step == zero_range_at:
            z = z.copy()
            z[1, 1] = 0.0
        out.append(Sighting(event.line, ids, z, 0.1 * step + 0.05 if timed else None))
    return out


def classic_truth(steps: int, *, seed: int, cut: int | None = None) -> GroundTruth:
    """The truth of :func:`classic_run` among the classic landmarks (its landmarks and
    true poses), the poses after step ``cut`` left out."""
    controls = np.tile(classic_controls(), (steps // 29 + 1, 1))[:steps]
    sim = simulate(controls, CLASSIC_LANDMARKS_XY, seed=seed)
    poses = sim.poses_xytheta if cut is None else sim.poses_xytheta[: cut + 1]
    return GroundTruth(ids=sim.landmark_ids, landmarks_xy=sim.landmarks_xy, poses_xytheta=poses)
