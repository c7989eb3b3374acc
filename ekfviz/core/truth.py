"""Ground truth: the true landmarks and, when known, the true poses of a run."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import BoolArray, FloatArray, IntArray


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """True landmark positions: ``ids`` (K,), ``landmarks_xy`` (K, 2); and, when known,
    the true poses ``poses_xytheta`` (T+1, 3), one per step (step 0 = start), and the
    noise levels and prior a simulator used (``simulated_with``, by filter parameter name:
    ``sigma_x`` ... ``sigma_range``, ``init_pose_sigma``); for id-less scans, ``scan_ids``:
    per scan line the true landmark id of each measurement, None for clutter.

    A timestamped truth (a motion-capture track) gives the true pose by time instead:
    ``track_times`` (T,) seconds, ascending, and ``track_xytheta`` (T, 3); the pose of an
    event is interpolated there (:meth:`pose_at`)."""

    ids: IntArray
    landmarks_xy: FloatArray
    poses_xytheta: FloatArray | None = None
    simulated_with: dict[str, float | list[float]] | None = None
    scan_ids: tuple[tuple[int | None, ...], ...] | None = None
    track_times: FloatArray | None = None
    track_xytheta: FloatArray | None = None

    @property
    def has_poses(self) -> bool:
        """Whether the truth knows true poses (per step, or by time)."""
        return self.poses_xytheta is not None or self.track_times is not None

    def pose_at(self, time: float) -> FloatArray | None:
        """The true pose (3,) at ``time`` on the track, or None outside it (or without one).

        Linear between the two samples around ``time``; the heading on the circle (the
        shorter way round), wrapped to (-pi, pi].
        """
        times, poses = self.track_times, self.track_xytheta
        if times is None or poses is None or not times[0] <= time <= times[-1]:
            return None
        k = int(np.searchsorted(times, time, side="right")) - 1
        if k >= len(times) - 1:
            last: FloatArray = poses[-1].copy()
            return last
        span = times[k + 1] - times[k]
        w = 0.0 if span <= 0.0 else (time - times[k]) / span
        a, b = poses[k], poses[k + 1]
        turn = math.remainder(float(b[2] - a[2]), 2.0 * math.pi)
        heading = math.remainder(float(a[2]) + w * turn, 2.0 * math.pi)
        if heading == -math.pi:
            heading = math.pi
        return np.array([a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), heading])

    def pose_of(self, step: int, time: float | None) -> FloatArray | None:
        """The true pose of an event: by its time on a track, else by its step."""
        if self.track_times is not None:
            return None if time is None else self.pose_at(time)
        if self.poses_xytheta is None or step >= len(self.poses_xytheta):
            return None
        pose: FloatArray = self.poses_xytheta[step]
        return pose

    def poses_of(self, steps: IntArray, times: FloatArray) -> tuple[FloatArray, BoolArray]:
        """:meth:`pose_of` of many events (``times`` NaN where an event has none): their
        true poses (k, 3), and which have one (the others' rows are NaN)."""
        out = np.full((len(steps), 3), np.nan)
        if self.track_times is not None:  # by time, one at a time
            for k, time in enumerate(times.tolist()):
                if not math.isnan(time) and (pose := self.pose_at(time)) is not None:
                    out[k] = pose
        elif self.poses_xytheta is not None:
            inside = steps < len(self.poses_xytheta)
            out[inside] = self.poses_xytheta[steps[inside]]
        return out, ~np.isnan(out[:, 0])

    def lookup(self, ids: IntArray) -> FloatArray:
        """True positions (len(ids), 2) of the given ids, NaN where the truth has none."""
        # vectorised: this runs at every update of a replay with truth
        ids = np.asarray(ids, dtype=np.int64)
        order = np.argsort(self.ids, kind="stable")
        sorted_ids = self.ids[order]
        at = np.minimum(np.searchsorted(sorted_ids, ids), max(len(sorted_ids) - 1, 0))
        found = (sorted_ids[at] == ids) if len(sorted_ids) else np.zeros(len(ids), dtype=bool)
        out = np.full((len(ids), 2), np.nan)
        out[found] = self.landmarks_xy[order[at[found]]]
        return out
