"""ekfviz: replay a 2-D EKF-SLAM run and explore it in Rerun."""

__version__ = "0.1.0"
