# The compiled kernel of small maps (_kernel.c); see its docstrings.
from ekfviz.core.types import FloatArray, Int8Array, IntArray

def predict(
    x: FloatArray, P: FloatArray, n: int, d: float, alpha: float, qx: float, qy: float, qa: float
) -> bool: ...
def update_sequential(
    x: FloatArray,
    P: FloatArray,
    n: int,
    slots: IntArray,
    z: FloatArray,
    table: FloatArray,
    status: Int8Array,
    r00: float,
    r11: float,
    min_range: float,
) -> tuple[int, int, int]: ...
def model_update(
    x: FloatArray,
    P: FloatArray,
    U: FloatArray,
    n: int,
    rank: int,
    slots: IntArray,
    z: FloatArray,
    table: FloatArray,
    status: Int8Array,
    start: int,
    a: float,
    b: float,
    r00: float,
    r01: float,
    r11: float,
    min_range: float,
    wide: bool = True,
) -> tuple[int, int, int]: ...
def ackermann_drive(
    segments: FloatArray,
    x: float,
    y: float,
    theta: float,
    p00: float,
    p01: float,
    p02: float,
    p11: float,
    p12: float,
    p22: float,
    L: float,
    H: float,
    qv: float,
    qs: float,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]: ...
