# The readers' number parser (_numbers.c); see its docstring.
import numpy as np
import numpy.typing as npt

from ekfviz.core.types import FloatArray, IntArray

def parse(
    data: bytes,
    lines: int,
    values: FloatArray,
    counts: IntArray,
    digits: npt.NDArray[np.uint8] | None = None,
) -> int: ...
