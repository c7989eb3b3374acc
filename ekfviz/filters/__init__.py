"""The filters and how a run gets one.

- :mod:`~ekfviz.filters.ekf`: the built-in EKF-SLAM (and its compiled kernel, ``_kernel.c``);
- :mod:`~ekfviz.filters.model_ekf`: the same EKF over any motion and measurement model;
- :mod:`~ekfviz.filters.protocol`: what a filter must do (:class:`SlamFilter`);
- :mod:`~ekfviz.filters.plugged`: a filter of the protocol driven like the built-in;
- :mod:`~ekfviz.filters.spec`: ``--filter`` parsed, registered backends, user code loaded;
- user code runs in a process of its own: :mod:`ekfviz.sandbox`;
- :mod:`~ekfviz.filters.gtsam`: the factor-graph smoothers (optional extra).
"""
