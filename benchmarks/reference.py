"""Where the shared reference data sets are, for the benchmarks that use real data.

They are never copied into the project: a benchmark looks for them beside it (in
``shared/reference/`` of a folder above) or where an environment variable says.
"""

from __future__ import annotations

import os
from pathlib import Path


def find_reference(name: str, variable: str) -> Path | None:
    """``$variable`` if set (None when it is no folder), else ``shared/reference/<name>``
    in the nearest folder above this file that has one."""
    given = os.environ.get(variable)
    if given:
        return Path(given) if Path(given).is_dir() else None
    for parent in Path(__file__).resolve().parents:
        candidate = parent / "shared" / "reference" / name
        if candidate.is_dir():
            return candidate
    return None
