"""Bring your own filter: a plain dense EKF-SLAM loop, recorded with ekfviz's Recorder.

    .venv/bin/python examples/byof_minimal.py [OUT.rrd]
    .venv/bin/rerun OUT.rrd          (or rerun with the venv activated)

(OUT.rrd by default: byof_minimal.rrd in the temp directory; the script prints the
command that opens it.)

The filter below is the textbook one (docs/ekf-slam.md), written for reading, not speed:
dense Jacobians, all landmarks of a line folded in at once. Only the four ``recorder``
calls are about ekfviz.
"""

from __future__ import annotations

import shlex
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import rerun as rr

from ekfviz.core.records import Control
from ekfviz.core.types import FloatArray
from ekfviz.sim.simulate import CLASSIC_LANDMARKS_XY, classic_controls, simulate
from ekfviz.viz import Recorder

Q = np.diag([0.25, 0.1, 0.1]) ** 2  # motion noise in the robot frame
R = np.diag([0.01, 0.08]) ** 2  # (bearing, range) noise


def wrap(angle: FloatArray) -> FloatArray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def main(out: Path) -> None:
    run = simulate(classic_controls(), CLASSIC_LANDMARKS_XY, seed=7)
    rec = rr.RecordingStream("byof_minimal")
    rec.save(out)
    recorder = Recorder(rec)

    x = np.zeros(3)
    P = np.diag([0.02, 0.02, 0.1]) ** 2
    for event in run.events:
        if isinstance(event, Control):
            d, alpha = event.d, event.alpha
            c, s = np.cos(x[2]), np.sin(x[2])
            F = np.eye(len(x))
            F[0, 2], F[1, 2] = -d * s, d * c
            W = np.zeros((len(x), 3))
            W[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
            x[:3] += [d * c, d * s, alpha]
            x[2] = wrap(x[2])
            P = F @ P @ F.T + W @ Q @ W.T
            recorder.predict(x, P, control=(d, alpha), line=event.line)
            continue
        if len(x) == 3:  # the first line: initialise every landmark from its measurement
            for bearing, r in event.z:
                angle = x[2] + bearing
                c, s = np.cos(angle), np.sin(angle)
                Jp = np.zeros((2, len(x)))
                Jp[:, :3] = [[1.0, 0.0, -r * s], [0.0, 1.0, r * c]]
                Jz = np.array([[-r * s, c], [r * c, s]])
                P_lx = Jp @ P
                P = np.block([[P, P_lx.T], [P_lx, Jp @ P @ Jp.T + Jz @ R @ Jz.T]])
                x = np.concatenate([x, x[:2] + r * np.array([c, s])])
            recorder.initialise(x, P, landmark_ids=event.ids, z=event.z, line=event.line)
            continue
        m = len(event.ids)
        H = np.zeros((2 * m, len(x)))
        z_pred = np.zeros((m, 2))
        for k, landmark_id in enumerate(event.ids):
            j = 3 + 2 * (int(landmark_id) - 1)  # landmark i sits at 3 + 2(i - 1)
            dx, dy = x[j] - x[0], x[j + 1] - x[1]
            q = dx * dx + dy * dy
            z_pred[k] = wrap(np.arctan2(dy, dx) - x[2]), np.sqrt(q)
            H[2 * k : 2 * k + 2, :3] = [[dy / q, -dx / q, -1.0], [-dx / q**0.5, -dy / q**0.5, 0.0]]
            H[2 * k : 2 * k + 2, j : j + 2] = [[-dy / q, dx / q], [dx / q**0.5, dy / q**0.5]]
        nu = event.z - z_pred
        nu[:, 0] = wrap(nu[:, 0])
        S = H @ P @ H.T + np.kron(np.eye(m), R)
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ nu.reshape(-1)
        x[2] = wrap(x[2])
        P = P - K @ S @ K.T
        S_blocks = np.array([S[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] for k in range(m)])
        recorder.update(
            x, P, landmark_ids=event.ids, z=event.z, z_pred=z_pred, S=S_blocks, line=event.line
        )
    recorder.finish()
    rec.disconnect()  # closes the file


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.gettempdir())
    if target.is_dir():
        target = target / "byof_minimal.rrd"
    main(target)
    # the viewer beside this Python (an unactivated venv has it there, not on PATH)
    beside = Path(sys.executable).with_name("rerun")
    on_path = shutil.which("rerun")
    viewer = "rerun"
    if beside.is_file() and (on_path is None or Path(on_path).resolve() != beside.resolve()):
        viewer = str(beside)
    print(f"Saved {target}; open it with: {shlex.join([viewer, str(target)])}")
