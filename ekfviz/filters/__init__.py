"""Filters beyond the built-in EKF; optional backends (GTSAM) are imported lazily."""
