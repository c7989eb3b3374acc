"""Arrow arrays ekfviz builds itself against the ones Rerun's SDK builds for the same data:
the same component, without the SDK's per-element conversion (and its pyarrow.compute)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pytest
import rerun as rr

from ekfviz.viz.annotations import annotation_context
from ekfviz.viz.correlation import PALETTE, palette_classes
from ekfviz.viz.layers.arrow import FirstRow


def _array(context: rr.AnnotationContext) -> pa.Array:
    (batch,) = context.as_component_batches()
    return batch.as_arrow_array()


@pytest.mark.parametrize("ids", [[0, 1, 2, 3], [1, 7, 300, 65535], []])
def test_an_annotation_context_is_the_sdks_with_and_without_colours(ids: list[int]) -> None:
    labels = [f"L{i}" for i in ids]
    plain = rr.AnnotationContext([(i, label) for i, label in zip(ids, labels, strict=True)])
    assert _array(annotation_context(ids, labels)).equals(_array(plain))
    rgb = np.random.default_rng(1).integers(0, 256, (len(ids), 3), dtype=np.uint8)
    coloured = rr.AnnotationContext(
        [
            rr.AnnotationInfo(id=i, label=label, color=tuple(int(c) for c in colour))
            for i, label, colour in zip(ids, labels, rgb.tolist(), strict=True)
        ]
    )
    assert _array(annotation_context(ids, labels, rgb)).equals(_array(coloured))


def test_the_correlation_palette_classes_are_the_sdks() -> None:
    step = 2.0 / 254
    labels = [f"{-1.0 + i * step:+.3f}" for i in range(255)] + ["undefined"]
    sdk = rr.AnnotationContext(
        [
            rr.AnnotationInfo(id=i, label=label, color=tuple(int(c) for c in colour))
            for i, (label, colour) in enumerate(zip(labels, PALETTE.tolist(), strict=True))
        ]
    )
    assert _array(palette_classes()).equals(_array(sdk))


@pytest.mark.parametrize("rows", [1, 2, 5])
def test_a_first_row_column_is_the_masked_list_array(rows: int) -> None:
    values = pa.array([3, 1, 4], pa.uint32())
    built = FirstRow(rr.ComponentDescriptor("x"), values, rows).as_arrow_array()
    offsets = np.full(rows + 1, 3, dtype=np.int32)
    offsets[0] = 0
    mask = np.ones(rows, dtype=bool)
    mask[0] = False
    masked = pa.ListArray.from_arrays(pa.array(offsets), values, mask=pa.array(mask))
    assert built.to_pylist() == [[3, 1, 4]] + [None] * (rows - 1)
    assert built.equals(masked) and built.null_count == rows - 1
