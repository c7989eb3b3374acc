"""Trajectories and maps as text for other tools: TUM for evo, CSV for spreadsheets.

Numpy only. A TUM line is ``timestamp tx ty tz qx qy qz qw`` (the format of the TUM RGB-D
benchmark, which ``evo_ape tum`` reads): a planar pose (x, y, theta) is the translation
(x, y, 0) and the rotation theta about z, the quaternion (0, 0, sin(theta/2), cos(theta/2)).
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.types import FloatArray, IntArray


def _stamp(seconds: float) -> str:
    """A time stamp to the microsecond, without trailing zeros (a step number stays an
    integer; Unix times keep their digits, which ``%g`` would round away)."""
    return f"{seconds:.6f}".rstrip("0").rstrip(".")


def format_tum(stamps: FloatArray, poses_xytheta: FloatArray) -> str:
    """One TUM line per pose.

    :param stamps: (T,) time stamps in seconds (or step numbers), increasing
    :param poses_xytheta: (T, 3) planar poses
    """
    half = 0.5 * poses_xytheta[:, 2]
    lines = [
        f"{_stamp(t)} {x:.9g} {y:.9g} 0 0 0 {qz:.9g} {qw:.9g}"
        for t, x, y, qz, qw in zip(
            stamps.tolist(),
            poses_xytheta[:, 0].tolist(),
            poses_xytheta[:, 1].tolist(),
            np.sin(half).tolist(),
            np.cos(half).tolist(),
            strict=True,
        )
    ]
    return "".join(f"{line}\n" for line in lines)


def format_poses_csv(
    steps: IntArray,
    stamps: FloatArray | None,
    poses_xytheta: FloatArray,
    sigmas_xytheta: FloatArray,
) -> str:
    """``step[,time],x,y,theta,sigma_x,sigma_y,sigma_theta`` with a header line; a
    standard deviation the recording does not hold is left empty.

    :param stamps: (T,) seconds, or None when the log had no time stamps
    :param sigmas_xytheta: (T, 3) the pose's standard deviations, NaN where unknown
    """
    header = ["step", *(["time"] if stamps is not None else []), "x", "y", "theta"]
    header += ["sigma_x", "sigma_y", "sigma_theta"]
    rows = [",".join(header)]
    for k, step in enumerate(steps.tolist()):
        cells = [str(step)]
        if stamps is not None:
            cells.append(_stamp(float(stamps[k])))
        cells += [f"{v:.9g}" for v in poses_xytheta[k].tolist()]
        cells += ["" if not np.isfinite(v) else f"{v:.9g}" for v in sigmas_xytheta[k].tolist()]
        rows.append(",".join(cells))
    return "".join(f"{row}\n" for row in rows)


def format_landmarks_csv(ids: IntArray, landmarks_xy: FloatArray) -> str:
    """``id,x,y`` with a header line, one landmark a line."""
    rows = ["id,x,y"] + [
        f"{i},{x:.9g},{y:.9g}"
        for i, (x, y) in zip(ids.tolist(), landmarks_xy.tolist(), strict=True)
    ]
    return "".join(f"{row}\n" for row in rows)
