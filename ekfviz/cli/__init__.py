"""The ``ekfviz`` command line: one module per command, shared options in :mod:`.common`.

Importing this package registers every command on :data:`app`.
"""

from ekfviz.cli import (
    calibrate,
    check,
    compare,
    consistency,
    convert,
    export,
    grade,
    info,
    replay,
    simulate,
    sweep,
)
from ekfviz.cli.common import app
from ekfviz.cli.help import polish

polish(app)

__all__ = [
    "app",
    "calibrate",
    "check",
    "compare",
    "consistency",
    "convert",
    "export",
    "grade",
    "info",
    "replay",
    "simulate",
    "sweep",
]
