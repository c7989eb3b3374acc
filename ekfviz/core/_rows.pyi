# A replay's row copies (_rows.c); see its docstring.
from ekfviz.core.types import FloatArray

def copy_row(
    x: FloatArray,
    P: FloatArray,
    poses: FloatArray,
    pose_covs: FloatArray,
    row: int,
    map_xy: FloatArray,
    map_covs: FloatArray,
    start: int,
    count: int,
) -> None: ...
