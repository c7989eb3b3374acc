"""Calibrating a log's noise: odometry errors and motion noise fitted to truth, checked on
held-out time."""
