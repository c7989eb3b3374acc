"""The correlation matrix of P (core and image) and the history layout."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import entity_rows

from ekfviz.cli import app
from ekfviz.core.correlation import (
    EVERY_STEPS,
    EVERY_UPDATE_STEPS,
    MAX_SIDE,
    SMALL_MAP,
    CorrelationCadence,
    _block_columns_summed,
    block_average,
    correlation_matrix,
    correlation_of,
)
from ekfviz.core.params import FilterParams
from ekfviz.core.records import EventKind
from ekfviz.io.extended import read_log
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, classic_controls, simulate
from ekfviz.viz import style
from ekfviz.viz.blueprint import map_view
from ekfviz.viz.correlation import PALETTE, block_outlines, colormap
from ekfviz.viz.recorder import Recorder


def by_hand(P: np.ndarray) -> np.ndarray:
    n = len(P)
    return np.array([[P[i, j] / math.sqrt(P[i, i] * P[j, j]) for j in range(n)] for i in range(n)])


def image_pixels(row: dict[str, object]) -> np.ndarray:
    """The RGB pixels of a logged correlation image: its palette entries (the class ids
    of a segmentation image) through the palette."""
    buffers, formats = row["SegmentationImage:buffer"], row["SegmentationImage:format"]
    assert isinstance(buffers, list) and isinstance(formats, list)
    shape = (formats[0]["height"], formats[0]["width"])
    pixels: np.ndarray = PALETTE[np.frombuffer(bytes(buffers[0]), dtype=np.uint8).reshape(shape)]
    return pixels


@pytest.fixture(scope="module")
def classic_rrd(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("correlation")
    sim = simulate(classic_controls(), CLASSIC_LANDMARKS_XY, seed=5)
    from ekfviz.io.classic import format_classic

    log = folder / "classic.txt"
    log.write_text(format_classic(list(sim.events)))
    rrd = folder / "classic.rrd"
    app(["replay", str(log), "--save", str(rrd), "--history"], standalone_mode=False)
    return log, rrd


def test_the_image_of_a_6_landmark_run_is_p_correlated_by_hand(
    classic_rrd: tuple[Path, Path],
) -> None:
    """At update event 14, read back from the .rrd: the colours of P's correlations
    computed entry by entry, and at every update of the small map an image."""
    log, rrd = classic_rrd
    records = every_event(replay(read_log(log), FilterParams(), full_cov=True))
    updates = [r for r in records if r.kind is not EventKind.PREDICT]
    assert all(r.correlation is not None for r in updates)
    rows = entity_rows(rrd, f"/{style.CORRELATION_MATRIX}")
    assert [row["event"] for row in rows] == [r.event for r in updates]
    chosen = next(r for r in records if r.event == 14)
    assert chosen.full_cov is not None and chosen.correlation is not None
    expected = by_hand(chosen.full_cov)
    np.testing.assert_allclose(chosen.correlation.matrix, expected, atol=1e-12)
    assert chosen.correlation.factor == 1
    row = next(row for row in rows if row["event"] == 14)
    pixels = image_pixels(row)
    assert pixels.shape == (15, 15, 3)
    np.testing.assert_array_equal(pixels, colormap(expected))
    # the colour scale is fixed: the diagonal is the darkest red, off-diagonal entries not
    assert (pixels[np.arange(15), np.arange(15)] == colormap(np.array([[1.0]]))[0, 0]).all()


def test_the_colour_map_is_diverging_and_fixed_to_minus_one_one() -> None:
    rgb = colormap(np.array([[-1.0, 0.0, 1.0, 2.0, np.nan]])).astype(int)[0]
    blue, white, red, clipped, grey = rgb
    assert blue[2] > blue[0] and red[0] > red[2] and (white > 240).all()
    np.testing.assert_array_equal(clipped, red)
    assert grey[0] == grey[1] == grey[2]


def test_a_large_state_is_block_averaged_to_at_most_200_and_says_so() -> None:
    rng = np.random.default_rng(1)
    A = rng.normal(size=(403, 403))
    P = A @ A.T
    correlation = correlation_of(P, list(range(1, 201)))
    assert correlation.factor == 3 and correlation.matrix.shape == (135, 135)
    assert max(correlation.matrix.shape) <= MAX_SIDE
    C = by_hand(P)
    np.testing.assert_allclose(correlation.matrix[0, 1], C[0:3, 3:6].mean(), atol=1e-12)
    np.testing.assert_allclose(correlation.matrix[-1, -1], C[402, 402], atol=1e-12)  # 1 x 1
    assert "block-averaged" in correlation.describe()
    assert "block-averaged" not in correlation_of(P[:15, :15], [1, 2, 3, 4, 5, 6]).describe()
    _, sizes, labels = block_outlines(correlation)
    assert labels[0] == "pose" and labels[1] == "L1-L7" and len(labels) <= 33
    np.testing.assert_allclose(sizes[0], [1.0, 1.0])  # 3 rows of P in 3-row blocks


def test_block_average_leaves_nan_out_and_keeps_small_matrices() -> None:
    C = np.array([[1.0, np.nan], [np.nan, 1.0]])
    same, factor = block_average(C)
    assert factor == 1 and same is C
    averaged, factor = block_average(C, max_side=1)
    assert factor == 2 and averaged[0, 0] == 1.0


@pytest.mark.parametrize("with_nan", [False, True])
def test_block_average_is_the_mean_of_each_block_ragged_edges_included(with_nan: bool) -> None:
    """Both paths (finite: plain sums and the blocks' sizes; with NaN: finite entries
    counted) against the mean of each block taken one by one, on a side that leaves
    a smaller last block."""
    rng = np.random.default_rng(3)
    C = rng.uniform(-1.0, 1.0, size=(23, 23))
    if with_nan:
        C[4, :] = C[:, 4] = np.nan
        C[20:, 20:] = np.nan  # a last block of NaN only
    averaged, factor = block_average(C, max_side=5)
    assert factor == 5 and averaged.shape == (5, 5)
    for i in range(5):
        for j in range(5):
            block = C[5 * i : 5 * i + 5, 5 * j : 5 * j + 5]
            values = block[np.isfinite(block)]
            if values.size:
                assert averaged[i, j] == pytest.approx(values.mean(), rel=1e-12)
            else:
                assert math.isnan(averaged[i, j])


@pytest.mark.parametrize("factor", range(2, 14))
def test_the_blocks_of_columns_are_summed_to_the_floats_of_numpys_reduction(factor: int) -> None:
    """The strided sums that replace ``sum(axis=2)`` (ten times slower) give its very
    floats: numpy adds fewer than eight terms in order (the recording stays the same);
    from eight on it sums them in pairs, which rounds otherwise, and the reduction
    itself is used."""
    rng = np.random.default_rng(factor)
    side = 7
    padded = rng.normal(size=(side * factor, side * factor)) * 10.0 ** rng.integers(
        -8, 8, size=(side * factor, side * factor)
    )
    reduced = padded.reshape(side * factor, side, factor).sum(axis=2)
    summed = _block_columns_summed(padded, side, factor)
    assert summed.shape == reduced.shape
    assert np.array_equal(summed, reduced)


@pytest.mark.parametrize("n", [7, 120, 601])
def test_correlation_matrix_is_each_entry_scaled_by_both_standard_deviations(n: int) -> None:
    """C = D^-1/2 P D^-1/2 entry by entry, in the order (P_ij s_i) s_j, clipped."""
    rng = np.random.default_rng(n)
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    scale = 1.0 / np.sqrt(np.diagonal(P))
    expected = np.clip((P * scale[:, None]) * scale[None, :], -1.0, 1.0)
    assert np.array_equal(correlation_matrix(P), expected)


def test_cadence_every_update_for_small_maps_then_every_25_steps_and_the_last() -> None:
    cadence = CorrelationCadence()
    assert all(cadence.due(step, SMALL_MAP, last=False) for step in range(10))
    taken = [step for step in range(10, 100) if cadence.due(step, SMALL_MAP + 1, last=False)]
    assert taken == list(range(9 + EVERY_STEPS, 100, EVERY_STEPS))
    assert cadence.due(101, SMALL_MAP + 1, last=True)


def test_cadence_thins_out_a_long_run_of_a_small_map() -> None:
    cadence = CorrelationCadence()
    taken = [step for step in range(3 * EVERY_UPDATE_STEPS) if cadence.due(step, 6, False)]
    assert taken[:EVERY_UPDATE_STEPS] == list(range(EVERY_UPDATE_STEPS))
    later = taken[EVERY_UPDATE_STEPS:]
    assert (
        np.all(np.diff(later) == EVERY_STEPS) and later[0] == EVERY_UPDATE_STEPS - 1 + EVERY_STEPS
    )


def test_history_mode_logs_a_robot_ellipse_per_event_and_accumulates_them(
    classic_rrd: tuple[Path, Path],
) -> None:
    log, rrd = classic_rrd
    events = len(list(read_log(log)))  # the first line initialises: event 0
    # the robot frame's ellipses cannot accumulate: with --history each is an outline too
    predicted = entity_rows(rrd, f"/{style.POSE_PREDICTED_HISTORY}")
    updated = entity_rows(rrd, f"/{style.POSE_UPDATED_HISTORY}")
    assert sorted(int(str(r["event"])) for r in predicted + updated) == list(range(events))
    assert all(len(r["LineStrips2D:strips"]) == 1 for r in predicted + updated)  # type: ignore[arg-type]
    with_history = map_view(history=True).visualizer_overrides
    without = map_view().visualizer_overrides
    assert with_history is not None and without is not None
    for path in style.HISTORY:
        assert f"/{path}" in with_history and f"/{path}" not in without


def test_the_array_api_logs_correlations_too(tmp_path: Path) -> None:
    import rerun as rr

    rec = rr.RecordingStream("correlation_api")
    rrd = tmp_path / "api.rrd"
    rec.save(rrd)
    recorder = Recorder(rec)
    P = np.diag([1.0, 2.0, 3.0, 4.0, 5.0])
    P[0, 3] = P[3, 0] = 1.0
    recorder.initialise(np.zeros(5), P, landmark_ids=[7], z=np.array([[0.1, 2.0]]))
    recorder.finish()
    rec.disconnect()
    rows = entity_rows(rrd, f"/{style.CORRELATION_MATRIX}")
    assert len(rows) == 1
    pixels = image_pixels(rows[0])
    assert pixels.shape == (5, 5, 3)
    np.testing.assert_array_equal(pixels, colormap(by_hand(P)))


def test_the_image_is_coloured_by_classes_of_the_palette(
    classic_rrd: tuple[Path, Path],
) -> None:
    """The segmentation image's classes are the palette: class i has colour PALETTE[i]
    (the viewer colours each pixel by its class), with the first image."""
    _, rrd = classic_rrd
    rows = entity_rows(rrd, f"/{style.CORRELATION_MATRIX}")
    (context,) = [row["AnnotationContext:context"] for row in rows if row.get(
        "AnnotationContext:context") is not None]  # fmt: skip
    assert isinstance(context, list) and len(context) == 1  # one context, 256 classes
    classes = context[0]
    assert len(classes) == len(PALETTE) == 256
    for i, entry in enumerate(classes):
        info = entry["class_description"]["info"]
        assert entry["class_id"] == info["id"] == i
        color = info["color"]  # packed RGBA
        rgb = [(color >> 24) & 0xFF, (color >> 16) & 0xFF, (color >> 8) & 0xFF]
        assert rgb == PALETTE[i].tolist() and color & 0xFF == 0xFF
        # hovering a pixel names its correlation (the last class: NaN's grey)
        label = "undefined" if i == 255 else f"{-1.0 + i * 2.0 / 254:+.3f}"
        assert info["label"] == label
        assert entry["class_description"]["keypoint_annotations"] == []
        assert entry["class_description"]["keypoint_connections"] == []
    assert colormap(np.array([[np.nan]]))[0, 0].tolist() == PALETTE[-1].tolist()


def test_the_colour_indices_are_the_scales_rounded() -> None:
    """The palette entry of each correlation, computed in one buffer, is the plain
    definition's, rint((clip(C, -1, 1) + 1) / 2 * 254), NaN and infinities grey, for
    float64, float32 and integer matrices."""
    from ekfviz.viz.correlation import LUT_SIZE, NAN_INDEX, color_indices

    rng = np.random.default_rng(8)
    values = rng.uniform(-1.3, 1.3, size=(300, 200))
    values[rng.random(values.shape) < 0.01] = np.nan
    values[0, :6] = [np.inf, -np.inf, -0.0, 1.0, -1.0, 2.0 / (LUT_SIZE - 1) * 0.5 - 1.0]
    for matrix in (values, values.astype(np.float32), np.array([[-2, -1, 0, 1, 2]])):
        finite = np.isfinite(matrix)
        scale = (np.clip(np.where(finite, matrix, 0.0), -1.0, 1.0) + 1.0) * 0.5 * (LUT_SIZE - 1)
        expected = np.where(finite, np.rint(scale), NAN_INDEX).astype(np.uint8)
        assert color_indices(matrix).tobytes() == expected.tobytes()  # type: ignore[arg-type]
    assert color_indices(np.array([-1.0, 0.0, 1.0, np.nan])).tolist() == [0, 127, 254, NAN_INDEX]
