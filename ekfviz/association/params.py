"""What the association is asked to do: its method and parameters (imported without the
association itself, which a replay of a log with ids never loads)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from ekfviz.core.errors import UsageError

DEFAULT_BUDGET = 10_000  # JCBB's hypotheses per scan
# JCBB's units of work per scan, (2p + 2)^2 per hypothesis of p pairs: about 0.1-0.3 s of
# numpy on a laptop core; a first, greedy descent through 150 measurements needs 18 million.
DEFAULT_WORK_BUDGET = 40_000_000


class Method(str, enum.Enum):
    """How the measurements of a log are paired with landmarks."""

    KNOWN = "known"  # the log names them (observe lines)
    NN = "nn"
    JCBB = "jcbb"


class AssociationError(UsageError):
    """The association cannot run as asked (a filter without landmark removal, ...)."""


@dataclass(frozen=True, slots=True)
class AssociationParams:
    """Options of the association; the defaults are those of ``ekfviz replay``.

    :param method: nn or jcbb (known does not use an associator)
    :param gate_probability: of the individual gate (chi-square, 2 dof) and of JCBB's
        joint gate (2p dof)
    :param confirm: K, compatible sightings (the first included) that confirm a new landmark
    :param confirm_window: W, scans from its first in which it must get them, or be removed
    :param new_probability: a measurement inside any landmark's gate at this probability
        does not start a landmark (it is rejected when it is not paired)
    :param budget: JCBB's hypotheses per scan (see :mod:`ekfviz.association.jcbb`)
    :param work_budget: JCBB's units of work per scan (likewise); past either budget
        the scan falls back (to the best pairing found, else nearest neighbour)
    :param single_gate_area: m^2, the largest gate (at ``gate_probability``, in the
        plane) of a landmark that JCBB may pair on its own, one measurement in the scan's
        pairing; larger gates need a joint pairing of two or more
    :param wide_pairs: how many pairs with wide gates a pairing needs to keep them
    """

    method: Method = Method.JCBB
    gate_probability: float = 0.99
    confirm: int = 3
    confirm_window: int = 6
    new_probability: float = 0.9999
    budget: int = DEFAULT_BUDGET
    work_budget: int = DEFAULT_WORK_BUDGET
    single_gate_area: float = 20.0
    wide_pairs: int = 3

    def as_dict(self) -> dict[str, object]:
        return {
            "association": self.method.value,
            "gate_probability": self.gate_probability,
            "confirm": self.confirm,
            "confirm_window": self.confirm_window,
            "new_landmark_gate_probability": self.new_probability,
            "jcbb_budget": self.budget,
            "jcbb_work_budget": self.work_budget,
            "single_gate_area_m2": self.single_gate_area,
            "wide_pairs": self.wide_pairs,
        }
