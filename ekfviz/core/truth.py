"""Ground truth: the true landmarks and, when known, the true poses of a run."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray, IntArray


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """True landmark positions: ``ids`` (K,), ``landmarks_xy`` (K, 2); and, when known,
    the true poses ``poses_xytheta`` (T+1, 3), one per step (step 0 = start), and the
    noise levels and prior a simulator used (``simulated_with``, by filter parameter name:
    ``sigma_x`` ... ``sigma_range``, ``init_pose_sigma``); for id-less scans, ``scan_ids``:
    per scan line the true landmark id of each measurement, None for clutter."""

    ids: IntArray
    landmarks_xy: FloatArray
    poses_xytheta: FloatArray | None = None
    simulated_with: dict[str, float | list[float]] | None = None
    scan_ids: tuple[tuple[int | None, ...], ...] | None = None

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
