"""The recorder's parts of the picture, one module each, over one shared columnar buffer.

:class:`~ekfviz.viz.recorder.Recorder` buffers the records of a run and hands each batch
(:class:`~ekfviz.viz.layers.batch.Batch`, the records' shared columns) to every part,
which logs its own entities with its own styling:

| module | entities |
|---|---|
| :mod:`.robot` | ``world/robot`` (point and frame), its pose ellipses, ``world/trajectory`` |
| :mod:`.history` | ``world/history/...``: every pose ellipse, accumulated (``--history``) |
| :mod:`.landmarks` | ``world/landmarks`` points and ellipses, first sightings |
| :mod:`.labels` | ``world/landmarks/labels`` and the landmark classes of ``world`` |
| :mod:`.observations` | ``world/robot/frame/observations``: the rays of an update |
| :mod:`.metrics` | ``metrics/...``: pose sigma, NIS, numerical health |
| :mod:`.truth` | ``world/truth/...``, NEES and the landmark errors |
| :mod:`.text` | ``log``: a line per step, one per warning |

The association (:mod:`ekfviz.viz.association`) and the correlation
(:mod:`ekfviz.viz.correlation`) are parts too, with modules of their own beside.
:mod:`.arrow` builds Arrow columns without the SDK's per-row conversions and
:mod:`.canvas` holds what the parts share: the stream, the clock, the series buffer and the
map's bounds; :mod:`.batch` the batch of records.
"""
