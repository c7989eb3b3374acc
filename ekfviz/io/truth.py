"""Readers of ground-truth files.

Plain text: one ``x y`` pair per line in landmark order (ids 1, 2, ...), ``#`` comments
and blank lines allowed. JSON: ``{"landmarks": [[x, y], ...]}`` in landmark order.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ekfviz.core.evaluation import GroundTruth
from ekfviz.io.errors import InputError
from ekfviz.io.text import numeric_lines


def read_truth(path: Path) -> GroundTruth:
    """Read a truth file, JSON when it ends in ``.json`` or starts with ``{``.

    :raises InputError: naming the line and what was expected
    """
    if path.suffix.lower() == ".json" or _starts_with_brace(path):
        return _read_json(path)
    return _read_text(path)


def _starts_with_brace(path: Path) -> bool:
    try:
        with path.open("rb") as handle:
            return handle.read(64).lstrip().startswith(b"{")
    except OSError:
        return False  # the text reader reports it


def _read_text(path: Path) -> GroundTruth:
    rows: list[list[float]] = []
    for line, values in numeric_lines(path):
        if len(values) != 2:
            raise InputError(
                path, line, f"found {len(values)} numbers, expected 2 (a landmark's x y)"
            )
        rows.append(values)
    if not rows:
        raise InputError(path, 1, "found no data, expected one 'x y' line per landmark")
    return _truth(rows)


def _read_json(path: Path) -> GroundTruth:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, 0, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, 0, "is a directory, expected a JSON file") from None
    except UnicodeDecodeError:
        raise InputError(path, 0, "found bytes that are not UTF-8 text") from None
    try:
        document = json.loads(text)
    except json.JSONDecodeError as error:
        raise InputError(path, error.lineno, f"invalid JSON: {error.msg}") from None
    landmarks = document.get("landmarks") if isinstance(document, dict) else None
    if not isinstance(landmarks, list) or not landmarks:
        raise InputError(path, 1, 'expected an object {"landmarks": [[x, y], ...]}')
    for i, pair in enumerate(landmarks, start=1):
        if not (
            isinstance(pair, list)
            and len(pair) == 2
            and all(isinstance(v, int | float) and math.isfinite(v) for v in pair)
        ):
            raise InputError(
                path, 1, f"landmark {i} is {json.dumps(pair)[:40]}, expected [x, y] numbers"
            )
    return _truth(landmarks)


def _truth(rows: list[list[float]]) -> GroundTruth:
    xy = np.array(rows, dtype=np.float64).reshape(-1, 2)
    return GroundTruth(ids=np.arange(1, len(xy) + 1, dtype=np.int64), landmarks_xy=xy)
