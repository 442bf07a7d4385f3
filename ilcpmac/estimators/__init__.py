"""Kalman-filtered parameter estimators (a thin adapter over filterpy)."""

from ilcpmac.estimators.kalman import KalmanEstimator, import_in_background

__all__ = ["KalmanEstimator", "import_in_background"]
