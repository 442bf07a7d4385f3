"""Limits every request obeys, whatever the stages ask."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.errors import ConfigError
from ilcpmac.records import TrialRequest


@dataclass(frozen=True)
class SafetyLimits:
    """Bounds on a request.

    Attributes
    ----------
    max_correction_nm : float
        |feed-forward| per count, N m.
    max_current_a : float
        |I*_p| per count and phase, A.
    max_torque_nm : float
        |torque reference| per count, N m.
    """

    max_correction_nm: float
    max_current_a: float
    max_torque_nm: float


def torque_bound_nm(backemf_nm_per_a: np.ndarray, limits: SafetyLimits) -> np.ndarray:
    """Largest |tau_ref| per count that keeps every I*_p = tau_ref K_p / sum K^2 within the current limit."""
    k = np.abs(backemf_nm_per_a)
    current_bound = limits.max_current_a * np.sum(backemf_nm_per_a**2, axis=1) / k.max(axis=1)
    return np.minimum(current_bound, limits.max_torque_nm)


def enforce_limits(request: TrialRequest, backemf_nm_per_a: np.ndarray, limits: SafetyLimits) -> TrialRequest:
    """Clip the feed-forward so that it and the resulting current references stay within ``limits``.

    Raises `ConfigError` when the set point plus excitation alone break the limits.
    """
    bound = torque_bound_nm(backemf_nm_per_a, limits)
    base = request.torque_setpoint_nm + request.excitation_nm
    if np.any(np.abs(base) > bound):
        raise ConfigError(
            f"set point {request.torque_setpoint_nm} N m with its excitation exceeds the limits "
            f"(max_current_a {limits.max_current_a}, max_torque_nm {limits.max_torque_nm})")
    correction = np.clip(request.feedforward_nm, -limits.max_correction_nm, limits.max_correction_nm)
    correction = np.clip(base + correction, -bound, bound) - base
    return request.with_changes(feedforward_nm=correction)
