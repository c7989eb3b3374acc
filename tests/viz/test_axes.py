"""The NIS and NEES axes fitted to their data: known answers on generated values."""

from __future__ import annotations

import numpy as np
import pytest

from ekfviz.evaluation.consistency import chi2_bounds
from ekfviz.viz.axes import HEADROOM, SeriesExtent, fitted_axis, study_axis


def test_a_cautious_filter_is_framed_on_its_values_and_the_lower_bound() -> None:
    # NIS of 6 landmarks (12 dof) far below the bounds, as the course log's: the old fit
    # to three times the upper bound drew them flat on zero
    low, high = chi2_bounds(12)
    values = np.random.default_rng(0).uniform(0.05, 0.35, 200)
    axis = fitted_axis([values], [np.full(200, low)], [np.full(200, high)])
    assert axis is not None
    assert axis.range == pytest.approx((0.0, HEADROOM * low))
    assert axis.range[1] < high / 3  # the values fill a tenth of the frame, not 1/70
    assert axis.note == f"upper bound {high:.3g} above"


def test_a_consistent_filter_shows_both_bounds_and_no_note() -> None:
    low, high = chi2_bounds(4)
    values = np.random.default_rng(1).chisquare(4, 2000)
    axis = fitted_axis([values], [np.full(2000, low)], [np.full(2000, high)])
    assert axis is not None and axis.note == ""
    assert axis.range[1] == pytest.approx(HEADROOM * max(high, float(values.max())))


def test_one_exploding_run_is_clipped_and_named_not_flattening_the_others() -> None:
    low, high = chi2_bounds(2)
    rng = np.random.default_rng(2)
    sane = [rng.chisquare(2, 300) for _ in range(3)]
    wild = np.r_[rng.chisquare(2, 297), 1e4, 3e4, 7e4]  # the last 1% of one run
    axis = fitted_axis([*sane, wild], [np.array([low])], [np.array([high])])
    assert axis is not None
    assert axis.range[1] < 20.0  # the sane runs fill the frame
    assert axis.note.startswith(f"clipped at {axis.range[1]:.3g}, largest 7e+04")


def test_no_finite_value_gives_no_axis() -> None:
    assert fitted_axis([], [], []) is None
    assert fitted_axis([np.array([np.nan, np.inf])], [np.array([1.0])], [np.array([5.0])]) is None


def test_an_extent_gathers_batches_and_scalar_bounds() -> None:
    extent = SeriesExtent()
    extent.add(np.array([1.0, 2.0]), 0.5, 9.0)
    extent.add(np.array([6.0]), np.array([0.4]), np.array([8.0]))
    assert [v.tolist() for v in extent.values] == [[1.0, 2.0], [6.0]]
    assert [v.tolist() for v in extent.lowers] == [[0.5], [0.4]]
    axis = fitted_axis(extent.values, extent.lowers, extent.uppers)
    assert axis is not None and axis.range[1] == pytest.approx(HEADROOM * 8.5)


def test_a_study_clips_the_runs_that_explode_at_every_update_and_names_them() -> None:
    # a sweep's variant with R a hundred times too small: its NIS is wild at every update,
    # a tenth of all values, beyond any percentile's reach
    low, high = chi2_bounds(2)
    rng = np.random.default_rng(3)

    def run(scale: float) -> SeriesExtent:
        extent = SeriesExtent()
        extent.add(scale * rng.chisquare(2, 100), low, high)
        return extent

    runs = [(f"variant {k}", run(1.0 + 0.1 * k)) for k in range(9)]
    runs.append(("sigma_range /10", run(100.0)))
    axis = study_axis(runs)
    assert axis is not None
    assert axis.range[1] < 30.0  # the nine sane runs fill the frame (the wild one: 1000s)
    assert axis.note.endswith("sigma_range /10 above, clipped")
    tame = study_axis(runs[:9])
    assert tame is not None and "clipped" not in tame.note
