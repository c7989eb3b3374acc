"""How much memory this process may still take: what bounds the filter's covariance.

A map of N landmarks makes a (3 + 2N)^2 covariance; a first line of 20,000 landmarks (a
320 KB log) asks for 12.8 GB, which the operating system grants lazily and the run then
fills, swapping, until the machine gives out. The filter asks here first.
"""

from __future__ import annotations

import os
from pathlib import Path

MEMINFO = Path("/proc/meminfo")
CGROUP = Path("/sys/fs/cgroup")


def available_memory() -> int | None:
    """Bytes this process can still take: the system's available memory (Linux's
    ``MemAvailable``, else the free physical pages) and, in a container, what its
    control group's limit leaves; None where neither can be told."""
    found = [value for value in (_system_available(), _group_left()) if value is not None]
    return min(found) if found else None


def _system_available() -> int | None:
    try:
        for line in MEMINFO.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def _group_left() -> int | None:
    """What the control group's memory limit leaves (None: no limit, or none found),
    cgroup version 2 (``memory.max``) or 1 (``memory.limit_in_bytes``)."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        if line.count(":") < 2:
            continue
        _, controllers, group = line.split(":", 2)
        if controllers == "":  # version 2
            folder = CGROUP / group.lstrip("/")
            limit_name, used_name = "memory.max", "memory.current"
        elif "memory" in controllers.split(","):  # version 1
            folder = CGROUP / "memory" / group.lstrip("/")
            limit_name, used_name = "memory.limit_in_bytes", "memory.usage_in_bytes"
        else:
            continue
        try:
            limit = (folder / limit_name).read_text().strip()
            if limit == "max":
                continue
            return max(0, int(limit) - int((folder / used_name).read_text()))
        except (OSError, ValueError):
            continue
    return None
