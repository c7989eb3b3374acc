"""What an observation line does to the filter: by its landmark ids, or, for a scan of
unknown landmarks, through the association."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Observations, Scan, ScanAssociation, Sighting, frozen
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.plugged import Plugged

if TYPE_CHECKING:  # the association is loaded by a log with scans (or --gate) only
    from ekfviz.association.associator import Associator

GATE_ON_SCANS = (
    "--gate {gate:g} gates observations by landmark id; a scan's measurements are gated by"
    " the association (--gate-probability), not by it"
)

# what folding a line in gives: what was done with each observation, the association's
# decision (a scan's), and the line's warnings (the observations gated out, the filter's)
Observed = tuple[Observations, ScanAssociation | None, tuple[str, ...]]


class Observer:
    """Folds observation lines into a filter.

    :param ekf: the filter
    :param params: ``gate`` drops, by landmark id, the observations whose NIS exceeds it
    :param associator: pairs the measurements of scans with landmarks; None: a log with
        ids only
    """

    def __init__(
        self, ekf: EkfSlam | Plugged, params: FilterParams, associator: Associator | None
    ) -> None:
        self._ekf = ekf
        self._gate, self._R = params.gate, params.R
        self._associator = associator
        self._gate_said = False  # --gate on a log of scans: said at the first

    def observe(self, event: Sighting | Scan, last: bool) -> Observed:
        """Fold the line ``event`` in (the run's last where ``last``)."""
        ekf, gate = self._ekf, self._gate
        if gate is None and type(event) is Sighting:  # by its ids: the common case, at once
            return ekf.observe(event.ids, event.z), None, ekf.warnings
        rejected: tuple[str, ...] = ()
        if gate is not None and isinstance(event, Sighting):
            from ekfviz.association.gating import gated  # --gate only

            event, rejected = gated(ekf.x, ekf.P, ekf.landmark_ids, event, self._R, gate)
        elif gate is not None and not self._gate_said and isinstance(event, Scan):
            self._gate_said = True  # said once, at the first scan
            rejected = (GATE_ON_SCANS.format(gate=gate),)
        observations, association = self.fold(event, last)
        return observations, association, rejected + ekf.warnings

    def fold(
        self, event: Sighting | Scan, last: bool
    ) -> tuple[Observations, ScanAssociation | None]:
        """Fold an observation in, ungated: by its ids, or a scan through the
        association (any filter: a protocol one with ``remove_landmarks`` for tentative
        landmarks), with what the association decided (None for an observation by ids).
        At the run's last event, the landmarks still tentative are removed."""
        ekf = self._ekf
        if isinstance(event, Sighting):
            return ekf.observe(event.ids, event.z), None
        associator = self._associator
        if associator is None:
            raise FilterError("a scan has no landmark ids: it needs --association nn or jcbb")
        from ekfviz.association.associator import Associator
        from ekfviz.association.params import AssociationError

        if isinstance(ekf, Plugged):  # at the first scan: a log with ids needs no removal
            try:
                Associator.check_filter(ekf, associator.params)
            except AssociationError as error:
                raise FilterError(f"filter {ekf.name}: {error}") from error
        observations, association = associator.process(ekf, event)
        if last:  # the end of the run: nothing tentative is left in the map
            removed = associator.finish(ekf)
            if removed:
                both = np.union1d(association.removed, removed)
                association = replace(association, removed=frozen(both), tentative=frozen(both[:0]))
        return observations, association

    def finish(self) -> None:
        """The run ends at a motion: the landmarks still tentative are removed."""
        if self._associator is not None and isinstance(self._ekf, EkfSlam):
            self._associator.finish(self._ekf)
