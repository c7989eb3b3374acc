"""Studies: many pipelines over one log or scenario (sweep, compare, Monte-Carlo).

- :mod:`ekfviz.studies.runs`: the shared mechanism: run specifications, replays in
  parallel, summaries.
- :mod:`ekfviz.studies.sweep`: a sweep's variants from ``--vary`` and presets.

Numpy only, like the core: recording them is :mod:`ekfviz.viz.study`'s business.
"""
