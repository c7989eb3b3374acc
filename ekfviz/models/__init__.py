"""Motion and measurement models with analytic Jacobians (numpy only).

- :mod:`ekfviz.models.angles`: wrapping angles to (-pi, pi].
- :mod:`ekfviz.models.classic`: the classic models of the course: drive ``d`` then turn
  ``alpha``; (bearing, range) from the robot pose; landmark initialisation.
"""
