"""The worker's channel: a message is a 4-byte little-endian length, a JSON header, then the
raw bytes of each array the header lists (``{"__nd__": i}`` in the JSON; shape and dtype in
``header["arrays"]``): numpy objects never cross as pickles, so that ekfviz and the worker
may run different numpy versions."""

from __future__ import annotations

import json
import struct
from typing import Any, Dict, List, Tuple

import numpy as np

PROTOCOL = 1


def _read_exact(stream: Any, count: int) -> bytes:
    chunks = []
    left = count
    while left:
        chunk = stream.read(left)
        if not chunk:
            raise EOFError
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


# the longest message of a user's exception that ekfviz's one line shows (--debug shows
# the whole traceback): an exception may carry megabytes of text, or a __str__ that raises
MAX_MESSAGE = 1000


def shown(convert: Any, value: Any) -> str:
    """``convert(value)`` (``str`` or ``repr``) cut to :data:`MAX_MESSAGE` characters,
    or a note where it raises."""
    try:
        text = convert(value)
    except BaseException as error:  # a __str__ or __repr__ that fails, or loops to the bound
        return "(its text cannot be shown: %s raised %s)" % (
            convert.__name__,
            type(error).__name__,
        )
    if not isinstance(text, str):
        return "(its text cannot be shown)"
    if len(text) > MAX_MESSAGE:
        return "%s... (%d characters in all)" % (text[:MAX_MESSAGE], len(text))
    return text


def read_message(stream: Any) -> Tuple[Dict[str, Any], List[Any]]:
    """One message: its JSON header and its arrays."""
    (size,) = struct.unpack("<I", _read_exact(stream, 4))
    header = json.loads(_read_exact(stream, size).decode("utf-8"))
    arrays = []
    for meta in header.get("arrays", []):
        dtype = np.dtype(meta["dtype"])
        shape = tuple(meta["shape"])
        count = int(np.prod(shape)) if shape else 1
        data = _read_exact(stream, count * dtype.itemsize)
        arrays.append(np.frombuffer(data, dtype=dtype).reshape(shape).copy())
    return header, arrays


def write_message(stream: Any, header: Dict[str, Any], arrays: List[Any]) -> None:
    """Send one message (see the module docstring)."""
    contiguous = [np.ascontiguousarray(a) for a in arrays]
    header = dict(header)
    header["arrays"] = [{"shape": list(a.shape), "dtype": a.dtype.str} for a in contiguous]
    data = json.dumps(header, allow_nan=True).encode("utf-8")
    stream.write(struct.pack("<I", len(data)))
    stream.write(data)
    for a in contiguous:
        # the array's own buffer, not a copy of it (a state of a few MB crosses every event)
        stream.write(memoryview(a.reshape(-1)).cast("B") if a.size else b"")  # type: ignore[arg-type]
    stream.flush()
