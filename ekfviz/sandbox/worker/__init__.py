"""The worker's modules (see ``child.py`` beside this folder, which runs them): the channel
(:mod:`.framing`), what the user's code did wrong (:mod:`.faults`), course modules
(:mod:`.course`), matplotlib without windows (:mod:`.no_windows`), the loop of requests
(:mod:`.serving`) and the process's guard and probe (:mod:`.process`).

The standard library and numpy only, any Python >= 3.8 (3.8's syntax, numpy 1.17's API),
and relative imports only: in the worker this folder is the package ``ekfviz_worker``,
imported from its files without ekfviz and without a folder of ekfviz's on ``sys.path``.
"""
