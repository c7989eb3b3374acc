# The readers' number parser (_numbers.c); see its docstring.
from ekfviz.core.types import FloatArray, IntArray

def parse(data: bytes, lines: int, values: FloatArray, counts: IntArray) -> int: ...
