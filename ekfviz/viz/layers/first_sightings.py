"""The first-sighting outlines of the landmarks of id-less scans
(``world/landmarks/initial``), drawn once the association confirms a landmark.

Most new landmarks of a cluttered scan are removed again, and their outlines would
bury the map (Victoria Park: 600 of 900): each is held from its first sighting until the
association confirms it (drawn then, at that update) or removes it (dropped). A log
with ids draws its first sightings at once (:mod:`.landmarks`).
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.viz import style
from ekfviz.viz.ellipses import ellipse_outlines, outline_points
from ekfviz.viz.layers.batch import Maps
from ekfviz.viz.layers.canvas import Canvas, Rows
from ekfviz.viz.layers.map_rows import IdRows, JoinedIds, joined_rows

# a first-sighting outline is logged once, and on real data it is metres wide: 16 points
# showed corners there, 32 do not (within 0.5 % of its radius)
INITIAL_POINTS = 32


class FirstSightings:
    """The outlines held until the association decides (see the module)."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas
        # a new landmark's first-sighting outline (mean, covariance), by id
        self._held: dict[int, tuple[FloatArray, FloatArray]] = {}

    def send(
        self,
        rows: Rows,
        corrected: IntArray,
        maps: Maps,
        new_counts: IntArray,
        joined_ids: JoinedIds,
        tables: dict[int, IdRows | None],
    ) -> None:
        """With id-less scans, the first-sighting outline of a landmark appears when the
        association confirms it: most new landmarks of a cluttered scan are removed
        again, and their outlines would bury the map (Victoria Park: 600 of 900).

        :param new_counts: (u,) how many landmarks each update initialised
        :param joined_ids: the landmark id of each row of the joined maps
        :param tables: the id lookups of the batch's maps (see :func:`joined_rows`)
        """
        picks = np.array(
            [i for i in np.flatnonzero(new_counts).tolist() if maps.association(i) is not None],
            dtype=np.int64,
        )
        landmark_ids = joined_ids.all() if len(picks) else np.zeros(0, dtype=np.int64)
        # the rows of each update's new landmarks in the joined maps, for all at once
        new_rows, new_per_update = joined_rows(maps, picks, "initialised", tables)
        new_ends = np.cumsum(new_per_update).tolist()
        new_of = {
            i: new_rows[end - count : end].tolist()
            for i, end, count in zip(picks.tolist(), new_ends, new_per_update.tolist(), strict=True)
        }
        at: list[int] = []
        means: list[FloatArray] = []
        covs: list[FloatArray] = []
        ids: list[list[int]] = []
        for u in sorted(maps.associations):
            k, association = int(corrected[u]), maps.associations[u]
            for row in new_of.get(u, ()):
                self._held[int(landmark_ids[row])] = (
                    maps.xy[row].copy(),
                    maps.covs[row].copy(),
                )
            if len(association.removed):
                for landmark_id in association.removed.tolist():
                    self._held.pop(int(landmark_id), None)
            if not len(association.confirmed):
                continue
            confirmed = [
                (int(i), held)
                for i in association.confirmed.tolist()
                if (held := self._held.pop(int(i), None)) is not None
            ]
            if confirmed:
                at.append(k)
                ids.append([i for i, _ in confirmed])
                means += [mean for _, (mean, _) in confirmed]
                covs += [cov for _, (_, cov) in confirmed]
        if not at:
            return
        counts = np.array([len(group) for group in ids])
        n_points = min(INITIAL_POINTS, outline_points(int(counts.max())))
        outlines = ellipse_outlines(np.array(means), np.array(covs), n_points=n_points)
        self._canvas.send_strips(
            style.LANDMARK_INITIAL, rows, np.array(at, dtype=np.int64), outlines, counts,
            np.array([i for group in ids for i in group], dtype=np.int64),
        )  # fmt: skip
