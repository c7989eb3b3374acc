"""Recordings read back: what a recording holds (``ekfviz info``) and its trajectories and
map (``ekfviz export``), each read in a child process that a damaged file cannot take down.
"""

from __future__ import annotations

from ekfviz.readback.apart import NotARecordingError
from ekfviz.readback.export import RecordedRun, Trajectory, read_recorded_run
from ekfviz.readback.info import RecordingInfo, read_recording_info

__all__ = [
    "NotARecordingError",
    "RecordedRun",
    "RecordingInfo",
    "Trajectory",
    "read_recorded_run",
    "read_recording_info",
]
