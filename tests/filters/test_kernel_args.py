"""The compiled kernel refuses a line's buffers of the wrong kind or size, whichever
update reads them (the checks are shared: ``get_line`` in ``_kernel.c``)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

kernel = pytest.importorskip("ekfviz.filters._kernel")

N = 9  # a state of 3 landmarks


def line(m: int = 2, **changed: Any) -> dict[str, Any]:
    parts = {
        "slots": np.array([3, 5][:m], dtype=np.int64),
        "z": np.zeros((m, 2)),
        "table": np.zeros((m, 9)),
        "status": np.zeros(m, dtype=np.int8),
    }
    parts.update(changed)
    return parts


def sequential(parts: dict[str, Any]) -> Any:
    x, P = np.zeros(N), np.eye(N)
    return kernel.update_sequential(
        x, P, N, parts["slots"], parts["z"], parts["table"], parts["status"], 1.0, 1.0, 1e-9
    )


def model(parts: dict[str, Any], rank: int = 0) -> Any:
    x, P, U = np.zeros(N), np.eye(N), np.zeros((4, N))
    return kernel.model_update(
        x, P, U, N, rank, parts["slots"], parts["z"], parts["table"], parts["status"], 0,
        0.0, 0.0, 1.0, 0.0, 1.0, 1e-9,
    )  # fmt: skip


BAD = [
    ("slots", line(slots=np.array([3, 5], dtype=np.int32)), "slots: expected contiguous int64"),
    ("z", line(z=np.zeros((1, 2))), "z: expected at least 4 contiguous float64"),
    ("table", line(table=np.zeros((2, 8))), "table: expected at least 18 contiguous float64"),
    ("status", line(status=np.zeros(1, dtype=np.int8)), "status: expected one byte per"),
]


@pytest.mark.parametrize("update", [sequential, model])
@pytest.mark.parametrize(("what", "parts", "message"), BAD, ids=[b[0] for b in BAD])
def test_a_bad_buffer_of_the_line_is_refused(
    update: Any, what: str, parts: dict[str, Any], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        update(parts)


def test_a_good_line_goes_through_both_and_a_bad_rank_is_refused() -> None:
    assert sequential(line())[0] == 0
    assert model(line())[0] == 0
    with pytest.raises(ValueError, match="rank: expected even"):
        model(line(), rank=1)
