"""The Rerun logging layer: the only part of ekfviz that imports rerun.

- :mod:`ekfviz.viz.recorder` -- ``Recorder``, from filter states to Rerun entities
  (also for a filter of your own: ``initialise``/``predict``/``update`` take numpy
  arrays in the classic layout x = [x, y, theta, l1x, l1y, ...]);
- :mod:`ekfviz.viz.ellipses` -- the 3-sigma outline of a covariance;
- :mod:`ekfviz.viz.style` -- entity paths and colours;
- :mod:`ekfviz.viz.blueprint` -- the default viewer layout;
- :mod:`ekfviz.viz.run` -- one ``ekfviz replay`` run, logged batch by batch;
- :mod:`ekfviz.viz.recording` -- a recording sent to its sinks, its file saved whole;
- :mod:`ekfviz.viz.provenance` -- what describes a run, and its recording id;
- :mod:`ekfviz.viz.viewer` -- the viewer: probed, spawned or served.

Reading a recording back is :mod:`ekfviz.readback`'s.

Bring your own filter::

    import rerun as rr
    from ekfviz.viz import Recorder

    rec = rr.RecordingStream("my_slam")
    rec.save("run.rrd")
    recorder = Recorder(rec)  # sends the default layout, logs the styling once
    recorder.initialise(x, P, landmark_ids=ids, z=z)
    ...
    recorder.predict(x, P, control=(d, alpha))
    recorder.update(x, P, landmark_ids=ids, z=z, z_pred=z_pred, S=S)
    recorder.finish()

See ``examples/byof_minimal.py`` for a complete, runnable loop.
"""

from __future__ import annotations

from ekfviz.viz.ellipses import ellipse_outlines
from ekfviz.viz.provenance import RunInfo, run_info
from ekfviz.viz.recorder import Recorder
from ekfviz.viz.recording import Recording, Sinks, open_recording, resolve_default_sinks
from ekfviz.viz.run import RunLogger, open_run
from ekfviz.viz.viewer import LOOPBACK, ServedViewer, SinkError, check_bind

__all__ = [
    "LOOPBACK",
    "Recorder",
    "Recording",
    "RunInfo",
    "RunLogger",
    "ServedViewer",
    "SinkError",
    "Sinks",
    "check_bind",
    "ellipse_outlines",
    "open_recording",
    "open_run",
    "resolve_default_sinks",
    "run_info",
]
