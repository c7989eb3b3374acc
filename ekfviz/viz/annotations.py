"""Annotation contexts (class id -> label, colour) built as one Arrow array.

Rerun converts a list of ``AnnotationInfo`` one class at a time and casts the result,
which imports ``pyarrow.compute`` at the first conversion: 30-45 ms of a short replay's
start, and some 50 us per class after it. The array here is the same component, built
from whole columns (tests compare the two).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.types import IntArray


def annotation_context(
    ids: IntArray | Sequence[int],
    labels: Sequence[str],
    rgb: np.ndarray | None = None,
) -> rr.AnnotationContext:
    """Classes ``ids[k]`` labelled ``labels[k]``, coloured ``rgb[k]`` (or by the viewer).

    :param ids: (K,) class ids, 0 to 65535
    :param labels: K labels
    :param rgb: (K, 3) uint8 colours, or None for the viewer's own per class
    """
    context: pa.ListType = rr.components.AnnotationContextBatch._ARROW_DATATYPE
    element: pa.StructType = context.value_type
    description: pa.StructType = element.field("class_description").type
    count = len(labels)
    class_ids = pa.array(np.asarray(ids, dtype=np.uint16))
    if rgb is None:
        colours = pa.nulls(count, pa.uint32())
    else:
        channels = np.asarray(rgb, dtype=np.uint32)
        colours = pa.array(
            (channels[:, 0] << 24) | (channels[:, 1] << 16) | (channels[:, 2] << 8) | 0xFF,
            pa.uint32(),
        )  # packed RGBA, opaque
    info = pa.StructArray.from_arrays(
        [class_ids, pa.array(list(labels), pa.utf8()), colours],
        fields=list(description.field("info").type),
    )
    no_items = pa.array(np.zeros(count + 1, dtype=np.int32))  # no keypoints in any class
    keypoints = [
        pa.ListArray.from_arrays(no_items, pa.array([], kind.value_type), type=kind)
        for kind in (
            description.field("keypoint_annotations").type,
            description.field("keypoint_connections").type,
        )
    ]
    classes = pa.StructArray.from_arrays(
        [class_ids, pa.StructArray.from_arrays([info, *keypoints], fields=list(description))],
        fields=list(element),
    )
    one = pa.ListArray.from_arrays(pa.array([0, count], pa.int32()), classes, type=context)
    return rr.AnnotationContext.from_fields(context=one)
