"""Kalman-filtered parameter estimators (a thin adapter over filterpy)."""

from ilcpmac.estimators.kalman import KalmanEstimator

__all__ = ["KalmanEstimator"]
