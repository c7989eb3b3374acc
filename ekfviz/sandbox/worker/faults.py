"""What the user's code did wrong, as the worker says it: a fault in one line, an
exception of the user's with where in the user's own files it was raised."""

from __future__ import annotations

import os
import traceback
from typing import Optional, Tuple

import numpy as np

from .framing import shown

WORKER_FOLDER = os.path.dirname(os.path.abspath(__file__))
CHILD_SCRIPT = os.path.join(os.path.dirname(WORKER_FOLDER), "child.py")  # what runs this


class FilterFault(Exception):
    """What the user's code did wrong, said in one line (no traceback of ours)."""

    kind = "fault"


class ExitFault(FilterFault):
    """The user's code called ``sys.exit``."""

    kind = "exit"


class UserError(Exception):
    """An exception raised by the user's code, with where and its traceback."""

    def __init__(self, function: str, error: BaseException, trace: str) -> None:
        super().__init__("%s raised %s: %s" % (function, type(error).__name__, error))
        self.function = function
        self.error = error
        self.trace = trace


def said(error: BaseException) -> str:
    """``": message"`` of an exception on one line (numpy's run over several: its lines
    joined by spaces), cut as :func:`shown` cuts it; nothing when it has none."""
    text = " ".join(shown(str, error).split())  # (a __str__ that raises is said)
    return ": " + text if text else ""


def top_level_line(error: BaseException, path: str) -> Optional[Tuple[int, str]]:
    """The line of the module at ``path``'s top-level code from which ``error`` was
    raised, and the name of the module's function it called there (empty when it raised
    there itself); None when the error did not come from its top-level code."""
    frames = traceback.extract_tb(error.__traceback__)
    target = os.path.abspath(path)
    for index, frame in enumerate(frames):
        if frame.name != "<module>" or os.path.abspath(frame.filename) != target:
            continue
        if not frame.lineno:
            return None
        callee = frames[index + 1] if index + 1 < len(frames) else None
        inside = callee is not None and os.path.abspath(callee.filename) == target
        return frame.lineno, callee.name if inside and callee is not None else ""
    return None


def user_line(error: BaseException) -> str:
    """Where in the user's code ``error`` was raised: the innermost frame that is neither
    the worker's own (this folder, ``child.py`` beside it) nor of an installed package or
    the standard library (a student needs the line of their own file, not numpy's or
    matplotlib's), as `` (at ekf_slam.py:47 in update: K = ...)``; empty when there is
    none."""
    import sysconfig

    installed = sysconfig.get_paths()
    skip = tuple(
        os.path.abspath(installed[key]) + os.sep
        for key in ("stdlib", "platstdlib", "purelib", "platlib")
        if key in installed
    ) + (os.path.dirname(np.__file__), WORKER_FOLDER + os.sep, CHILD_SCRIPT)
    try:
        frames = traceback.extract_tb(error.__traceback__)
    except Exception:
        return ""
    for frame in reversed(frames):
        if frame.filename.startswith("<"):
            continue
        filename = os.path.abspath(frame.filename)
        if filename.startswith(skip):
            continue
        code = (frame.line or "").strip()
        if len(code) > 80:
            code = code[:77] + "..."
        return " (at %s:%d in %s%s)" % (
            os.path.basename(filename),
            frame.lineno or 0,
            frame.name,
            ": " + code if code else "",
        )
    return ""
