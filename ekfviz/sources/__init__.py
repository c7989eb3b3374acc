"""Sources: every input format as one module that gives a run all it needs.

A format is a :class:`~ekfviz.sources.base.Source` subclass in a module of its own,
registered with :func:`~ekfviz.sources.base.register`; importing it below is its one
registration, and its place in the line is its turn in detection (the first format
that claims a path reads it; classic, the fallback, comes last). Numpy only.
"""

from ekfviz.sources import mrclam, victoria, rosbag, extended, classic  # noqa: F401, I001
from ekfviz.sources.base import (
    FittedReference,
    Models,
    OwnTruth,
    Reference,
    Source,
    SourceArgs,
    SourceOption,
    formats,
    open_source,
    read_log,
    register,
    source_options,
)
from ekfviz.sources.simulated import SimulatedSource

__all__ = [
    "FittedReference",
    "Models",
    "OwnTruth",
    "Reference",
    "SimulatedSource",
    "Source",
    "SourceArgs",
    "SourceOption",
    "formats",
    "open_source",
    "read_log",
    "register",
    "source_options",
]
