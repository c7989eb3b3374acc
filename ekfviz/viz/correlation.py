"""The correlation matrix of P as an image: a fixed diverging colour map, labelled blocks.

Each matrix a replay took (see :mod:`ekfviz.core.correlation`) is logged at its event
under ``correlation/``: the image (``matrix``, -1 blue, 0 white, +1 red, whatever the
run: the colours are fixed to [-1, 1] so that images of different events and runs
compare; a segmentation image of palette entries, coloured by classes), an outline per
block along the diagonal labelled ``pose`` and ``L<id>`` (groups of consecutive
landmarks beyond ``MAX_LABELLED_BLOCKS``), and one sentence on what is shown, which says
when the matrix was block-averaged.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.correlation import Correlation
from ekfviz.core.types import FloatArray
from ekfviz.viz import style
from ekfviz.viz.annotations import annotation_context
from ekfviz.viz.layers.arrow import column
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Canvas

MAX_LABELLED_BLOCKS = 32  # landmark blocks (or groups of them) outlined and labelled
NAN_RGB = (160, 160, 160)  # a correlation with a zero variance: undefined

# ColorBrewer's RdBu, from -1 (dark blue) through 0 (near white) to +1 (dark red)
_ANCHORS = np.array(
    [
        (5, 48, 97), (33, 102, 172), (67, 147, 195), (146, 197, 222), (209, 229, 240),
        (247, 247, 247),
        (253, 219, 199), (244, 165, 130), (214, 96, 77), (178, 24, 43), (103, 0, 31),
    ],
    dtype=np.float64,
)  # fmt: skip
LUT_SIZE = 255  # colours of [-1, 1]; with NaN's grey, class ids 0..255 (see below)
_LUT: npt.NDArray[np.uint8] = np.rint(
    np.column_stack(
        [
            np.interp(
                np.linspace(0.0, 1.0, LUT_SIZE), np.linspace(0.0, 1.0, len(_ANCHORS)), channel
            )
            for channel in _ANCHORS.T
        ]
    )
).astype(np.uint8)
PALETTE: npt.NDArray[np.uint8] = np.vstack([_LUT, np.array([NAN_RGB], dtype=np.uint8)])
NAN_INDEX = LUT_SIZE
# The Arrow types of a segmentation image's pixels and format, from the SDK's conversion
_SAMPLE = {
    batch.component_descriptor(): batch.as_arrow_array()
    for batch in rr.SegmentationImage(np.zeros((1, 1), np.uint8)).as_component_batches()
}
_BUFFER = _SAMPLE[rr.SegmentationImage.descriptor_buffer()].type
_FORMAT = _SAMPLE[rr.SegmentationImage.descriptor_format()].type
_U8 = _SAMPLE[rr.SegmentationImage.descriptor_format()].field("channel_datatype")[0].as_py()


def color_indices(C: FloatArray) -> npt.NDArray[np.uint8]:
    """Entries of ``PALETTE`` of correlations, the colour scale fixed to [-1, 1]; NaN grey.

    :param C: (m, k) values in [-1, 1]
    :return: (m, k) uint8
    """
    finite = np.isfinite(C)
    # rint((clip(C) + 1) * 0.5 * (LUT_SIZE - 1)), the same operations in the same order in
    # one buffer: a replay's matrices make millions of pixels, and each temporary of them
    # cost as much as the arithmetic
    values = np.clip(C, -1.0, 1.0)
    if not np.issubdtype(values.dtype, np.floating):  # (integers: as in float64)
        values = values.astype(np.float64)
    values[~finite] = 0.0
    values += 1.0
    values *= 0.5
    values *= LUT_SIZE - 1
    np.rint(values, out=values)
    index = values.astype(np.uint8)
    index[~finite] = NAN_INDEX
    return index


def colormap(C: FloatArray) -> npt.NDArray[np.uint8]:
    """RGB of correlations, the colour scale fixed to [-1, 1]; NaN grey.

    :param C: (m, k) values in [-1, 1]
    :return: (m, k, 3) uint8
    """
    return PALETTE[color_indices(C)]


def palette_classes() -> rr.AnnotationContext:
    """``PALETTE`` as classes: entry i is class i, its colour, labelled by its value.

    The image is logged as a segmentation image of palette entries, one byte a pixel,
    which the viewer colours through these classes: a third of the bytes of RGB pixels,
    the same colours, and hovering a pixel names its correlation.
    """
    step = 2.0 / (LUT_SIZE - 1)
    labels = [f"{-1.0 + i * step:+.3f}" for i in range(LUT_SIZE)]
    labels.append("undefined")
    return annotation_context(range(len(labels)), labels, PALETTE)


def block_outlines(correlation: Correlation) -> tuple[FloatArray, FloatArray, list[str]]:
    """The diagonal blocks (pose, then landmarks or groups of them) in image pixels.

    :return: (mins (B, 2), sizes (B, 2), labels)
    """
    ids = correlation.landmark_ids.tolist()
    per_group = max(1, math.ceil(len(ids) / MAX_LABELLED_BLOCKS))
    spans: list[tuple[int, int, str]] = [(0, 3, "pose")]
    for first in range(0, len(ids), per_group):
        group = ids[first : first + per_group]
        label = f"L{group[0]}" if len(group) == 1 else f"L{group[0]}-L{group[-1]}"
        spans.append((3 + 2 * first, 3 + 2 * (first + len(group)), label))
    f = correlation.factor
    starts = np.array([start / f for start, _, _ in spans])
    sizes = np.array([(end - start) / f for start, end, _ in spans])
    return (
        np.column_stack([starts, starts]),
        np.column_stack([sizes, sizes]),
        [label for _, _, label in spans],
    )


class _Logger(Protocol):
    def log(self, entity: str, data: rr.AsComponents, *, static: bool = False) -> None: ...

    def style(self, entity: str, styling: rr.AsComponents) -> None: ...


def log_correlation_styling(rec: _Logger) -> None:
    """The blocks' outline colour and the image's classes (see :func:`palette_classes`),
    once (with their first data)."""
    rec.style(
        style.CORRELATION_BLOCKS,
        rr.Boxes2D.from_fields(colors=style.CORRELATION_BLOCK_COLOR, draw_order=10.0),
    )
    rec.style(style.CORRELATION_MATRIX, palette_classes())


class CorrelationLayer:
    """The correlation matrices of a run's events: the images sent in columns with the
    batch they belong to (a ``log`` call each cost more than the filter's step), their
    blocks and description logged where they change."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas
        self._last: Correlation | None = None  # the last one logged

    def log_styling(self) -> None:
        log_correlation_styling(self._canvas.entities)

    def send(self, batch: Batch) -> None:
        at = sorted(k for k, extra in batch.extras.items() if extra.correlation is not None)
        if not at:
            return
        correlations = [batch.extras[k].correlation for k in at]
        matrices = [c.matrix for c in correlations]  # type: ignore[union-attr]
        # the colours of all matrices in one call (each pixel's its own): a call each cost
        # more than the rest of their logging
        sizes = np.array([matrix.size for matrix in matrices], dtype=np.int64)
        offsets = np.zeros(len(matrices) + 1, dtype=np.int32)
        np.cumsum(sizes, out=offsets[1:])
        flat = np.concatenate([matrix.reshape(-1) for matrix in matrices])
        pixels = pa.array(color_indices(flat), pa.uint8())
        heights = np.array([matrix.shape[0] for matrix in matrices], dtype=np.uint32)
        widths = np.array([matrix.shape[1] for matrix in matrices], dtype=np.uint32)
        n = len(matrices)
        formats = pa.StructArray.from_arrays(
            [pa.array(widths), pa.array(heights), pa.nulls(n, pa.uint8()),
             pa.nulls(n, pa.uint8()), pa.array(np.full(n, _U8, dtype=np.uint8))],
            fields=list(_FORMAT),
        )  # fmt: skip
        self._canvas.send(
            style.CORRELATION_MATRIX,
            batch.rows.pick(at),
            [
                column(
                    rr.SegmentationImage.descriptor_buffer(),
                    pa.ListArray.from_arrays(pa.array(offsets), pixels, type=_BUFFER),
                ),
                column(rr.SegmentationImage.descriptor_format(), formats),
            ],
        )
        for k, correlation in zip(at, correlations, strict=True):
            assert correlation is not None
            previous = self._last
            self._last = correlation
            if (
                previous is not None
                and previous.dim == correlation.dim
                and previous.factor == correlation.factor
                and (
                    (ids := correlation.landmark_ids) is previous.landmark_ids
                    or np.array_equal(previous.landmark_ids, ids)
                )
            ):
                continue
            time = float(batch.times[k])
            self._canvas.set_times(
                int(batch.rows.steps[k]), int(batch.rows.events[k]), None if time != time else time
            )
            mins, sizes_xy, labels = block_outlines(correlation)
            entities = self._canvas.entities
            entities.log(
                style.CORRELATION_BLOCKS, rr.Boxes2D(mins=mins, sizes=sizes_xy, labels=labels)
            )
            entities.log(style.CORRELATION_NOTE, rr.TextDocument(correlation.describe()))
