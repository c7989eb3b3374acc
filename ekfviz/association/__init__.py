"""Data association for id-less scans (numpy only): which landmark each measurement is.

- :mod:`~ekfviz.association.gating`: every landmark's predicted measurement and
  innovation covariance from the filter's x and P with ekfviz's own measurement model,
  and the individual compatibility (Mahalanobis gate) of each measurement with each;
- :mod:`~ekfviz.association.nn`: nearest neighbour, each landmark used once per scan;
- :mod:`~ekfviz.association.jcbb`: Joint Compatibility Branch and Bound (Neira and
  Tardos 2001), bounded by a budget of search nodes;
- :mod:`~ekfviz.association.tentative`: new landmarks stay tentative until confirmed;
- :mod:`~ekfviz.association.associator`: one scan through all of it, for the runner.

The association never touches P: it returns a pairing and what it rejected, and the
runner folds the pairing into the filter.
"""

from typing import TYPE_CHECKING

from ekfviz.association.params import AssociationError, AssociationParams, Method

if TYPE_CHECKING:
    from ekfviz.association.associator import Associator

__all__ = ["AssociationError", "AssociationParams", "Associator", "Method"]


def __getattr__(name: str) -> object:
    """``Associator`` when first asked for: a replay of a log with ids asks for the
    parameters alone and never loads the association (see ``tests/test_startup.py``)."""
    if name == "Associator":
        from ekfviz.association.associator import Associator

        return Associator
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
