"""Rerun's native log filter, set before rerun is first imported (it reads it then).

ekfviz saves recordings without an RRD footer (see :func:`ekfviz.viz.run.footerless`),
and Rerun warns of it on stderr at every save; that one warning is what ekfviz means, so
it is raised to an error-only level. Rerun's other warnings stay, and a ``RUST_LOG`` of
the user's own is left alone.
"""

from __future__ import annotations

import os

RUST_LOG = "warn,re_log_encoding::rrd::file_sink=error"

os.environ.setdefault("RUST_LOG", RUST_LOG)
