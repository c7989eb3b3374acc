"""Tentative landmarks: a new landmark must be seen again before it counts.

A measurement that no landmark explains starts a tentative landmark (in the filter's
state from the start, so that its next sightings can be associated with it). It is
confirmed once it has ``confirm`` compatible sightings (its first included) within its
first ``window`` scans, and removed from the state when its window ends before that.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(slots=True)
class TentativeBook:
    """Which landmarks are tentative, since when, and how often they were seen.

    :param confirm: K, sightings needed (1: every new landmark is confirmed at once)
    :param window: W, scans from a landmark's first (included) in which to get them
    """

    confirm: int
    window: int
    scan: int = 0  # index of the current scan, from 1
    _born: dict[int, int] = field(default_factory=dict)  # tentative id -> scan of birth
    _seen: dict[int, int] = field(default_factory=dict)  # tentative id -> sightings

    @property
    def tentative(self) -> list[int]:
        return sorted(self._born)

    def is_tentative(self, landmark_id: int) -> bool:
        return landmark_id in self._born

    def next_scan(self) -> None:
        self.scan += 1

    def settle(self, matched: list[int], new: list[int]) -> tuple[list[int], list[int]]:
        """Count this scan's sightings, confirm and expire.

        :param matched: landmarks paired with a measurement at this scan
        :param new: landmarks started at this scan
        :return: (confirmed, removed) at this scan
        """
        confirmed: list[int] = []
        for landmark_id in matched:
            if landmark_id in self._seen:
                self._seen[landmark_id] += 1
        for landmark_id in new:
            self._born[landmark_id] = self.scan
            self._seen[landmark_id] = 1
        for landmark_id in list(self._born):
            if self._seen[landmark_id] >= self.confirm:
                confirmed.append(landmark_id)
                del self._born[landmark_id], self._seen[landmark_id]
        removed = [
            landmark_id
            for landmark_id, born in self._born.items()
            if self.scan - born + 1 >= self.window
        ]
        for landmark_id in removed:
            del self._born[landmark_id], self._seen[landmark_id]
        return sorted(confirmed), sorted(removed)

    def drop_all(self) -> list[int]:
        """The end of the run: every landmark still tentative is removed."""
        removed = sorted(self._born)
        self._born.clear()
        self._seen.clear()
        return removed
