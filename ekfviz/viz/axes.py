"""The y range of a NIS or NEES plot, fitted to its data, and what it leaves out.

A fit to the largest value lets one outlier (or one wild filter of a comparison) flatten
every other line at zero; a fit to three times the 95% upper bound of many landmarks
(chi-square of 12 or more dof) does the same to a filter whose values are small. The
range here takes the 99th percentile of the values and the typical lower bound, and the
upper bound and the largest value where they are near; what lies above is named in the
plot's title.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ekfviz.core.types import FloatArray

HEADROOM = 1.1  # the frame's top above the highest value it is fitted to
UPPER_REACH = 2.0  # the upper bound is framed while it is at most this times the data's top


@dataclass
class SeriesExtent:
    """The values of a statistic and its 95% bounds, gathered over a run."""

    values: list[FloatArray] = field(default_factory=list)
    lowers: list[FloatArray] = field(default_factory=list)
    uppers: list[FloatArray] = field(default_factory=list)

    def add(self, values: FloatArray, lower: FloatArray | float, upper: FloatArray | float) -> None:
        """Take in some values and their bounds (one each, or one for all)."""
        self.values.append(np.asarray(values, dtype=np.float64).ravel())
        self.lowers.append(np.atleast_1d(np.asarray(lower, dtype=np.float64)))
        self.uppers.append(np.atleast_1d(np.asarray(upper, dtype=np.float64)))


@dataclass(frozen=True, slots=True)
class FittedAxis:
    """A plot's y range and a note on what it leaves out (empty when nothing)."""

    range: tuple[float, float]
    note: str


def fitted_axis(
    values: Sequence[FloatArray], lowers: Sequence[FloatArray], uppers: Sequence[FloatArray]
) -> FittedAxis | None:
    """The y range from 0 that shows a statistic's bulk and its bounds where they are near.

    :param values: arrays of the statistic (NaN and inf ignored), one per run or batch
    :param lowers: arrays of its 95% lower bounds, likewise; ``uppers`` the upper ones
    :return: the range to ``HEADROOM`` x max(99th percentile, median lower bound, and the
        median upper bound and the largest value where within ``UPPER_REACH`` of those),
        and a note naming the values clipped and an upper bound left above; None without
        a finite value
    """
    finite = _finite(values)
    if not finite.size:
        return None
    lower = _median(lowers)
    upper = _median(uppers)
    top = max(float(np.percentile(finite, 99.0)), lower)
    if upper <= UPPER_REACH * top or top <= 0.0:
        top = max(top, upper)
    largest = float(finite.max())
    if largest <= UPPER_REACH * top:  # a tail, not an outlier: shown whole
        top = max(top, largest)
    top = HEADROOM * top if top > 0.0 else 1.0
    notes = []
    if largest > top:
        notes.append(f"clipped at {top:.3g}, largest {largest:.3g}")
    if upper > top:
        notes.append(f"upper bound {upper:.3g} above")
    return FittedAxis((0.0, top), "; ".join(notes))


def fitted_axes(extents: Mapping[str, SeriesExtent]) -> dict[str, FittedAxis]:
    """:func:`fitted_axis` of every series with a finite value, by entity path."""
    return {
        path: axis
        for path, extent in extents.items()
        if (axis := fitted_axis(extent.values, extent.lowers, extent.uppers)) is not None
    }


WILD_RUN = 5.0  # a study's run whose own fitted top is this times the median run's: clipped


def study_axis(runs: Sequence[tuple[str, SeriesExtent]]) -> FittedAxis | None:
    """The y range of a study's overlaid runs: fitted to the runs that are not wild, a
    run being wild where its own fitted top is ``WILD_RUN`` times the median run's (a
    percentile of all values does not clip a run that explodes at every update).

    :param runs: (label, extent) of every run with values
    :return: the range (see :func:`fitted_axis`), its note naming the wild runs clipped
    """
    own = [
        (label, extent, axis)
        for label, extent in runs
        if (axis := fitted_axis(extent.values, extent.lowers, extent.uppers)) is not None
    ]
    if not own:
        return None
    middle = float(np.median([axis.range[1] for _, _, axis in own]))
    wild = [label for label, _, axis in own if axis.range[1] > WILD_RUN * middle]
    tame = [extent for label, extent, _ in own if label not in wild]
    fitted = fitted_axis(
        [v for e in tame for v in e.values],
        [v for e in tame for v in e.lowers],
        [v for e in tame for v in e.uppers],
    )
    if fitted is None or not wild:
        return fitted
    named = ", ".join(wild[:2]) + (f" and {len(wild) - 2} more" if len(wild) > 2 else "")
    notes = [note for note in (fitted.note, f"{named} above, clipped") if note]
    return FittedAxis(fitted.range, "; ".join(notes))


def _median(arrays: Sequence[FloatArray]) -> float:
    """The median of the finite values of some arrays, 0 without one."""
    finite = _finite(arrays)
    return float(np.median(finite)) if finite.size else 0.0


def _finite(arrays: Sequence[FloatArray]) -> FloatArray:
    """The finite values of some arrays, joined."""
    parts = [np.asarray(a, dtype=np.float64).ravel() for a in arrays]
    joined = np.concatenate(parts) if parts else np.zeros(0)
    finite: FloatArray = joined[np.isfinite(joined)]
    return finite
