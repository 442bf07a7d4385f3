"""The torque sensor's response: what a piezo torque sensor does to a harmonic of the true torque (sec. 1.1).

A piezo cannot measure the mean: it is a first-order high-pass of corner f_hp, and its filter and
sampling delay the measurement by D,

    H_s(w) = j w / (j w + w_c) exp(-j w D),    w_c = 2 pi f_hp,

at angular frequency w = 2 pi h f of harmonic h at mechanical speed f. The joint fit identifies f_hp and D
(`ilcpmac.identify.joint`, with `highpass` and `sensor_response`); the pipeline divides the measured harmonics
by H_s (`harmonic_response`, through `ilcpmac.stages.base.Identified`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["delay", "harmonic_response", "highpass", "sensor_response"]


def highpass(omega_rad_s: np.ndarray, highpass_hz: float) -> np.ndarray:
    """The first-order high-pass j w / (j w + w_c) at ``omega_rad_s``, w_c = 2 pi ``highpass_hz``."""
    return 1j * omega_rad_s / (1j * omega_rad_s + 2.0 * np.pi * highpass_hz)


def delay(omega_rad_s: np.ndarray, delay_s: float) -> np.ndarray:
    """The delay e^{-j w D} at ``omega_rad_s``."""
    return np.exp(-1j * omega_rad_s * delay_s)


def sensor_response(omega_rad_s: np.ndarray, highpass_hz: float, delay_s: float) -> np.ndarray:
    """H_s(w): the `highpass` and the `delay` at ``omega_rad_s``."""
    response: np.ndarray = highpass(omega_rad_s, highpass_hz) * delay(omega_rad_s, delay_s)
    return response


def harmonic_response(harmonics: np.ndarray, speed_hz: float, highpass_hz: float, delay_s: float) -> np.ndarray:
    """H_s at ``harmonics`` h of a trial at ``speed_hz`` f, w = 2 pi h f; 1 at h = 0 (the mean, which a piezo does
    not measure, is taken as it is).

    The high-pass is evaluated as 1 / (1 - j w_c / w): the campaign's figures were computed with this form,
    which differs from `highpass`'s in the last bit.
    """
    w = 2.0 * np.pi * np.asarray(harmonics, float) * speed_hz
    corner = 2.0 * np.pi * highpass_hz
    with np.errstate(divide="ignore", invalid="ignore"):
        response = np.where(w > 0, 1.0 / (1.0 - 1j * corner / w), 1.0)
    delayed: np.ndarray = response * delay(w, delay_s)
    return delayed
