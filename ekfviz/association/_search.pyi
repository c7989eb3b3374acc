# JCBB's branch and bound and the scan's gate (_search.c); see its docstrings.
from ekfviz.core.types import BoolArray, FloatArray, IntArray

def gate(
    x: FloatArray,
    bearing: FloatArray,
    pose_rows: FloatArray,
    covs: FloatArray,
    z: FloatArray,
    values: FloatArray,
    out: FloatArray,
    rows: IntArray,
    flags: BoolArray,
) -> int: ...
def jcbb(
    nu: FloatArray,
    d2: FloatArray,
    compatible: BoolArray,
    C: FloatArray,
    R: FloatArray,
    thresholds: FloatArray,
    m: int,
    K: int,
    budget: int,
    work_budget: int,
    max_joint: int,
) -> tuple[list[int], float, int, int, int, int] | None: ...
